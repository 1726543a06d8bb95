"""The simulated bench: fake Marlin firmware behind a pyserial URL, virtual clock, optics.

Kept import-light: pyserial imports this package when it looks up the ``simmarlin://`` handler.
"""
