"""The simulated bench: fake Marlin firmware behind a pyserial URL (marlin.py) on a virtual clock,
the gel + optics simulator (optics.py, indenters.py), and the two
coupled (bench.py); the simulated ReSkin board behind ``simreskin://`` (reskin.py).
"""

from threedcal.sim.bench import SimBench
from threedcal.sim.indenters import Flat, Indenter, Relief, Sphere
from threedcal.sim.optics import GelSimulator

__all__ = ["Flat", "GelSimulator", "Relief", "Indenter", "SimBench", "Sphere"]
