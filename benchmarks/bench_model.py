"""Frames/s of DepthEstimator.depth (network + DST Poisson integration) for every preset at 240×320,
and training samples/s per preset.

The baseline is the paper's TouchNet on the same frame (and the same training batch) in the same run; the goal for the
presets the default scenes train is ≥ 30 frames/s and ≥ 100× TouchNet. Training is timed in float32 and in
`precision: bfloat16` (mixed precision, what the simulated scenes train with), the float32 step as baseline. Each preset is also timed with the network's
tensors in PyTorch's default (contiguous NCHW) layout, the baseline of the channels-last layout DepthEstimator uses. Weights are freshly initialised (speed does not depend
on their values). Each figure is the median time of single-frame calls, which a busy shared machine
disturbs less than a mean.

With --accuracy FOLDER (a ball_folder dataset, e.g. data/gelsight_ball_fots) it also trains
every CPU preset there with BALL_SETTINGS on the seeded 80/20 image split and prints the accuracy per
millisecond table (held-out gradient RMSE and cap depth MAE, threedcal.model.ball_eval).

Usage: python benchmarks/bench_model.py [--threads N] [--seconds S] [--accuracy FOLDER]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from threedcal.model import DEFAULT_PRESET, PRESET_NAMES
from threedcal.model.checkpoint import FORMAT, FORMAT_VERSION, OUR_NORMALISATION
from threedcal.model.inference import DepthEstimator
from threedcal.model.losses import gradient_loss
from threedcal.model.presets import build_model, preferred_memory_format, preset_args
from threedcal.model.train import training_autocast

HEIGHT, WIDTH = 240, 320
# The settings the accuracy table trains with, as an imported ball scene's `model:` section would set
# them (docs/models.md, "Choosing a preset"); chosen on an inner validation split of the training images.
BALL_SETTINGS = dict(
    lr=3e-3,
    lr_schedule="cosine",
    epochs_base=20,
    batch_size=16,
    patch_px=48,
    contact_patches=16,
    background_patches=32,
    skirt_reach=2.5,
)


def estimator(preset: str, blank: np.ndarray, channels_last: bool = True) -> DepthEstimator:
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
    return DepthEstimator(checkpoint, device="cpu", batch_size=1, channels_last=channels_last)


def ms_per_frame(est: DepthEstimator, frame: np.ndarray, seconds: float) -> float:
    est.depth(frame)  # warm-up
    times, began = [], time.perf_counter()
    while len(times) < 3 or time.perf_counter() - began < seconds:
        start = time.perf_counter()
        est.depth(frame)
        times.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times))


def training_samples_per_s(
    preset: str,
    seconds: float,
    batch: int = 32,
    patch: int = 64,
    loss: str = "normal",
    layout: torch.memory_format | None = None,
    precision: str = "float32",
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
    model = model.to(memory_format=layout)
    optimizer = torch.optim.AdamW(parameters, lr=1e-3)
    x = torch.randn(batch, 5, patch, patch).contiguous(memory_format=layout)
    with torch.no_grad():
        y = torch.randn_like(model(x))

    def step():
        optimizer.zero_grad(set_to_none=True)
        with training_autocast(precision, x.device):
            prediction = model(x)
        gradient_loss(prediction.float(), y, loss).backward()
        optimizer.step()

    step()  # warm-up
    times, began = [], time.perf_counter()
    while len(times) < 3 or time.perf_counter() - began < seconds:
        start = time.perf_counter()
        step()
        times.append(time.perf_counter() - start)
    return batch / float(np.median(times))


def accuracy(folder: Path, presets: list[str], threads: int) -> dict[str, dict]:
    """Held-out ball_eval figures of each preset trained with BALL_SETTINGS on `folder`."""
    from threedcal.dataset.build import build_imported
    from threedcal.model.ball_eval import evaluate
    from threedcal.model.train import TrainSettings, train

    scene = {
        "import": {"format": "ball_folder", "path": str(folder)},
        "seed": 0,
        "dataset": {"downscale": 1, "max_slope_deg": 75},
    }
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        ts = build_imported(scene, Path(tmp) / "trainset", Path(tmp) / "splits.csv")
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
    parser.add_argument("--seconds", type=float, default=3.0, help="timing per preset")
    parser.add_argument("--accuracy", type=Path, help="ball_folder dataset for the accuracy table")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    blank = rng.uniform(60, 200, (HEIGHT, WIDTH, 3)).astype(np.float32)
    frame = np.clip(blank + rng.normal(0, 20, blank.shape), 0, 255).astype(np.uint8)
    print(f"DepthEstimator.depth at {HEIGHT}x{WIDTH}, CPU, torch threads {args.threads}")
    ms = {p: ms_per_frame(estimator(p, blank), frame, args.seconds) for p in PRESET_NAMES}
    nchw = {
        p: ms_per_frame(estimator(p, blank, channels_last=False), frame, args.seconds)
        for p in PRESET_NAMES
        if p != "touchnet"
    }
    base = ms["touchnet"]
    print(
        f"{'preset':14s} {'frames/s':>10s} {'ms/frame':>10s} {'x touchnet':>11s} "
        f"{'NCHW ms':>8s} {'x NCHW':>7s}"
    )
    for preset, value in ms.items():
        mark = "  (default)" if preset == DEFAULT_PRESET else ""
        layout = (
            f"{nchw[preset]:8.1f} {nchw[preset] / value:6.2f}x" if preset in nchw else f"{'':16s}"
        )
        print(
            f"{preset:14s} {1000 / value:10.2f} {value:10.1f} {base / value:10.0f}x {layout}{mark}"
        )
    rates = {p: training_samples_per_s(p, args.seconds) for p in PRESET_NAMES}
    nchw_rates = {
        p: training_samples_per_s(p, args.seconds, layout=torch.contiguous_format)
        for p in PRESET_NAMES
    }
    bf16_rates = {
        p: training_samples_per_s(p, args.seconds, precision="bfloat16") for p in PRESET_NAMES
    }
    base = rates["touchnet"]
    print(
        f"\ntraining, batch of 32 patches 64x64, normal loss: {'samples/s':>10s} {'x touchnet':>11s}"
        f" {'NCHW':>8s} {'x NCHW':>7s} {'bfloat16':>9s} {'x fp32':>7s}"
    )
    for preset, rate in rates.items():
        if np.isfinite(rate):
            print(
                f"{preset:14s} {'':35s} {rate:10.1f} {rate / base:10.1f}x"
                f" {nchw_rates[preset]:8.1f} {rate / nchw_rates[preset]:6.2f}x"
                f" {bf16_rates[preset]:9.1f} {bf16_rates[preset] / rate:6.2f}x"
            )
        else:
            print(f"{preset:14s} {'':35s} {'(no gradient training)':>22s}")
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
