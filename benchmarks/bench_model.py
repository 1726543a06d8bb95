"""Live depth frames/s of DepthEstimator (network + DST Poisson integration) for every preset, from
240×320 camera frames, and training samples/s per preset in float32 and bfloat16.

The baseline is the paper's TouchNet on the same frame (and the same training step) in the same run.
`context_half` (the simulated scenes' network) runs on frames pooled by 2 (dataset.downscale: 2), as
it is trained; the others at the camera's size. Training is timed at the step shape each preset
trains with in the default study, in float32 and in bfloat16 (mixed precision), and the table says
which one `precision: auto` picks on this machine and whether that was the faster one. Each preset is
also timed with the network's tensors in PyTorch's default (contiguous NCHW) layout, the baseline of
the channels-last layout DepthEstimator uses. Weights are freshly initialised (speed does not depend
on their values). Each figure is the median time of single calls, which a busy shared machine
disturbs less than a mean. The first lines name the CPU and its instruction sets.

With --accuracy FOLDER (a ball_folder dataset, e.g. data/gelsight_ball_fots) it also trains
every CPU preset there with BALL_SETTINGS on the seeded 80/20 image split and prints the accuracy per
millisecond table (held-out gradient RMSE and cap depth MAE, threedcal.evaluate.ball_eval).

With --device cuda the same tables are timed on a GPU (the integration stays on the CPU).

Usage: python benchmarks/bench_model.py [--threads N] [--seconds S] [--accuracy FOLDER] [--device D]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from threedcal.evaluate.presets_study import PATCH_BALL_SETTINGS
from threedcal.model import DEFAULT_PRESET, PRESET_NAMES
from threedcal.model.checkpoint import FORMAT, FORMAT_VERSION, OUR_NORMALISATION
from threedcal.model.inference import DepthEstimator
from threedcal.model.losses import gradient_loss
from threedcal.model.machine import host_line, resolve_precision
from threedcal.model.presets import build_model, preferred_memory_format, preset_args
from threedcal.model.train_step import training_autocast

HEIGHT, WIDTH = 240, 320
# The model's frame is the camera's pooled by this (dataset.downscale, as the preset is trained).
POOLING = {"context_half": 2}
# (patches, patch px) of a training step as the default study trains each preset (context_half:
# 4 frames x 4 patches of 48 px, config.yaml's simulated scenes); the rest (64, 64).
STEP_SHAPES = {
    "context_half": (16, 48),
    "context": (16, 64),
    "multiscale": (8, 128),
    "touchnet": (2, 64),
}
# The settings the accuracy table trains with (docs/explanation/models.md, "Choosing a preset").
BALL_SETTINGS = PATCH_BALL_SETTINGS


def estimator(
    preset: str, blank: np.ndarray, channels_last: bool = True, device: str = "cpu"
) -> DepthEstimator:
    """A fresh `preset` for camera frames of blank's size (pooled by POOLING, as it is trained)."""
    torch.manual_seed(0)
    factor = POOLING.get(preset, 1)
    height, width = HEIGHT // factor, WIDTH // factor
    if factor > 1:
        from threedcal.dataset.trainset import pool_to

        blank = pool_to(blank, (height, width))
    checkpoint = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "preset": preset,
        "preset_args": preset_args(preset),
        "state_dict": build_model(preset).state_dict(),
        "normalisation": dict(OUR_NORMALISATION),
        "blank": torch.from_numpy(np.ascontiguousarray(blank, dtype=np.float32)),
        "px_per_mm": 20.0 / factor,
        "image_shape": [height, width],
        "camera": {"lens": None, "downscale": factor},
    }
    return DepthEstimator(checkpoint, device=device, batch_size=1, channels_last=channels_last)


