"""The simulated bench: fake Marlin firmware behind a pyserial URL (marlin.py) on a virtual clock,
the gel + optics simulator (optics.py, indenters.py), its realism check (realism.py), and the two
coupled (bench.py); the simulated ReSkin board behind ``simreskin://`` (reskin.py).

Kept import-light: pyserial imports this package when it looks up the ``simmarlin://`` handler, so
import the simulator from its module: ``from threedcal.sim.optics import GelSimulator``.
"""
