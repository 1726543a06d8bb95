"""Frames/s of an exported model in onnxruntime against the same model in torch, at 240×320.

For the presets the default study trains (`compact`, `context`, `multiscale`; freshly initialised
weights: speed does not depend on their values), the ONNX graph of `threedcal export` runs in
onnxruntime and `DepthEstimator.gradients` in torch (channels-last), on the same real DIGIT frame
(data/digit_frames_fots, turned to 240×320) with the same thread count.
Both compute the same thing: frame in, gradients out (blank, drift, coordinate channels, network). The two
are timed in alternating blocks of calls, so a busy shared machine disturbs both alike; each figure
is the median time of single-frame calls. The baseline is torch, in the same run.

Usage: python benchmarks/bench_export.py [--threads N] [--rounds R]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from bench_model import estimator  # the same freshly initialised 240 x 320 models

from threedcal.images import read_rgb
from threedcal.model.export import export_onnx, onnx_gradients, onnx_session
from threedcal.model.machine import host_line

DATA = Path(__file__).resolve().parents[1] / "data" / "digit_frames_fots"
PRESETS = ("compact", "context_half", "context", "multiscale")
BLOCK = 10  # calls per block; torch and onnxruntime alternate block by block


def median_ms(runs: dict, rounds: int) -> dict[str, float]:
    """Median ms per call of each callable, timed in alternating blocks of BLOCK calls."""
    times: dict[str, list[float]] = {name: [] for name in runs}
    for run in runs.values():
        run()  # warm-up
    for _ in range(rounds):
        for name, run in runs.items():
            for _ in range(BLOCK):
                began = time.perf_counter()
                run()
                times[name].append(time.perf_counter() - began)
    return {name: 1000.0 * float(np.median(t)) for name, t in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    # a real DIGIT frame (320 x 240) turned to bench_model's 240 x 320
    blank = np.ascontiguousarray(np.rot90(read_rgb(DATA / "background.png"))).astype(np.float32)
    frame = np.ascontiguousarray(np.rot90(read_rgb(DATA / "0010.png")))
    height, width = frame.shape[:2]
    print(f"{height}x{width} frame, {args.threads} threads, torch {torch.__version__}", end="")
    import onnxruntime

    print(f", onnxruntime {onnxruntime.__version__}")
    print(
        f"host: {host_line()} (onnxruntime picks its kernels from CPUID alone: the limits bind torch only)"
    )
    print(f"{'preset':<12}{'torch f/s':>10}{'onnx f/s':>10}{'onnx/torch':>12}")
    with tempfile.TemporaryDirectory() as tmp:
        for preset in PRESETS:
            est = estimator(preset, blank)
            model_frame = est.rectify(frame)  # pooled to the model's frame (context_half: by 2)
            path = Path(tmp) / f"{preset}.onnx"
            export_onnx(est, path)
            session = onnx_session(path, threads=args.threads)
            ms = median_ms(
                {
                    "torch": lambda est=est, f=model_frame: est.gradients(f),
                    "onnx": lambda session=session, f=model_frame: onnx_gradients(session, f[None]),
                },
                args.rounds,
            )
            print(
                f"{preset:<12}{1000 / ms['torch']:>10.1f}{1000 / ms['onnx']:>10.1f}"
                f"{ms['torch'] / ms['onnx']:>11.2f}x"
            )


if __name__ == "__main__":
    main()
