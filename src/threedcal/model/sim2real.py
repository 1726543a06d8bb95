"""Sim-to-real: pretrain on simulated probing of the sensor's profile, fine-tune on k real images.

For an imported scene (docs/explanation/real-data.md, "Sim-to-real"):

1. per group of chosen folds (:func:`pretraining_groups`: all of them when some folds are not
   chosen, else each alone), :func:`fold_profile` fits the sensor profile's optics to the frames
   outside the group's folds and the blank frame of the model-ready set (``profile: fitted``, the
   default; any import format): every chosen fold trains on those frames, and none of its test
   images is among them. :func:`simulate_trainset` renders ``frames`` ball presses with it
   (threedcal.sim.optics.GelSimulator) at the real set's image size, px/mm and ball radius, at
   seeded random centres (the whole contact inside the image) and depths, labelled exactly;
2. :func:`pretrain` trains the scene's model preset on them, one model per group;
3. :func:`train_k` trains, for one cross-validation fold (cv/folds.csv) and one k, the model on a
   seeded nested subset of k of the fold's training images — fine-tuned from the pretrained
   network (``sim_real``) or from scratch (``real_only``) with the same settings and the same
   number of optimiser steps: k images train ``finetune_epochs x pool / k`` epochs (pool: the
   fold's training images);
4. with ``shipped: true``, :func:`train_shipped` fine-tunes the weights this package ships for the
   scene's sensor (threedcal.pretrained: pretrained on simulated presses of many units, never on
   these frames) on the same k images, brought to the weights' frame by
   threedcal.dataset.reframe (pooled by the whole factor that gets there, turned a quarter if the
   frames stand on their side). Its settings are the weights' own recipe (their provenance) with
   `shipped_lr`, and the model's own holdout decides how long (the `doubling` rule, which may keep
   the shipped weights unchanged): nothing is chosen on a test image;
5. :func:`sim2real_eval` scores every model on its fold's held-out real images with ball_eval's
   figures and the group bootstrap (threedcal.model.crossval), and draws error against k. Every
   condition is scored at the set's own frame size: a model of another frame (shipped+real) has
   its gradients brought back to the original pixels (Reframe.gradients_back) and integrated
   there, so the same truth, discs and integrator score every row; errors.csv names the frame
   each condition predicted at (`predicted_at`).

One job trains every k of a (condition, fold) (:func:`train_fold_ks`). With ``profile: as_is``
the simulator sees no real image: the profile is used as it is, and one pretraining serves every
fold. (The built-in GelSight Mini profile's optics were fitted, once, to the background and
contacts of data/gelsight_ball_fots — all 42 frames — so on that set it is not independent of the
test images: that is why the default fits on the training images.)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.dataset.labels import check_max_slope, contact_radius_mm
from threedcal.dataset.trainset import TrainingSet, samples_table
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

    @classmethod
    def from_scene(cls, scene: Mapping) -> SimToRealSettings:
        return cls.of(**(scene.get("sim_to_real") or {}))


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


# ------------------------------------------------------------------------------ the workflow
SIM2REAL_CONDITIONS = tuple(CONDITIONS)
# The sim_to_real keys each stage reads: a change reruns only the stages that read it.
STAGE_KEYS = {
    "simulate": ("frames", "depth_mm", "profile"),
    "pretrain": ("pretrain_epochs",),
    "train": ("finetune_epochs", "k"),
    "shipped": ("shipped_lr", "k"),
}


def train_keys(scene: Mapping, condition: str) -> dict:
    """The sim_to_real keys a `condition`'s training reads."""
    return sim2real_keys(scene, "shipped" if condition == "shipped_real" else "train")


def sim2real_keys(scene: Mapping, stage: str) -> dict:
    values = scene.get("sim_to_real") or {}
    return {key: values[key] for key in STAGE_KEYS[stage] if key in values}


def sensor_profile(scene: Mapping) -> dict:
    """The scene's sensor profile as the simulator reads it (without its machine-specific path)."""
    from threedcal.profiles import load_profile

    profile = dict(load_profile("sensor", scene["sensor"]))
    profile.pop("source", None)
    return profile


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


