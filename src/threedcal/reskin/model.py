"""A small MLP from baseline-subtracted ReSkin field values to the contact (x, y) and depth (mm).

Inputs are compressed with asinh(b / input_scale_ut): a dipole's field falls as 1/r³, so a chip
right under the ball changes by hundreds of µT while a far one changes by a few; the compression
lets both inform the fit without either swamping it. Inputs and targets are then standardised with
the training set's statistics, which the checkpoint keeps (threedcal.model.checkpoint: the one
checkpoint format of every threedcal model, preset `reskin_mlp`). Training is deterministic: seeded
weights and batch order, `torch_threads` threads, deterministic algorithms — the same settings
give the same bytes of the checkpoint.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn as nn
from tqdm import tqdm

from threedcal.errors import ConfigError
from threedcal.model.checkpoint import FORMAT, FORMAT_VERSION, RESKIN_PRESET, read_checkpoint

TARGETS = ("x_mm", "y_mm", "depth_mm")


@dataclass(frozen=True)
class ReSkinSettings:
    """The `reskin:` block of a scene (see the config schema for each key)."""

    hidden: tuple[int, ...] = (128, 128)
    epochs: int = 300
    batch_size: int = 128
    lr: float = 3e-3
    weight_decay: float = 0.0
    input_scale_ut: float = 20.0
    test_fraction: float = 0.2

    @classmethod
    def from_config(cls, config: Mapping[str, Any] | None) -> ReSkinSettings:
        config = dict(config or {})
        unknown = sorted(set(config) - {f.name for f in fields(cls)})
        if unknown:
            raise ConfigError(f"reskin: unknown key(s) {', '.join(unknown)}")
        if "hidden" in config:
            config["hidden"] = tuple(int(h) for h in config["hidden"])
        return cls(**config)


def build_mlp(n_inputs: int, hidden: tuple[int, ...], n_outputs: int = 3):
    layers: list[nn.Module] = []
    width = n_inputs
    for size in hidden:
        layers += [nn.Linear(width, size), nn.SiLU()]
        width = size
    layers.append(nn.Linear(width, n_outputs))
    return nn.Sequential(*layers)


def _features(inputs: np.ndarray, scale: float) -> np.ndarray:
    return np.arcsinh(np.asarray(inputs, dtype=np.float64) / scale)


def train_mlp(
    inputs: np.ndarray,
    targets: np.ndarray,
    settings: ReSkinSettings,
    *,
    seed: int,
    torch_threads: int = 1,
    names: list[str] | None = None,
    monitor: tuple[np.ndarray, np.ndarray] | None = None,
    progress: bool = False,
) -> tuple[dict[str, Any], list[dict[str, float]]]:
    """Train on (N, F) inputs → (N, 3) targets; returns the checkpoint and one loss row per epoch.

    `monitor` (inputs, targets) is only scored each epoch (its MSE in mm² goes into the loss rows),
    never used to choose anything.
    """
    if len(inputs) == 0:
        raise ConfigError("reskin: no training readings (is the plan or the split empty?)")
    torch.set_num_threads(int(torch_threads))
    torch.use_deterministic_algorithms(True)
    torch.manual_seed(int(seed))
    x = _features(inputs, settings.input_scale_ut)
    y = np.asarray(targets, dtype=np.float64)
    in_mean, in_std = x.mean(0), x.std(0) + 1e-6
    out_mean, out_std = y.mean(0), y.std(0) + 1e-6
    xt = torch.tensor((x - in_mean) / in_std, dtype=torch.float32)
    yt = torch.tensor((y - out_mean) / out_std, dtype=torch.float32)
    model = build_mlp(x.shape[1], settings.hidden)
    optimiser = torch.optim.AdamW(
        model.parameters(), lr=settings.lr, weight_decay=settings.weight_decay
    )
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=settings.epochs)
    generator = torch.Generator().manual_seed(int(seed))
    rows = []
    bar = tqdm(range(settings.epochs), desc="reskin train", unit="epoch", disable=not progress)
    for epoch in bar:
        model.train()
        order = torch.randperm(len(xt), generator=generator)
        total = 0.0
        for start in range(0, len(order), settings.batch_size):
            batch = order[start : start + settings.batch_size]
            optimiser.zero_grad()
            loss = torch.nn.functional.mse_loss(model(xt[batch]), yt[batch])
            loss.backward()
            optimiser.step()
            total += loss.item() * len(batch)
        schedule.step()
        row = {"epoch": epoch + 1, "train_loss": total / len(order)}
        if monitor is not None and len(monitor[0]):
            guess = _predict(model, monitor[0], in_mean, in_std, out_mean, out_std, settings)
            row["test_mse_mm2"] = float(np.mean((guess - monitor[1]) ** 2))
        rows.append(row)
        bar.set_postfix(loss=f"{row['train_loss']:.4f}")

    checkpoint = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "preset": RESKIN_PRESET,
        "preset_args": {"n_inputs": int(x.shape[1]), "hidden": list(settings.hidden)},
        "state_dict": {k: v.detach().clone() for k, v in model.state_dict().items()},
        "normalisation": {
            "input_scale_ut": float(settings.input_scale_ut),
            "in_mean": in_mean.tolist(),
            "in_std": in_std.tolist(),
            "out_mean": out_mean.tolist(),
            "out_std": out_std.tolist(),
        },
        "names": list(names or []),
        "targets": list(TARGETS),
        "settings": {
            k: list(v) if isinstance(v, tuple) else v for k, v in asdict(settings).items()
        },
        "seed": int(seed),
    }
    return checkpoint, rows


def _predict(model, inputs, in_mean, in_std, out_mean, out_std, settings_or_scale) -> np.ndarray:
    scale = getattr(settings_or_scale, "input_scale_ut", settings_or_scale)
    x = (_features(inputs, scale) - in_mean) / in_std
    model.eval()
    with torch.no_grad():
        out = model(torch.tensor(x, dtype=torch.float32)).double().numpy()
    return out * out_std + out_mean


def predict(checkpoint: Mapping[str, Any], inputs: np.ndarray) -> np.ndarray:
    """(N, F) baseline-subtracted readings → (N, 3) x_mm, y_mm, depth_mm."""
    inputs = np.asarray(inputs, dtype=np.float64)
    args, norm = checkpoint["preset_args"], checkpoint["normalisation"]
    if inputs.ndim != 2 or inputs.shape[1] != args["n_inputs"]:
        raise ConfigError(
            f"reskin model expects (N, {args['n_inputs']}) readings, got {inputs.shape}"
        )
    model = build_mlp(args["n_inputs"], tuple(args["hidden"]))
    model.load_state_dict(checkpoint["state_dict"])
    return _predict(
        model,
        inputs,
        np.asarray(norm["in_mean"]),
        np.asarray(norm["in_std"]),
        np.asarray(norm["out_mean"]),
        np.asarray(norm["out_std"]),
        float(norm["input_scale_ut"]),
    )


def read_reskin_model(path: str | Path) -> dict[str, Any]:
    """A ReSkin model's checkpoint (threedcal.model.checkpoint.read_checkpoint: read safely,
    checked); any other model is refused, naming the file."""
    checkpoint = read_checkpoint(path)
    if checkpoint.get("preset") != RESKIN_PRESET:
        raise ConfigError(
            f"{path}: not a threedcal ReSkin model (preset {checkpoint.get('preset')!r})"
        )
    return checkpoint
