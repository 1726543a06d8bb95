"""Frames/s of DepthEstimator.depth (network + DST Poisson integration) for every preset at 240×320.

The baseline is the paper's TouchNet on the same frame in the same run; the goal for the default CPU
preset is ≥ 30 frames/s and ≥ 100× TouchNet. Weights are freshly initialised (speed does not depend
on their values). Usage: python benchmarks/bench_model.py [--threads N] [--seconds S]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from threedcal.model import DEFAULT_PRESET, PRESET_NAMES
from threedcal.model.checkpoint import FORMAT, FORMAT_VERSION, OUR_NORMALISATION
from threedcal.model.inference import DepthEstimator
from threedcal.model.presets import build_model, preset_args

HEIGHT, WIDTH = 240, 320


def estimator(preset: str, blank: np.ndarray) -> DepthEstimator:
    torch.manual_seed(0)
    checkpoint = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "preset": preset,
        "preset_args": preset_args(preset),
        "state_dict": build_model(preset).state_dict(),
        "normalisation": dict(OUR_NORMALISATION),
        "blank": torch.from_numpy(blank),
        "px_per_mm": 20.0,
        "image_shape": [HEIGHT, WIDTH],
    }
    return DepthEstimator(checkpoint, device="cpu", batch_size=1)


def frames_per_s(est: DepthEstimator, frame: np.ndarray, seconds: float) -> float:
    est.depth(frame)  # warm-up
    count, began = 0, time.perf_counter()
    while count < 3 or time.perf_counter() - began < seconds:
        est.depth(frame)
        count += 1
    return count / (time.perf_counter() - began)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument("--seconds", type=float, default=3.0, help="timing per preset")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    blank = rng.uniform(60, 200, (HEIGHT, WIDTH, 3)).astype(np.float32)
    frame = np.clip(blank + rng.normal(0, 20, blank.shape), 0, 255).astype(np.uint8)
    print(f"DepthEstimator.depth at {HEIGHT}x{WIDTH}, CPU, torch threads {args.threads}")
    fps = {p: frames_per_s(estimator(p, blank), frame, args.seconds) for p in PRESET_NAMES}
    base = fps["touchnet"]
    print(f"{'preset':14s} {'frames/s':>10s} {'ms/frame':>10s} {'x touchnet':>11s}")
    for preset, value in fps.items():
        mark = "  (default)" if preset == DEFAULT_PRESET else ""
        print(f"{preset:14s} {value:10.2f} {1000 / value:10.1f} {value / base:10.0f}x{mark}")


if __name__ == "__main__":
    main()