def group_of(scene: Mapping, fold: int) -> str:
    """The name of the pretraining group that holds `fold`."""
    settings = SimToRealSettings.from_scene(scene)
    for group in pretraining_groups(settings, int(scene["cv"]["folds"])):
        if fold in group:
            return group_name(group)
    raise ConfigError(f"sim_to_real.folds: fold {fold} is not evaluated")


def sim2real_inputs(name: str, scene: Mapping) -> dict[str, list[str]]:
    """The folders sim2real_eval scores: "{condition}" -> the condition's fold folders (each with
    k{k}/model.pt), "scene" -> the scene's cross-validated models (ball_eval's) of the same folds."""
    from threedcal.scenes import CV_MODEL_DIR, SIM2REAL_FOLD_DIR, target

    settings = SimToRealSettings.from_scene(scene)
    folds = chosen_folds(settings, int(scene["cv"]["folds"]))

    def path(pattern: str, **wildcards) -> str:
        path = target(pattern, name)
        for key, value in wildcards.items():
            path = path.replace(f"{{{key}}}", str(value))
        return path

    out = {
        condition: [path(SIM2REAL_FOLD_DIR, condition=condition, fold=f) for f in folds]
        for condition in settings.conditions
    }
    out["scene"] = [path(f"{CV_MODEL_DIR}/model.pt", method="model", fold=f) for f in folds]
    return out


def k_model(fold_dir: str | Path, k: int | str) -> Path:
    """The model of k images in a (condition, fold) folder (:func:`train_fold_ks`)."""
    return Path(fold_dir) / f"k{k}" / "model.pt"


