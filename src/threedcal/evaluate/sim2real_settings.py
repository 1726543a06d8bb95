"""The scene's `sim_to_real` section read into settings, and how the chosen folds group into
pretrainings: what the workflow needs to plan the sim-to-real jobs, without loading a model."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from threedcal.errors import ConfigError
from threedcal.schema import section

CONDITIONS = {"sim_real": "sim+real", "real_only": "real-only", "shipped_real": "shipped+real"}


# The scene's own cross-validated model (ball_eval's, the scene's full training budget) at k = all.
SCENE_MODEL = "scene model"


ERROR_COLUMNS = (
    "k",
    "n_train",
    "condition",
    "fold",
    "n_test_images",
    "gradient_rmse",
    "gradient_rmse_lo",
    "gradient_rmse_hi",
    "cap_depth_mae_um",
    "cap_depth_mae_um_lo",
    "cap_depth_mae_um_hi",
    "predicted_at",
    "scored_at",
)


# Evaluation disc of a simulated press: the contact shrunk as the ball importer shrinks it.
EVAL_SHRINK = 0.9


@dataclass(frozen=True)
class SimToRealSettings:
    """The scene's `sim_to_real:` section; the config schema fills its defaults."""

    enabled: bool
    frames: int
    depth_mm: tuple[float, float]
    profile: str
    pretrain_epochs: int
    finetune_epochs: int
    k: tuple[int | str, ...]
    folds: tuple[int, ...] | None
    shipped: bool
    shipped_lr: float

    @classmethod
    def of(cls, **settings) -> SimToRealSettings:
        values = section("sim_to_real", settings)
        lo, hi = (float(v) for v in values["depth_mm"])
        if not lo < hi:
            raise ConfigError(f"sim_to_real.depth_mm must be [shallow, deep], got {[lo, hi]}")
        folds = values["folds"]
        return cls(
            enabled=bool(values["enabled"]),
            frames=int(values["frames"]),
            depth_mm=(lo, hi),
            profile=str(values["profile"]),
            pretrain_epochs=int(values["pretrain_epochs"]),
            finetune_epochs=int(values["finetune_epochs"]),
            k=tuple(values["k"]),
            folds=None if folds is None else tuple(int(f) for f in folds),
            shipped=bool(values["shipped"]),
            shipped_lr=float(values["shipped_lr"]),
        )

    @property
    def conditions(self) -> tuple[str, ...]:
        """The trained conditions (CONDITIONS' keys): shipped_real only with `shipped`."""
        return tuple(c for c in CONDITIONS if c != "shipped_real" or self.shipped)


def chosen_folds(settings: SimToRealSettings, n_folds: int) -> list[int]:
    """The evaluated folds: `sim_to_real.folds`, or all `cv.folds` of them."""
    if settings.folds is None:
        return list(range(n_folds))
    bad = [f for f in settings.folds if not 0 <= f < n_folds]
    if bad:
        raise ConfigError(
            f"sim_to_real.folds: {bad} outside the {n_folds} cross-validation folds (cv.folds)"
        )
    return sorted(settings.folds)


def pretraining_groups(settings: SimToRealSettings, n_folds: int) -> list[tuple[int, ...]]:
    """The chosen folds grouped by the simulated set and pretraining they share.

    The simulator of a group is fitted to the frames outside its folds (``profile: fitted``):
    when some folds are not chosen, those frames lie outside every chosen fold, so one fit and one
    pretraining serve them all; when every fold is chosen, each is its own group (fitted to its
    own training frames). With ``profile: as_is`` no real frame is seen: one group."""
    chosen = chosen_folds(settings, n_folds)
    if settings.profile == "as_is" or len(chosen) < n_folds:
        return [tuple(chosen)]
    return [(fold,) for fold in chosen]


def group_name(group: Sequence[int]) -> str:
    """A group's name in paths (its folds joined by '-': 0-1-2) and back (:func:`parse_group`)."""
    return "-".join(str(int(f)) for f in group)


def parse_group(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(f) for f in text.split("-"))
    except ValueError:
        raise ConfigError(f"sim2real: {text!r} is not a group of folds (like 0-1-2)") from None
