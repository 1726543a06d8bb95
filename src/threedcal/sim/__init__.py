"""The simulated bench: fake Marlin firmware behind a pyserial URL (marlin.py) on a virtual clock,
the gel + optics simulator (optics.py, indenters.py), and the two coupled (bench.py); the simulated
ReSkin board behind ``simreskin://`` (reskin.py).

Nothing is imported here: pyserial imports this package to find the ``simmarlin://`` handler, and
the config check reads the firmware's fault list, neither of which needs the optics.
"""
