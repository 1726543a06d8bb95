"""poisson_dst at 240x320 against the authors' fast_poisson (py3DCal 1.1.0), timed in the same run.

The baseline is the authors' file itself when it is unpacked (`make bench` fetches their wheel into
.cache/py3dcal; or set PY3DCAL_FAST_POISSON). Otherwise it falls back to threedcal's re-expression
of it: same numerics, but on scipy.fft without transposes, so about 2x faster than the original and
a harder baseline. Both get the same gradients, float32 (as a network yields them) and float64; then
the three spectral solvers at every size of the integration study.
"""

import importlib.util
import os
import time
from pathlib import Path

import numpy as np

from threedcal.depth import integrate, py3dcal_fast_poisson
from threedcal.depth.scenarios import make_scene

AUTHORS = Path(
    os.environ.get(
        "PY3DCAL_FAST_POISSON", ".cache/py3dcal/py3DCal/model_training/lib/fast_poisson.py"
    )
)
REPEATS = 60


def baseline():
    if AUTHORS.is_file():
        spec = importlib.util.spec_from_file_location("authors_fast_poisson", AUTHORS)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module.fast_poisson, f"authors' fast_poisson ({AUTHORS})"
    return py3dcal_fast_poisson, "threedcal.depth.py3dcal_fast_poisson (authors' file not found)"


def median_ms(fn, repeats=REPEATS):
    fn()  # warm-up: plans and cached eigenvalues
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


SIZES = [(240, 320), (320, 240), (480, 640), (960, 1280)]  # the integration study's (paper.yaml)
SPECTRAL = ["poisson_dst", "poisson_dct", "frankot_chellappa"]


def main():
    scene = make_scene("cap", 240, 320)
    fast_poisson, name = baseline()
    workers = os.cpu_count()
    print(
        f"240x320 cap; {workers} CPUs; load average {os.getloadavg()[0]:.1f}; median of {REPEATS}"
    )
    print(f"baseline: {name}")
    for dtype in (np.float32, np.float64):
        gx = scene.gx.astype(dtype)
        gy = scene.gy.astype(dtype)
        base = median_ms(lambda gx=gx, gy=gy: fast_poisson(gx, gy))
        print(f"{dtype.__name__}: baseline {base:.3f} ms/frame")
        rows = [
            (
                "poisson_dst workers=1",
                lambda gx=gx, gy=gy: integrate(gx, gy, "poisson_dst", workers=1),
            ),
            (
                f"poisson_dst workers={workers}",
                lambda gx=gx, gy=gy: integrate(gx, gy, "poisson_dst", workers=workers),
            ),
            (
                "poisson_dct workers=1",
                lambda gx=gx, gy=gy: integrate(gx, gy, "poisson_dct", workers=1),
            ),
        ]
        for label, fn in rows:
            ms = median_ms(fn)
            print(f"  {label}: {ms:.3f} ms/frame  -> {base / ms:.2f}x faster than the baseline")
    print("\nspectral solvers at the integration study's sizes (ms/frame, workers=1, median)")
    print(f"{'size':>10s} {'dtype':>8s} " + " ".join(f"{m:>18s}" for m in SPECTRAL) + "  slowest")
    for h, w in SIZES:
        sized = make_scene("cap", h, w)
        repeats = max(5, REPEATS * 76800 // (h * w))
        for dtype in (np.float32, np.float64):
            gx, gy = sized.gx.astype(dtype), sized.gy.astype(dtype)
            ms = {
                m: median_ms(lambda m=m, gx=gx, gy=gy: integrate(gx, gy, m, workers=1), repeats)
                for m in SPECTRAL
            }
            slowest = max(ms, key=ms.get)
            cells = " ".join(f"{ms[m]:18.2f}" for m in SPECTRAL)
            print(f"{h:>4d}x{w:<5d} {dtype.__name__:>8s} {cells}  {slowest}")


if __name__ == "__main__":
    main()
