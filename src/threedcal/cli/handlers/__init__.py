"""What each `threedcal` command does, apart from its options (threedcal.cli's modules).

A :class:`threedcal.cli.Command` names its function here as ``"module:function"``;
:func:`threedcal.cli.handler` imports the module only when that command runs, so each module
imports its libraries at its top. Commands share a module only where they need the same
libraries: a command never loads what another needs (``config check`` needs pandas, ``profiles
list`` does not; ``predict`` and ``live`` run on the inference core alone).
"""
