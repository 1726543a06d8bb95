"""What keeping freed memory in the process (threedcal.model.allocator) buys: `context_half` live
depth frames/s from 240x320 camera frames and training samples/s (the arithmetic `precision: auto`
picks here, its study's step shape), each in a fresh process with glibc's default thresholds (the
baseline) and with reuse_freed_memory().

The setting is process-wide and cannot be undone, hence one subprocess per measurement.

Usage: python benchmarks/bench_allocator.py [--threads N] [--seconds S]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

MEASURE = """
import json, sys
sys.path.insert(0, {here!r})
import numpy as np, torch
import threedcal.model.allocator as allocator
if sys.argv[1] == "default":
    allocator._done = False  # as if the setting had been refused: glibc's thresholds stay
import bench_model
torch.set_num_threads({threads})
rng = np.random.default_rng(0)
blank = rng.uniform(60, 200, (bench_model.HEIGHT, bench_model.WIDTH, 3)).astype(np.float32)
frame = np.clip(blank + rng.normal(0, 20, blank.shape), 0, 255).astype(np.uint8)
ms = bench_model.ms_per_frame(bench_model.estimator("context_half", blank), frame, {seconds})
precision = bench_model.resolve_precision("auto", torch.device("cpu"))
batch, patch = bench_model.STEP_SHAPES["context_half"]
rate = bench_model.training_samples_per_s("context_half", {seconds}, batch, patch, precision=precision)
print(json.dumps({{"frames_per_s": 1000 / ms, "samples_per_s": rate}}))
"""


def measure(mode: str, threads: int, seconds: float) -> dict:
    code = MEASURE.format(here=str(Path(__file__).parent), threads=threads, seconds=seconds)
    run = subprocess.run(
        [sys.executable, "-c", code, mode], capture_output=True, text=True, check=True
    )
    return json.loads(run.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=3.0)
    args = parser.parse_args()
    base = measure("default", args.threads, args.seconds)
    reuse = measure("reuse", args.threads, args.seconds)
    print(
        f"context_half from 240x320 frames, torch threads {args.threads}: glibc default -> "
        "freed memory reused"
    )
    for key, label in (("frames_per_s", "depth frames/s"), ("samples_per_s", "training samples/s")):
        print(f"{label:20s} {base[key]:8.1f} -> {reuse[key]:8.1f}  ({reuse[key] / base[key]:.2f}x)")


if __name__ == "__main__":
    main()