def ms_per_frame(est: DepthEstimator, frame: np.ndarray, seconds: float, calls: int = 3) -> float:
    """Median ms of live depth from one camera frame (pooled to the model's frame, then depth)."""
    est.depth(est.rectify(frame))  # warm-up
    times, began = [], time.perf_counter()
    while len(times) < calls or time.perf_counter() - began < seconds:
        start = time.perf_counter()
        est.depth(est.rectify(frame))
        times.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times))


def training_samples_per_s(
    preset: str,
    seconds: float,
    batch: int = 32,
    patch: int = 64,
    loss: str = "huber",
    layout: torch.memory_format | None = None,
    precision: str = "float32",
    device: str = "cpu",
) -> float:
    """Training samples/s: AdamW steps (forward, loss, backward) on random (batch, 5, patch, patch)
    inputs, the batch, patch and loss the default sim scenes train with; median step time. The
    layout is the trainer's own (NHWC for convolutional presets) unless one is given."""
    torch.manual_seed(0)
    model = build_model(preset)
    parameters = [p for p in model.parameters() if p.requires_grad]
    if not parameters:
        return float("nan")
    layout = preferred_memory_format(model) if layout is None else layout
    model = model.to(device=device, memory_format=layout)
    optimizer = torch.optim.AdamW(parameters, lr=1e-3)
    x = torch.randn(batch, 5, patch, patch).to(device).contiguous(memory_format=layout)
    with torch.no_grad():
        y = torch.randn_like(model(x))

    def step():
        optimizer.zero_grad(set_to_none=True)
        with training_autocast(precision, x.device):
            prediction = model(x)
        gradient_loss(prediction.float(), y, loss).backward()
        optimizer.step()
        if x.device.type == "cuda":
            torch.cuda.synchronize()  # time the work, not its launch

    step()  # warm-up
    times, began = [], time.perf_counter()
    while len(times) < 2 or time.perf_counter() - began < seconds:
        start = time.perf_counter()
        step()
        times.append(time.perf_counter() - start)
    return batch / float(np.median(times))


