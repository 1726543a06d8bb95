"""The simulated bench: fake Marlin firmware behind a pyserial URL (marlin.py) on a virtual clock,
the gel + optics simulator (optics.py, indenters.py), and the two
coupled (bench.py); the simulated ReSkin board behind ``simreskin://`` (reskin.py).

Kept import-light: pyserial imports this package when it looks up the ``simmarlin://`` handler, so
its public names (``from threedcal.sim import GelSimulator, Sphere``) load on first use.
"""

# The simulator's public names, imported on first use (PEP 562) so the package itself stays light.
__all__ = ["Flat", "GelSimulator", "Relief", "Indenter", "SimBench", "Sphere"]


def __getattr__(name: str):
    if name == "GelSimulator":
        from threedcal.sim.optics import GelSimulator

        return GelSimulator
    if name in ("Indenter", "Sphere", "Flat", "Relief"):
        from threedcal.sim.indenters import Flat, Indenter, Relief, Sphere

        return {"Indenter": Indenter, "Sphere": Sphere, "Flat": Flat, "Relief": Relief}[name]
    if name == "SimBench":
        from threedcal.sim.bench import SimBench

        return SimBench
    raise AttributeError(f"module 'threedcal.sim' has no attribute {name!r}")