# ------------------------------------------------------------------------- simulated probing
def simulate_trainset(
    real: TrainingSet, profile: Mapping, settings: SimToRealSettings, seed: int, progress=True
) -> TrainingSet:
    """Simulated presses of the real set's ball at its image size and px/mm, labelled exactly.

    Centres are uniform over the positions that keep the whole contact circle inside the image;
    depths uniform in `depth_mm`. The last tenth of the frames (at least one) is split 'val'.
    """
    from tqdm import tqdm

    from threedcal.sim.indenters import Sphere
    from threedcal.sim.optics import GelSimulator

    height, width = real.image_shape
    radius = real.sphere_radius_mm
    lo, hi = settings.depth_mm
    if hi > radius:
        raise ConfigError(
            f"sim_to_real.depth_mm: {hi} mm is deeper than the ball's radius {radius} mm"
        )
    reach = contact_radius_mm(radius, hi) * real.px_per_mm + 1.0
    if 2 * reach >= min(height, width):
        raise ConfigError(
            f"sim_to_real.depth_mm: a {hi} mm press of the {radius} mm ball is "
            f"{2 * reach:.0f} px across, too wide for the {width} x {height} px images"
        )
    sim = GelSimulator(profile, seed, image_size=(width, height), px_per_mm=real.px_per_mm)
    rng = np.random.default_rng([seed, 0x51A2])
    n = settings.frames
    centres = rng.uniform([reach, reach], [width - 1 - reach, height - 1 - reach], (n, 2))
    depths = rng.uniform(lo, hi, n)
    ball = Sphere(radius)
    frames = np.empty((n, height, width, 3), dtype=np.uint8)
    for i in tqdm(range(n), desc="simulate presses", unit="frame", disable=not progress):
        frames[i] = sim.render(ball, tuple(centres[i]), 0.0, float(depths[i]), frame_index=i + 1)
    contact = np.array([contact_radius_mm(radius, float(d)) for d in depths]) * real.px_per_mm
    n_val = max(1, n // 10)
    split = np.where(np.arange(n) < n - n_val, "train", "val")
    samples = samples_table(
        np.arange(n),
        centres,
        depths,
        EVAL_SHRINK * contact,
        split,
        np.where(split == "train", 80, 0),
    )
    return TrainingSet(
        frames=frames,
        blank=sim.blank(0).astype(np.float32),
        samples=samples,
        px_per_mm=real.px_per_mm,
        sphere_radius_mm=radius,
        max_slope_deg=check_max_slope(real.max_slope_deg),
        meta={"source": f"simulated {profile.get('name')} presses", "seed": seed},
    )


# Fewest training images a fold's optics are fitted to: with fewer, the LED levels and the shading
# shape are not determined. (Enough for a gain is more: docs/explanation/real-data.md, 8 images give none.)
MIN_FIT_IMAGES = 3


@dataclass(frozen=True)
class _SetImages:
    """A model-ready set seen as the ball folder threedcal.sim.fit reads: frames by name, its
    blank as background.png. Works for every import format, and takes the set's own (possibly
    refined) contact circles."""

    ts: TrainingSet
    root: str
    names: tuple[str, ...]

    @property
    def px_per_mm(self) -> float:
        return self.ts.px_per_mm

    @property
    def ball_radius_mm(self) -> float:
        return self.ts.sphere_radius_mm

    @property
    def height_px(self) -> int:
        return self.ts.image_shape[0]

    @property
    def width_px(self) -> int:
        return self.ts.image_shape[1]

    def read(self, name: str) -> np.ndarray:
        if name == "background.png":
            return self.ts.blank
        return self.ts.frames[self.names.index(name)]


def fold_profile(
    profile: Mapping, ts: TrainingSet, folds: pd.DataFrame, held_out: Sequence[int], where: str
):
    """`profile` with its optics fitted to the frames outside the `held_out` folds and the set's
    blank: the simulator then never sees a test image of those folds."""
    held_out = sorted(int(f) for f in held_out)
    frames = folds.loc[~folds["fold"].isin(held_out), "frame"].to_numpy()
    if len(frames) < MIN_FIT_IMAGES:
        named = f"fold {held_out[0]}" if len(held_out) == 1 else f"folds {group_name(held_out)}"
        raise ConfigError(
            f"{where}: {len(frames)} training images lie outside {named}; fitting the optics "
            f"(sim_to_real.profile: fitted) needs at least {MIN_FIT_IMAGES} — add images, "
            "lower cv.folds, evaluate fewer sim_to_real.folds, or set profile: as_is"
        )
    return fitted_to_frames(profile, ts, frames, where)


def fitted_to_frames(profile: Mapping, ts: TrainingSet, frames: Sequence[int], where: str):
    """`profile` with its optics fitted (threedcal.sim.fit.fit_optics) to these frames of the
    model-ready set, with their contact circles, and its blank."""
    from threedcal.model.folds import contact_radius_px
    from threedcal.sim.fit import fit_optics
    from threedcal.sim.realism import BallLabel

    names = tuple(f"frame{i:05d}" for i in range(len(ts.frames)))
    radius = contact_radius_px(ts)
    labels = [
        BallLabel(
            names[i], (float(ts.center_px[i, 0]), float(ts.center_px[i, 1])), float(radius[i])
        )
        for i in frames
    ]
    return fit_optics(profile, _SetImages(ts, where, names), labels)


def write_simulated(
    real_dir: str | Path,
    profile: Mapping,
    sim_to_real: Mapping,
    seed: int,
    out_dir: str | Path,
    progress: bool = True,
    *,
    folds_path: str | Path | None = None,
    held_out: Sequence[int] | None = None,
) -> TrainingSet:
    """The simulated set of a group of test folds (`held_out`, :func:`pretraining_groups`) in
    `out_dir`; with `profile: fitted` also the fitted profile (profile.yaml, headed by the frames
    it was fitted on: frameNNNNN, the set's frame numbers, none of a held-out fold)."""
    from threedcal.model.folds import read_folds

    settings = SimToRealSettings.of(**sim_to_real)
    real = TrainingSet.load(real_dir)
    fit = None
    if settings.profile == "fitted":
        if folds_path is None or not held_out:
            raise ConfigError(
                "sim_to_real.profile: fitted needs the scene's folds and the folds held out"
            )
        folds = read_folds(folds_path, real)
        fit = fold_profile(profile, real, folds, held_out, str(real_dir))
        profile = fit.profile
    ts = simulate_trainset(real, profile, settings, seed, progress)
    ts.save(out_dir)
    if fit is not None:
        fit.write_profile(Path(out_dir) / "profile.yaml")
    return ts


# ---------------------------------------------------------------------------------- training
def _train_settings(model: Mapping, seed: int, threads: int, **changes):
    from threedcal.model.train_settings import TrainSettings

    return TrainSettings.from_scene(
        {"model": {**dict(model), **changes}, "seed": seed, "torch_threads": threads}
    )


def pretrain(
    sim_dir: str | Path,
    model: Mapping,
    sim_to_real: Mapping,
    seed: int,
    threads: int,
    out_dir: str | Path,
    progress: bool = True,
) -> dict:
    """The scene's model preset trained on the simulated presses for `pretrain_epochs` epochs."""
    from threedcal.model.train import train

    settings = SimToRealSettings.of(**sim_to_real)
    if model.get("init"):
        raise ConfigError("sim_to_real: the scene's model.init is set; pretraining starts fresh")
    train_settings = _train_settings(model, seed, threads, epochs_base=settings.pretrain_epochs)
    return train(TrainingSet.load(sim_dir), out_dir, 80, train_settings, progress)


def n_train_of(folds: pd.DataFrame, fold: int, k: int | str) -> int:
    """Real training images of `fold` at `k` (all = every image outside the fold)."""
    pool = int((folds["fold"] != fold).sum())
    if k == "all":
        return pool
    if not isinstance(k, int) or k < 1:
        raise ConfigError(f"sim_to_real.k: {k!r} is neither a whole number >= 1 nor 'all'")
    if k > pool:
        raise ConfigError(
            f"sim_to_real.k: fold {fold} has {pool} real training images, fewer than k = {k}; "
            "lower k or label more images"
        )
    return k


def parse_k(text: str) -> int | str:
    return "all" if text == "all" else int(text)


def train_k(
    trainset_dir: str | Path,
    folds_path: str | Path,
    fold: int,
    k: int | str,
    condition: str,
    model: Mapping,
    sim_to_real: Mapping,
    seed: int,
    threads: int,
    out_dir: str | Path,
    pretrained: str | Path | None = None,
    progress: bool = True,
) -> dict:
    """One fold's model on k real images: fine-tuned from `pretrained` (sim_real) or from scratch
    (real_only), both for finetune_epochs x pool / k epochs, pool the fold's training images (the
    same steps at every k); or the shipped weights fine-tuned on them (shipped_real,
    :func:`train_shipped`; `model` unused)."""
    from threedcal.model.folds import fold_trainset, read_folds
    from threedcal.model.train import train

    if condition not in CONDITIONS:
        raise ConfigError(
            f"sim_to_real condition {condition!r} unknown (allowed: {', '.join(CONDITIONS)})"
        )
    if (condition == "sim_real") != (pretrained is not None):
        raise ConfigError(
            f"sim_to_real: condition {condition} {'needs' if condition == 'sim_real' else 'takes no'} pretrained model"
        )
    if condition == "shipped_real":
        return train_shipped(
            trainset_dir, folds_path, fold, k, sim_to_real, seed, threads, out_dir, progress
        )
    settings = SimToRealSettings.of(**sim_to_real)
    ts = TrainingSet.load(trainset_dir)
    folds = read_folds(folds_path, ts)
    n_train = n_train_of(folds, fold, k)
    pool = int((folds["fold"] != fold).sum())
    epochs = max(1, round(settings.finetune_epochs * pool / n_train))
    changes = {"epochs_base": epochs, "init": None if pretrained is None else str(pretrained)}
    subset = fold_trainset(ts, folds, fold, None if k == "all" else n_train, seed)
    return train(subset, out_dir, 80, _train_settings(model, seed, threads, **changes), progress)


def train_fold_ks(
    trainset_dir: str | Path,
    folds_path: str | Path,
    fold: int,
    condition: str,
    model: Mapping,
    sim_to_real: Mapping,
    seed: int,
    threads: int,
    out_dir: str | Path,
    pretrained: str | Path | None = None,
    progress: bool = True,
) -> dict[int | str, dict]:
    """Every k of one (condition, fold) (:func:`train_k`) into out_dir/k{k}/: one job for them
    all, so the libraries and the set load once and not once a k."""
    from tqdm import tqdm

    ks = SimToRealSettings.of(**sim_to_real).k
    out = {}
    for k in tqdm(ks, desc=f"{condition} fold {fold}", unit="k", disable=not progress):
        out[k] = train_k(
            trainset_dir,
            folds_path,
            fold,
            k,
            condition,
            model,
            sim_to_real,
            seed,
            threads,
            k_model(out_dir, k).parent,
            pretrained,
            progress,
        )
    return out


SHIPPED_KEY = "sim_to_real.shipped"


def shipped_for(ts: TrainingSet, directory: Path | None = None) -> tuple[Path, dict]:
    """The shipped weights of the set's sensor and their provenance; refused, naming
    sim_to_real.shipped, for a sensor without them."""
    from threedcal.pretrained import provenance, shipped_sensors, shipped_weights

    sensor = (ts.meta or {}).get("sensor")
    if sensor not in shipped_sensors(directory):
        raise ConfigError(
            f"{SHIPPED_KEY}: no shipped weights for sensor {sensor!r} (shipped: "
            f"{', '.join(shipped_sensors(directory)) or 'none'}); set shipped: false"
        )
    return shipped_weights(sensor, None, directory), provenance(sensor, directory)


def shipped_settings(record: Mapping, lr: float, seed: int, threads: int, init: str | Path):
    """Fine-tuning settings of the shipped weights: their pretraining recipe's `model` (preset,
    patches, loss, batch), at rate `lr`, for as long as the recipe's doubling rule finds it pays
    on a holdout of the model's own training images (the weights as shipped are its first
    candidate)."""
    recipe = dict(record["pretraining"]["model"])
    stopping = {**recipe.get("stopping", {}), "rule": "doubling"}
    return _train_settings(recipe, seed, threads, init=str(init), lr=lr, stopping=stopping)


def train_shipped(
    trainset_dir: str | Path,
    folds_path: str | Path,
    fold: int,
    k: int | str,
    sim_to_real: Mapping,
    seed: int,
    threads: int,
    out_dir: str | Path,
    progress: bool = True,
    *,
    weights_dir: Path | None = None,
) -> dict:
    """The shipped weights of the set's sensor fine-tuned on the fold's k training images (the
    same nested subset as the other conditions), in the weights' frame (threedcal.dataset.reframe).
    The checkpoint records how its frames were brought there (training.reframe)."""
    from threedcal.dataset.reframe import reframe
    from threedcal.model.checkpoint import save_checkpoint
    from threedcal.model.folds import fold_trainset, read_folds
    from threedcal.model.train import train

    settings = SimToRealSettings.of(**sim_to_real)
    ts = TrainingSet.load(trainset_dir)
    weights, record = shipped_for(ts, weights_dir)
    framed, how = reframe(ts, tuple(record["image_shape"]), SHIPPED_KEY)
    folds = read_folds(folds_path, ts)
    n_train = n_train_of(folds, fold, k)
    subset = fold_trainset(framed, folds, fold, None if k == "all" else n_train, seed)
    train_settings = shipped_settings(record, settings.shipped_lr, seed, threads, weights)
    checkpoint = train(subset, out_dir, 80, train_settings, progress)
    checkpoint["training"]["reframe"] = {
        "full_shape": list(how.full_shape),
        "factor": how.factor,
        "turned": how.turned,
    }
    save_checkpoint(Path(out_dir) / "model.pt", checkpoint)
    return checkpoint


# ------------------------------------------------------------------------------- evaluation
def score_models(
    ts: TrainingSet,
    folds: pd.DataFrame,
    models: Mapping[tuple[str, str], Mapping[int, str | Path]],
    threads: int,
) -> pd.DataFrame:
    """Per-image errors (crossval.image_errors) of every (condition, k) model on its fold's test
    images, at the set's own frame size: columns condition, k, fold, frame, group, gradient_mse,
    cap_depth_mae_um, predicted_at (the frame the model predicted in)."""
    from threedcal.model.crossval import Truth, image_errors

    truth = Truth.of(ts)
    rows = []
    for (condition, k), by_fold in models.items():
        for fold, path in by_fold.items():
            only = folds[folds["fold"] == fold]
            frames, predicted_at = predict_frames(ts, only["frame"], path, threads)
            for frame in only["frame"]:
                mse, mae, _, _ = image_errors(*frames[int(frame)], ts, int(frame), truth)
                rows.append(
                    {
                        "condition": condition,
                        "k": k,
                        "fold": int(fold),
                        "frame": int(frame),
                        "group": int(folds.at[frame, "group"]),
                        "gradient_mse": mse,
                        "cap_depth_mae_um": mae,
                        "predicted_at": predicted_at,
                    }
                )
    return pd.DataFrame(rows)


def frame_size(shape: Sequence[int]) -> str:
    return f"{int(shape[0])}x{int(shape[1])} px"


def predict_frames(
    ts: TrainingSet, frames: Sequence[int], path: str | Path, threads: int
) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], str]:
    """frame -> (gradients, depth) at the set's frame size, and the frame the model predicted in.

    A model trained in another frame (its checkpoint's training.reframe: shipped+real) predicts
    on the frames brought to it, and its gradients are brought back to the set's pixels before
    they are integrated (threedcal.dataset.reframe): every model is integrated and scored alike.
    """
    import torch

    from threedcal.dataset.reframe import reframe
    from threedcal.depth import integrate
    from threedcal.model.checkpoint import read_checkpoint
    from threedcal.model.inference import DepthEstimator

    torch.set_num_threads(threads)
    checkpoint = read_checkpoint(path)
    recorded = (checkpoint.get("training") or {}).get("reframe")
    source, how = ts, None
    if recorded is not None:
        source, how = reframe(ts, tuple(checkpoint["image_shape"]), f"{path}")
        if [list(how.full_shape), how.factor, how.turned] != [
            list(recorded["full_shape"]),
            int(recorded["factor"]),
            bool(recorded["turned"]),
        ]:
            raise ConfigError(
                f"{path}: trained on frames brought to its size as {recorded}, this set's "
                f"come there as {how}: not the set it was trained on"
            )
    estimator = DepthEstimator(checkpoint, device="cpu")
    out = {}
    for frame in frames:
        grads = estimator.gradients(np.asarray(source.frames[int(frame)]))
        if how is not None:
            grads = how.gradients_back(grads)
        # as crossval.predict_held_out integrates the scene's models
        depth = integrate(grads[..., 0], grads[..., 1], px_per_mm=ts.px_per_mm)
        out[int(frame)] = (grads, depth)
    return out, how.describe() if how is not None else frame_size(ts.image_shape)