def accuracy(folder: Path, presets: list[str], threads: int) -> dict[str, dict]:
    """Held-out ball_eval figures of each preset trained with BALL_SETTINGS on `folder`."""
    from threedcal.evaluate.ball_eval import evaluate
    from threedcal.model.train import TrainSettings, train
    from threedcal.study.dataset_stage import import_stage

    scene = {
        "import": {"format": "ball_folder", "path": str(folder)},
        "seed": 0,
        "dataset": {"downscale": 1, "max_slope_deg": 75},
    }
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        ts = import_stage(
            scene,
            Path(tmp) / "trainset",
            Path(tmp) / "splits.csv",
        )
        test = ts.indices("val")
        for preset in presets:
            settings = TrainSettings.of(preset=preset, torch_threads=threads, **BALL_SETTINGS)
            began = time.perf_counter()
            checkpoint = train(ts, Path(tmp) / preset, 80, settings, progress=False)
            seconds = time.perf_counter() - began
            torch.set_num_threads(threads)
            out[preset] = {
                **evaluate(DepthEstimator(checkpoint, device="cpu"), ts, test),
                "train_s": seconds,
            }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument("--seconds", type=float, default=2.0, help="timing per preset")
    parser.add_argument("--accuracy", type=Path, help="ball_folder dataset for the accuracy table")
    parser.add_argument("--device", default="cpu", help="cpu, cuda, ... (inference and training)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"host: {host_line()}")
    rng = np.random.default_rng(0)
    blank = rng.uniform(60, 200, (HEIGHT, WIDTH, 3)).astype(np.float32)
    frame = np.clip(blank + rng.normal(0, 20, blank.shape), 0, 255).astype(np.uint8)
    where = (
        "CPU"
        if args.device == "cpu"
        else f"{args.device} ({torch.cuda.get_device_name(args.device)})"
    )
    print(f"live depth from {HEIGHT}x{WIDTH} camera frames, {where}, torch threads {args.threads}")
    # TouchNet takes seconds a frame on a CPU: there one timed call is its figure
    slow = {"touchnet"} if args.device == "cpu" else set()
    ms = {
        p: ms_per_frame(
            estimator(p, blank, device=args.device),
            frame,
            0.0 if p in slow else args.seconds,
            1 if p in slow else 3,
        )
        for p in PRESET_NAMES
    }
    nchw = {
        p: ms_per_frame(
            estimator(p, blank, channels_last=False, device=args.device), frame, args.seconds
        )
        for p in PRESET_NAMES
        if p != "touchnet"
    }
    base = ms["touchnet"]
    print(
        f"{'preset':14s} {'model frame':>12s} {'frames/s':>9s} {'ms/frame':>9s} {'x touchnet':>11s} "
        f"{'NCHW ms':>8s} {'x NCHW':>7s}"
    )
    for preset, value in ms.items():
        mark = "  (default)" if preset == DEFAULT_PRESET else ""
        factor = POOLING.get(preset, 1)
        size = f"{HEIGHT // factor}x{WIDTH // factor}"
        layout = (
            f"{nchw[preset]:8.1f} {nchw[preset] / value:6.2f}x" if preset in nchw else f"{'':16s}"
        )
        print(
            f"{preset:14s} {size:>12s} {1000 / value:9.2f} {value:9.1f} {base / value:10.0f}x "
            f"{layout}{mark}"
        )
    auto = resolve_precision("auto", torch.device(args.device))
    print(
        f"\ntraining samples/s (AdamW steps, huber loss, the study's step shape); "
        f"precision: auto picks {auto} here"
    )
    print(
        f"{'preset':14s} {'batch x patch':>13s} {'float32':>9s} {'bfloat16':>9s} {'bf16/fp32':>10s} "
        f"{'NCHW fp32':>10s} {'auto':>9s}"
    )
    for preset in PRESET_NAMES:
        batch, patch = STEP_SHAPES.get(preset, (64, 64))
        rates = {
            precision: training_samples_per_s(
                preset, args.seconds, batch, patch, precision=precision, device=args.device
            )
            for precision in ("float32", "bfloat16")
        }
        if not np.isfinite(rates["float32"]):
            print(f"{preset:14s} {'':13s} {'(no gradient training)':>22s}")
            continue
        nchw_rate = training_samples_per_s(
            preset, args.seconds, batch, patch, layout=torch.contiguous_format, device=args.device
        )
        faster = max(rates, key=rates.get)
        verdict = f"{auto}" + (" (faster)" if auto == faster else f" ({faster} faster)")
        print(
            f"{preset:14s} {f'{batch} x {patch}':>13s} {rates['float32']:9.1f} "
            f"{rates['bfloat16']:9.1f} {rates['bfloat16'] / rates['float32']:9.2f}x "
            f"{nchw_rate:10.1f} {verdict}"
        )
    if args.accuracy is None:
        return
    cpu = [p for p in PRESET_NAMES if p != "touchnet"]
    figures = accuracy(args.accuracy, cpu, 1)
    lookup = figures["lookup"]
    print(f"\naccuracy per ms on {args.accuracy} (held-out images: {lookup['n_test_images']})")
    print(
        f"{'preset':14s} {'ms/frame':>9s} {'grad_rmse':>10s} {'depth_mae_um':>13s} "
        f"{'rmse/lookup':>12s} {'mae/lookup':>11s} {'train_s':>8s}"
    )
    for preset in cpu:
        f = figures[preset]
        mark = "  (default)" if preset == DEFAULT_PRESET else ""
        print(
            f"{preset:14s} {ms[preset]:9.1f} {f['gradient_rmse']:10.3f} "
            f"{f['cap_depth_mae_um']:13.0f} {f['gradient_rmse'] / lookup['gradient_rmse']:12.2f} "
            f"{f['cap_depth_mae_um'] / lookup['cap_depth_mae_um']:11.2f} {f['train_s']:8.1f}{mark}"
        )


if __name__ == "__main__":
    main()
