"""The settings one training reads (the scene's `model:` section, seed, threads) and its
learning-rate schedule."""

from __future__ import annotations

import math
from dataclasses import dataclass

from threedcal.errors import ConfigError
from threedcal.schema import load_schema, section


def _or(value, default):
    return default if value is None else value


@dataclass(frozen=True)
class TrainSettings:
    """Every setting a training reads: the scene's `model:` section plus seed and threads.

    No defaults of its own: `of` fills what a config leaves out from the config
    schema, so the schema is the one place a default is written.
    """

    preset: str
    epochs_base: int
    batch_size: int
    lr: float
    lr_schedule: str  # constant or cosine (scheduled_lr)
    weight_decay: float
    loss: str  # per-pixel loss on the gradient (threedcal.model.losses)
    init: str | None
    patch_px: int
    contact_patches: int
    background_patches: int
    skirt_reach: float  # contact-patch centres up to this many contact radii off the centre
    drift: str  # lighting-drift removal of the inputs (threedcal.model.drift)
    seed: int
    torch_threads: int
    device: str  # auto = CUDA when present, else CPU
    precision: str  # auto (threedcal.model.machine), float32, or bfloat16 autocast of the steps
    stopping: dict  # the stopping rule (threedcal.model.stopping)

    @classmethod
    def of(cls, **settings) -> TrainSettings:
        """Settings from `model:` keys plus seed and torch_threads; the schema fills the rest."""
        schema = load_schema("config")
        model = section(
            "model", {k: v for k, v in settings.items() if k not in ("seed", "torch_threads")}
        )
        top = schema["properties"]
        return cls(
            seed=int(_or(settings.get("seed"), top["seed"]["default"])),
            torch_threads=int(_or(settings.get("torch_threads"), top["torch_threads"]["default"])),
            **model,
        )

    def epochs(self, percent: int) -> int:
        """epochs_base · 80 / P (the paper keeps the number of gradient steps roughly constant)."""
        if not 1 <= percent <= 80:
            raise ConfigError(f"training fraction P must be 1..80 percent, got {percent}")
        return max(1, round(self.epochs_base * 80 / percent))


def scheduled_lr(
    settings: TrainSettings, epoch: int, epochs: int, batch: int, batches: int
) -> float:
    """Learning rate of batch 0..batches-1 of epoch 1..epochs: constant, or a half cosine over the
    run's steps from lr down to lr/100.

    Per step, not per epoch: P = 80 % trains 4 epochs, and a rate held for a whole epoch spent its
    last quarter at lr/100 (its validation MSE about 5 % worse, docs/explanation/statistics.md, The learning-rate
    schedule), while P = 1 % (320 epochs) annealed smoothly: the fractions did not get the same
    schedule. A function of the position alone, so a resumed run uses the same rates.
    """
    if settings.lr_schedule == "constant":
        return settings.lr
    if settings.lr_schedule != "cosine":
        raise ConfigError(
            f"model.lr_schedule: {settings.lr_schedule!r} (allowed: constant, cosine)"
        )
    progress = ((epoch - 1) + batch / max(batches, 1)) / epochs
    floor = settings.lr / 100
    return floor + (settings.lr - floor) * 0.5 * (1 + math.cos(math.pi * progress))