def summarise_k(
    images: pd.DataFrame, folds: pd.DataFrame, resamples: int, seed: int, scored_at: str = ""
) -> pd.DataFrame:
    """errors.csv: per (k, condition) the figures of each fold and pooled over the folds (fold
    'all', with a 95 % interval from the group bootstrap, the same resamples for every model),
    with the frame each condition predicted at and the one it was scored at."""
    from threedcal.model.crossval import group_bootstrap, interval, pooled

    keys = list(dict.fromkeys(zip(images["condition"], images["k"], strict=True)))
    tables = {
        key: images[(images["condition"] == key[0]) & (images["k"] == key[1])].reset_index(
            drop=True
        )
        for key in keys
    }
    boot = group_bootstrap(tables, resamples, seed)
    pool_size = {int(f): int((folds["fold"] != f).sum()) for f in folds["fold"].unique()}
    rows = []
    for key, table in tables.items():
        condition, k = key
        sizes = {"scored_at": scored_at}
        if "predicted_at" in table:
            sizes["predicted_at"] = "; ".join(dict.fromkeys(table["predicted_at"]))
        for fold, part in table.groupby("fold"):
            n_train = pool_size[int(fold)] if k == "all" else int(k)
            rows.append(
                {"k": k, "n_train": n_train, "condition": condition, "fold": str(fold)}
                | {"n_test_images": len(part)}
                | pooled(part)
                | sizes
            )
        n_train = (
            float(np.mean([pool_size[int(f)] for f in table["fold"].unique()]))
            if k == "all"
            else int(k)
        )
        row = {"k": k, "n_train": n_train, "condition": condition, "fold": "all"}
        row |= {"n_test_images": len(table)} | pooled(table) | sizes
        for metric in ("gradient_rmse", "cap_depth_mae_um"):
            row[f"{metric}_lo"], row[f"{metric}_hi"] = interval(boot[key][metric])
        rows.append(row)
    return pd.DataFrame(rows).reindex(columns=list(ERROR_COLUMNS))


