"""One optimiser step, one pass over patches, and the loss on a fixed set of checked windows."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import torch

from threedcal.errors import TrainingError
from threedcal.model.checkpoint import adapt_inputs
from threedcal.model.losses import gradient_loss
from threedcal.model.patches import input_batches, sample_windows
from threedcal.model.presets import preferred_memory_format
from threedcal.model.train_settings import TrainSettings, scheduled_lr


def windows_mse(model, ts, windows, settings, device, normalisation, inputs) -> float:
    if not windows:
        return float("nan")
    model.eval()
    total, count = 0.0, 0
    sign = normalisation["gradient_sign"]
    layout = preferred_memory_format(model)
    with torch.no_grad():
        for x, y in input_batches(ts, windows, settings.batch_size, inputs):
            x = adapt_inputs(x.to(device), normalisation, ts.image_shape)
            x = x.contiguous(memory_format=layout)
            pred = model(x) * sign
            total += float(gradient_loss(pred, y.to(device), settings.loss)) * y.numel()
            count += y.numel()
    return total / count


def loss_row(epoch, step, train_loss, val_loss, seconds, lr) -> dict:
    return {
        "epoch": epoch,
        "step": int(step),
        "train_loss": train_loss,
        "val_loss": val_loss,
        "seconds": seconds,
        "lr": lr,
    }


def make_optimizer(model, settings: TrainSettings):
    return torch.optim.AdamW(model.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)


# Validation runs on at most this many patches and at most this many epochs (spread evenly, the
# last always): a P = 1 % model trains 80x the epochs of P = 80 % on 1/80 of the data, and
# validating every epoch would cost more than its training.
VALIDATION_WINDOWS = 128


VALIDATION_POINTS = 25


def validation_epochs(epochs: int) -> set[int]:
    return set(
        np.unique(
            np.round(np.linspace(1, epochs, min(epochs, VALIDATION_POINTS))).astype(int)
        ).tolist()
    )


def validation_settings(settings: TrainSettings) -> TrainSettings:
    return replace(settings, contact_patches=1, background_patches=1)


def train_epoch(
    model,
    ts,
    train_idx,
    settings,
    rng,
    device,
    optimizer,
    normalisation,
    inputs,
    position,
    precision="float32",
) -> tuple[float, int]:
    """One pass over patches of the training frames: (mean loss, optimiser steps); the rate
    scheduled per batch over (epoch, epochs) = `position` (the `epochs` rule)."""
    windows = sample_windows(ts, train_idx, settings, rng)
    order = rng.permutation(len(windows))
    windows = [windows[k] for k in order]
    total, count = 0.0, 0
    batches = -(-len(windows) // settings.batch_size)
    for batch, (x, y) in enumerate(input_batches(ts, windows, settings.batch_size, inputs)):
        for group in optimizer.param_groups:
            group["lr"] = scheduled_lr(settings, *position, batch, batches)
        try:
            value = optimizer_step(
                model, ts, settings, device, optimizer, normalisation, x, y, precision
            )
        except TrainingError as exc:
            raise TrainingError(f"the loss of batch {batch + 1} is {exc}") from None
        total += value * len(x)
        count += len(x)
    return total / count, batches


def optimizer_step(model, ts, settings, device, optimizer, normalisation, x, y, precision) -> float:
    """Forward, loss, backward and update on one batch; the loss (a TrainingError holding the
    value where it is not finite)."""
    model.train()
    x = adapt_inputs(x.to(device), normalisation, ts.image_shape)
    x = x.contiguous(memory_format=preferred_memory_format(model))
    optimizer.zero_grad(set_to_none=True)
    with training_autocast(precision, device):
        prediction = model(x)
    loss = gradient_loss(
        prediction.float() * normalisation["gradient_sign"], y.to(device), settings.loss
    )
    value = float(loss.detach())
    if not math.isfinite(value):
        raise TrainingError(str(value))
    loss.backward()
    optimizer.step()
    return value


def divergence_hint(precision: str) -> str:
    if precision == "bfloat16":
        return (
            "model.precision is bfloat16, whose gradients are not finite for some networks on "
            "some CPUs (multiscale's 24-channel dilated convolutions in channels-last, torch "
            "2.13): set model.precision: float32 (docs/explanation/models.md)"
        )
    return "lower model.lr, or look for non-finite labels in the dataset"


def training_autocast(precision: str, device: torch.device):
    """Mixed precision for a resolved `bfloat16`: convolutions in bfloat16, weights stay float32."""
    return torch.autocast(
        device_type=device.type, dtype=torch.bfloat16, enabled=precision == "bfloat16"
    )
