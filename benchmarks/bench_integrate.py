"""poisson_dst at 240x320 against the authors' fast_poisson (py3DCal 1.1.0), timed in the same run.

The baseline is the authors' file itself when it is unpacked (`make bench` fetches their wheel into
.cache/py3dcal; or set PY3DCAL_FAST_POISSON). Otherwise it falls back to threedcal's re-expression
of it: same numerics, but on scipy.fft without transposes, so about 2x faster than the original and
a harder baseline. Both get the same gradients, float32 (as a network yields them) and float64; then
the three spectral solvers at every size of the integration study.

poisson_dst transforms short awkward axes by a dense product (BLAS). BLAS runs single-threaded here
unless OPENBLAS_NUM_THREADS says otherwise, as in every workflow job (Snakemake sets it to the
job's threads): on a loaded machine a threaded product of this size waits for a second core and
turns erratic (5-20x slower). Each figure is the median wall-clock ms and, in brackets, the median
CPU ms of this process (steadier when the machine is shared; the ratio uses wall-clock).
"""

import importlib.util
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from threedcal.depth import integrate, py3dcal_fast_poisson  # noqa: E402
from threedcal.depth.scenarios import make_scene  # noqa: E402

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
    """(wall-clock, CPU) median ms per call."""
    fn()  # warm-up: plans and cached eigenvalues
    wall, cpu = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return 1e3 * float(np.median(wall)), 1e3 * float(np.median(cpu))


SIZES = [(240, 320), (320, 240), (480, 640), (960, 1280)]  # the integration study's (paper.yaml)
SPECTRAL = ["poisson_dst", "poisson_dct", "frankot_chellappa"]


def main():
    scene = make_scene("cap", 240, 320)
    fast_poisson, name = baseline()
    workers = os.cpu_count()
    print(
        f"240x320 cap; {workers} CPUs; load average {os.getloadavg()[0]:.1f}; median of {REPEATS}; "
        f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}"
    )
    print(f"baseline: {name}")
    for dtype in (np.float32, np.float64):
        gx = scene.gx.astype(dtype)
        gy = scene.gy.astype(dtype)
        base, base_cpu = median_ms(lambda gx=gx, gy=gy: fast_poisson(gx, gy))
        print(f"{dtype.__name__}: baseline {base:.3f} ms/frame ({base_cpu:.3f} CPU)")
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
            ms, cpu = median_ms(fn)
            print(
                f"  {label}: {ms:.3f} ms/frame ({cpu:.3f} CPU)  -> {base / ms:.2f}x faster than "
                f"the baseline ({base_cpu / cpu:.2f}x in CPU time)"
            )
    print(
        "\nspectral solvers at the integration study's sizes "
        "(median ms/frame wall-clock (CPU), workers=1)"
    )
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
            slowest = max(ms, key=lambda m: ms[m][0])
            cells = " ".join(f"{ms[m][0]:9.2f} ({ms[m][1]:6.2f})" for m in SPECTRAL)
            print(f"{h:>4d}x{w:<5d} {dtype.__name__:>8s} {cells}  {slowest}")


if __name__ == "__main__":
    main()