def error_figure(errors: pd.DataFrame, path: str | Path, title: str) -> None:
    """Error against k (log axis; 'all' at the mean training-set size), each condition with its
    95 % intervals, and the scene's own model as a band."""
    from threedcal.plotting import pyplot

    plt = pyplot()

    pooled_rows = errors[errors["fold"] == "all"]
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.4), dpi=120, layout="constrained")
    for ax, metric, label in (
        (axes[0], "gradient_rmse", "gradient RMSE"),
        (axes[1], "cap_depth_mae_um", "cap depth MAE (µm)"),
    ):
        for offset, (condition, colour) in zip(
            (0.96, 1.0, 1.04),
            [(CONDITIONS[c], f"C{i}") for i, c in enumerate(CONDITIONS)],
            strict=True,
        ):
            part = pooled_rows[pooled_rows["condition"] == condition].sort_values("n_train")
            if part.empty:
                continue
            x = part["n_train"].to_numpy(float) * offset
            y = part[metric].to_numpy(float)
            err = [y - part[f"{metric}_lo"].to_numpy(float), part[f"{metric}_hi"] - y]
            ax.errorbar(x, y, yerr=err, fmt="o-", color=colour, capsize=3, label=condition)
        scene = pooled_rows[pooled_rows["condition"] == SCENE_MODEL]
        if not scene.empty:
            row = scene.iloc[0]
            ax.axhspan(row[f"{metric}_lo"], row[f"{metric}_hi"], color="grey", alpha=0.2)
            ax.axhline(row[metric], color="grey", lw=1, label=f"{SCENE_MODEL} (all, full budget)")
        ax.set_xscale("log")
        ticks = pooled_rows[pooled_rows["condition"] != SCENE_MODEL].drop_duplicates("k")
        ax.set_xticks(
            ticks["n_train"].to_numpy(float),
            [
                f"{k}" if k != "all" else f"all\n({n:.0f})"
                for k, n in zip(ticks["k"], ticks["n_train"], strict=True)
            ],
        )
        ax.minorticks_off()
        ax.set_xlabel("real training images k")
        ax.set_ylabel(label)
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def sim2real_eval(
    trainset_dir: str | Path,
    folds_path: str | Path,
    models: Mapping[str, Sequence[str | Path]],
    scene_models: Sequence[str | Path],
    sim_to_real: Mapping,
    cv: Mapping,
    seed: int,
    threads: int,
    errors_path: str | Path,
    figure_path: str | Path,
    images_path: str | Path | None = None,
) -> pd.DataFrame:
    """errors.csv and error_vs_k.png of the chosen folds.

    `models[condition]` lists that condition's fold folders (:func:`train_fold_ks`, k{k}/model.pt
    inside) in the order of the chosen folds; `scene_models` the scene's cross-validated models
    (ball_eval's) of the same folds.
    """
    from threedcal.model.folds import CVSettings, read_folds

    settings = SimToRealSettings.of(**sim_to_real)
    cv_settings = CVSettings.of(**cv)
    ts = TrainingSet.load(trainset_dir)
    folds = read_folds(folds_path, ts)
    chosen = chosen_folds(settings, cv_settings.folds)
    by_model: dict[tuple[str, str], dict[int, str | Path]] = {}
    for condition in settings.conditions:
        dirs = list(models[condition])
        if len(dirs) != len(chosen):
            raise ConfigError(f"sim2real: {len(dirs)} {condition} fold folders for folds {chosen}")
        for k in settings.k:
            paths = {fold: k_model(d, k) for fold, d in zip(chosen, dirs, strict=True)}
            missing = [str(p) for p in paths.values() if not p.is_file()]
            if missing:
                raise ConfigError(f"sim2real: no {condition} model of k = {k}: {missing[0]}")
            by_model[(CONDITIONS[condition], str(k))] = paths
    if len(scene_models) != len(chosen):
        raise ConfigError(f"sim2real: {len(scene_models)} scene models for folds {chosen}")
    by_model[(SCENE_MODEL, "all")] = dict(zip(chosen, scene_models, strict=True))
    images = score_models(ts, folds, by_model, threads)
    errors = summarise_k(
        images, folds, cv_settings.bootstrap, seed, scored_at=frame_size(ts.image_shape)
    )
    Path(errors_path).parent.mkdir(parents=True, exist_ok=True)
    errors.to_csv(errors_path, index=False, float_format="%.6g")
    if images_path is not None:
        images.to_csv(images_path, index=False, float_format="%.6g")
    n_test = int(folds["fold"].isin(chosen).sum())
    error_figure(
        errors,
        figure_path,
        f"folds {', '.join(map(str, chosen))}: {n_test} held-out real images, scored at "
        f"{frame_size(ts.image_shape)}; 95 % group-bootstrap intervals",
    )
    return errors
