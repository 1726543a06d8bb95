"""poisson_dst at 240x320 against the authors' fast_poisson (py3DCal 1.1.0), timed in the same run.

The baseline is the authors' file itself when it is unpacked (`make bench` fetches their wheel into
.cache/py3dcal; or set PY3DCAL_FAST_POISSON). Otherwise it falls back to threedcal's re-expression
of it: same numerics, but on scipy.fft without transposes, so about 2x faster than the original and
a harder baseline. Both get the same float32 gradients, as a TouchNet forward pass yields them.
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


def main():
    scene = make_scene("cap", 240, 320)
    gx = scene.gx.astype(np.float32)
    gy = scene.gy.astype(np.float32)
    fast_poisson, name = baseline()
    workers = os.cpu_count()
    print(f"240x320 float32 gradients; {os.cpu_count()} CPUs; median of {REPEATS} runs")
    base = median_ms(lambda: fast_poisson(gx, gy))
    print(f"baseline  {name}: {base:.3f} ms/frame")
    rows = [
        ("poisson_dst float32 workers=1", lambda: integrate(gx, gy, "poisson_dst", workers=1)),
        (
            f"poisson_dst float32 workers={workers}",
            lambda: integrate(gx, gy, "poisson_dst", workers=workers),
        ),
        (
            "poisson_dst float64 workers=1",
            lambda: integrate(scene.gx, scene.gy, "poisson_dst", workers=1),
        ),
        ("poisson_dct float32 workers=1", lambda: integrate(gx, gy, "poisson_dct", workers=1)),
    ]
    for label, fn in rows:
        ms = median_ms(fn)
        print(f"{label}: {ms:.3f} ms/frame  -> {base / ms:.2f}x faster than the baseline")


if __name__ == "__main__":
    main()
