"""How fast `threedcal rig`'s status answers while the page's collection runs on the simulated bench
(the goal: under 200 ms), against the same status with the rig idle (the baseline, same run).

The scene: a simulated DIGIT (digit_fots), a 1 mm grid after the touch search and registration
presses; the status is asked over HTTP every 20 ms for as long as the collection runs.

Usage: python benchmarks/bench_rig_page.py [--spacing-mm S]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np
import yaml

from threedcal.page.control import RigControl
from threedcal.page.server import serving
from threedcal.profiles import load_profile


def status_ms(url: str) -> float:
    started = time.perf_counter()
    with urllib.request.urlopen(url + "api/status", timeout=30) as response:
        json.loads(response.read())
    return 1000 * (time.perf_counter() - started)


def summary(name: str, values: list[float]) -> str:
    v = np.asarray(values)
    return (
        f"{name:22s} n={len(v):4d}  median {np.median(v):6.1f} ms  p95 {np.percentile(v, 95):6.1f}"
        f" ms  max {v.max():6.1f} ms"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spacing-mm", type=float, default=1.0)
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="bench-rig-page-"))
    (folder / "mount.yaml").write_text(
        yaml.safe_dump(load_profile("sensor", "digit_fots")["mount"])
    )
    scene = {
        "sensor": "digit_fots",
        "printer": "ender3",
        "port": "sim",
        "mount": str(folder / "mount.yaml"),
        "plan": {"spacing_mm": args.spacing_mm, "depth_mm": 1.0, "frames": 1},
    }
    (folder / "rig.yaml").write_text(yaml.safe_dump({"scenes": {"bench": scene}}))
    os.chdir(folder)  # the collection's store: results/bench/raw.zarr there
    with (
        RigControl(folder / "rig.yaml", "bench") as control,
        serving(control) as url,
    ):
        idle = [status_ms(url) for _ in range(50)]
        request = urllib.request.Request(url + "api/collect", data=b"{}", method="POST")
        urllib.request.urlopen(request, timeout=60).read()
        running, started = [], time.monotonic()
        while control.collection.get("state") == "running":
            running.append(status_ms(url))
            time.sleep(0.02)
        took = time.monotonic() - started
        rows = control.collection.get("rows_total")
    cpu = next(
        (
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")
        ),
        platform.processor(),
    )
    print(f"host: {cpu}, {platform.python_version()}")
    print(f"collection: {rows} plan rows in {took:.1f} s on the simulated bench")
    print(summary("status, rig idle", idle))
    print(summary("status, collecting", running))


if __name__ == "__main__":
    main()
