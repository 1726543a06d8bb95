"""Sim-to-real: pretrain on simulated probing of the sensor's profile, fine-tune on k real images.

For an imported scene (docs/explanation/real-data.md, "Sim-to-real"):

1. per group of chosen folds (:func:`pretraining_groups`: all of them when some folds are not
   chosen, else each alone), `sim2real_simulate.fold_profile` fits the sensor profile's optics to the frames
   outside the group's folds and the blank frame of the model-ready set (``profile: fitted``, the
   default; any import format): every chosen fold trains on those frames, and none of its test
   images is among them. `sim2real_simulate.simulate_trainset` renders ``frames`` ball presses with it
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
   figures and the group bootstrap (threedcal.evaluate.crossval), and draws error against k. Every
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

from collections.abc import Mapping
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from threedcal.dataset.folds import fold_trainset, read_folds
from threedcal.dataset.reframe import reframe
from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError
from threedcal.evaluate.sim2real_settings import (
    CONDITIONS,
    SimToRealSettings,
)
from threedcal.model.checkpoint import save_checkpoint
from threedcal.model.train import TrainSettings, train
from threedcal.pretrained import provenance, shipped_sensors, shipped_weights


def k_model(fold_dir: str | Path, k: int | str) -> Path:
    """The model of k images in a (condition, fold) folder (:func:`train_fold_ks`)."""
    return Path(fold_dir) / f"k{k}" / "model.pt"


def _train_settings(model: Mapping, seed: int, threads: int, **changes):
    return TrainSettings.of(seed=seed, torch_threads=threads, **{**dict(model), **changes})


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
