"""The simulated sensor: gel deformation + optics (optics.py), indenter shapes (indenters.py), and the
realism check against real frames (realism.py)."""

from threedcal.sim.indenters import Flat, HeightMap, Indenter, Sphere
from threedcal.sim.optics import GelSimulator

__all__ = ["Flat", "GelSimulator", "HeightMap", "Indenter", "Sphere"]
