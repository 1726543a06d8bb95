"""Training one model on a TrainingSet at one fraction P: deterministic, resumable, patch-sampled.

The paper trains TouchNet on full frames; on a CPU that is out of reach, so each epoch draws, per
training frame, a few patches around the contact (where the labels vary) plus a few anywhere (so the
background is learnt to be flat). Patch positions come from a generator seeded by (seed, epoch) and
torch is reseeded per epoch, so a resumed run continues exactly as an uninterrupted one and the same
settings give the same bytes of model.pt. How long it trains is the stopping rule's
(threedcal.model.stopping): the paper's fixed epochs, or until the error on a holdout of its own
training coordinates stops falling.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError, TrainingError
from threedcal.model.allocator import reuse_freed_memory
from threedcal.model.checkpoint import (
    FORMAT,
    FORMAT_VERSION,
    OUR_NORMALISATION,
    model_from_checkpoint,
    read_checkpoint,
    save_checkpoint,
)
from threedcal.model.loss_log import plot_losses, write_losses
from threedcal.model.machine import describe as describe_machine
from threedcal.model.machine import resolve_precision, torch_device
from threedcal.model.patches import FramePairs, ModelInputs, input_batches, sample_windows
from threedcal.model.presets import (
    build_model,
    is_learned,
    preferred_memory_format,
    preset_args,
)
from threedcal.model.stopping import (
    SNAPSHOT_DIR,
    Doubling,
    check_rule,
    holdout_split,
    snapshot_name,
)
from threedcal.model.train_settings import TrainSettings, scheduled_lr
from threedcal.model.train_step import (
    VALIDATION_WINDOWS,
    divergence_hint,
    loss_row,
    make_optimizer,
    optimizer_step,
    train_epoch,
    validation_epochs,
    validation_settings,
    windows_mse,
)
from threedcal.pretrained import shipped_weights
from threedcal.seeds import replicate_seed

RESUME_NAME = "checkpoint.pt"
# The resume checkpoint is rewritten after an epoch only when this long has passed since the last:
# a P = 1 % job runs 320 short epochs, and saving after each would cost 5 % of its time. An interrupted
# job redoes at most this much, and ends with the same bytes either way.
RESUME_EVERY_S = 20.0


def configure_torch(settings: TrainSettings) -> torch.device:
    """Threads, determinism and device, set before any tensor is made."""
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # deterministic cuBLAS
    reuse_freed_memory()
    torch.set_num_threads(settings.torch_threads)
    torch.use_deterministic_algorithms(True)
    torch.backends.cudnn.benchmark = False
    return torch_device(settings.device)


# Raised whenever the same settings come to train differently, so that an interrupted run's
# checkpoint is resumed only by the code that wrote it (the changelog says what each step changed).
TRAINING_SEMANTICS = 4


def _resume_key(settings: TrainSettings, percent: int, replicate: int, ts: TrainingSet, run) -> str:
    described = {
        "semantics": TRAINING_SEMANTICS,
        "settings": asdict(settings),
        "percent": percent,
        "replicate": replicate,
        "frames": list(ts.frames.shape),
        "meta": ts.meta or {},
        "run": run,
    }
    return hashlib.sha256(json.dumps(described, sort_keys=True, default=str).encode()).hexdigest()


def _cpu_state(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}


def initial_model(settings: TrainSettings, ts: TrainingSet) -> tuple[torch.nn.Module, dict]:
    torch.manual_seed(settings.seed)
    if settings.init is None:
        return build_model(settings.preset), {**OUR_NORMALISATION, "drift": settings.drift}
    source = read_checkpoint(init_path(settings.init, ts))
    if source["preset"] != settings.preset:
        raise ConfigError(
            f"model.init: {settings.init} holds a {source['preset']!r} model, "
            f"but model.preset is {settings.preset!r}"
        )
    shape = source.get("image_shape")
    if shape is not None and tuple(shape) != ts.image_shape:
        raise ConfigError(
            f"model.init: {settings.init} was trained on {tuple(shape)} images, "
            f"this dataset has {ts.image_shape}"
        )
    # Fine-tuning keeps the normalisation the source network was trained with.
    normalisation = {"drift": "none", **source.get("normalisation", OUR_NORMALISATION)}
    return model_from_checkpoint(source), normalisation


def save_initial(ts: TrainingSet, path: str | Path, settings: TrainSettings) -> dict:
    """The weights a training with `settings` starts from (`model.init`'s, or fresh ones of the
    preset), saved as a usable model.pt of `ts` (its blank, registration and lens): what a quick
    calibration scores its first round's presses with."""
    configure_torch(settings)
    model, normalisation = initial_model(settings, ts)
    checkpoint = checkpoint_of(model, settings, ts, 80, 0, 0, normalisation)
    checkpoint["training"].update(steps=0, stopped="not trained: the weights it starts from")
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_checkpoint(path, checkpoint)
    return checkpoint


def init_path(init: str, ts: TrainingSet) -> str | Path:
    """`model.init`'s checkpoint: a path, or `pretrained` — the weights this package ships for
    the dataset's sensor (threedcal.pretrained)."""
    if init != "pretrained":
        return init

    return shipped_weights((ts.meta or {}).get("sensor"), ts.image_shape)


@dataclass
class _Job:
    """One training's fixed inputs: the data it fits, the windows it checks, the device."""

    ts: TrainingSet
    fit_idx: np.ndarray  # frames the optimiser sees
    check_idx: np.ndarray  # frames whose windows are checked (holdout, or the paper's val)
    check_windows: list
    settings: TrainSettings
    device: torch.device
    precision: str  # resolved: float32 or bfloat16
    name: str  # "P80 r0": what errors name
    inputs: ModelInputs | None = None
    normalisation: dict | None = None


def _plan_job(ts, percent, replicate, settings, device, precision) -> _Job:
    """Which frames train and which are checked: under `doubling` a holdout of the model's own
    training frames; under `epochs` (the paper's) the trainer logs the validation split's loss."""
    train_idx = ts.indices("train", percent=percent, replicate=replicate)
    if len(train_idx) == 0:
        raise ConfigError(
            f"P={percent}, replicate {replicate}: no training frames in this dataset's split"
        )
    check_rule(settings.stopping)
    if settings.stopping["rule"] == "doubling":
        fit_idx, check_idx = holdout_split(
            train_idx, settings.stopping["holdout"], settings.seed, ts.point[train_idx]
        )
        if len(check_idx) == 0:  # too few frames to hold any out: judged on what it fits
            check_idx = fit_idx
    else:
        fit_idx, check_idx = train_idx, ts.indices("val")
    check_rng = np.random.default_rng([settings.seed, 1 << 20])
    windows = sample_windows(ts, check_idx, validation_settings(settings), check_rng)
    if len(windows) > VALIDATION_WINDOWS:  # a fixed, seeded subset: checks stay cheap
        keep = np.sort(check_rng.choice(len(windows), VALIDATION_WINDOWS, replace=False))
        windows = [windows[k] for k in keep]
    name = f"P={percent} r{replicate}"
    return _Job(ts, fit_idx, check_idx, windows, settings, device, precision, name)


def train(
    ts: TrainingSet | str | Path,
    out_dir: str | Path,
    percent: int,
    settings: TrainSettings,
    progress: bool = True,
    replicate: int = 0,
    *,
    budget_scale: float = 1.0,
    min_steps: int = 0,
    snapshot_every: int = 0,
) -> dict:
    """Train replicate r at fraction `percent` into out_dir/{model.pt, losses.csv, losses.png}.

    Replicate r trains on its own nested subset (TrainingSet.indices) with the seed
    replicate_seed(settings.seed, r): replicate 0 is the scene seed itself. `budget_scale` and
    `min_steps` lengthen a `doubling` rule (the convergence check trains twice the budget), and
    `snapshot_every` > 0 writes the best weights so far to out_dir/snapshots/ every that many
    checks (the error-against-time curve). Returns the checkpoint.
    """
    if not isinstance(ts, TrainingSet):
        ts = TrainingSet.load(ts)
    settings = replace(settings, seed=replicate_seed(settings.seed, replicate))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    device = configure_torch(settings)
    precision = resolve_precision(settings.precision, device, settings.preset)
    # Where it trains: on a cluster, whether the job's GPU was usable (else the CPU).
    logging.getLogger(__name__).info(
        "training P=%d r%d on %s in %s", percent, replicate, device, precision
    )
    job = _plan_job(ts, percent, replicate, settings, device, precision)
    model, job.normalisation = initial_model(settings, ts)
    model.to(device=device, memory_format=preferred_memory_format(model))
    job.inputs = ModelInputs(ts, job.normalisation["drift"])
    run = {"precision": precision, "budget_scale": budget_scale, "min_steps": min_steps}
    key = _resume_key(settings, percent, replicate, ts, run)
    if not is_learned(settings.preset):
        rows, stopped = _fit_lookup(model, job), {"epochs": 1, "steps": 0, "reason": "fitted"}
    elif settings.stopping["rule"] == "doubling":
        rule = Doubling.of(settings.stopping, settings.lr, budget_scale, min_steps)
        rows, stopped = _run_doubling(
            model, job, rule, out_dir, key, progress, (percent, replicate), snapshot_every
        )
    else:
        epochs = max(1, round(settings.epochs(percent) * budget_scale))
        rows, stopped = _run_epochs(
            model, job, epochs, out_dir, key, progress, (percent, replicate), snapshot_every
        )
    final = checkpoint_of(
        model, settings, ts, percent, replicate, stopped["epochs"], job.normalisation
    )
    final["training"].update(
        steps=int(stopped["steps"]),
        stopped=stopped["reason"],
        precision=precision,
        machine=describe_machine(),
        fit_frames=int(len(job.fit_idx)),
        holdout_frames=int(len(job.check_idx)) if settings.stopping["rule"] == "doubling" else 0,
    )
    save_checkpoint(out_dir / "model.pt", final)
    write_losses(out_dir / "losses.csv", rows)
    plot_losses(
        out_dir / "losses.png", rows, title=f"{settings.preset}, P={percent}, replicate {replicate}"
    )
    (out_dir / RESUME_NAME).unlink(missing_ok=True)
    return final


def _fit_lookup(model, job: _Job) -> list[dict]:
    """The lookup table is fitted by binning, once: one row of losses."""
    began = time.perf_counter()
    rng = np.random.default_rng([job.settings.seed, 1])
    model.fit(FramePairs(job.ts, job.fit_idx, job.inputs))
    windows = sample_windows(job.ts, job.fit_idx, job.settings, rng)
    args = (job.ts, windows, job.settings, job.device, job.normalisation, job.inputs)
    train_loss = windows_mse(model, *args)
    val_loss = windows_mse(model, job.ts, job.check_windows, *args[2:])
    return [loss_row(1, 0, train_loss, val_loss, _since(began), 0.0)]


def _resume(out_dir: Path, key: str, model, optimizer) -> dict | None:
    """The state of an interrupted run of this very job (same key), restored into model and
    optimizer; None when there is none to resume."""
    path = out_dir / RESUME_NAME
    if not path.is_file():
        return None
    state = read_checkpoint(path)
    if state.get("resume_key") != key:
        return None
    model.load_state_dict(state["state_dict"])
    optimizer.load_state_dict(state["optimizer"])
    return state


def _run_epochs(model, job: _Job, epochs, out_dir, key, progress, job_id, snapshot_every):
    """The paper's rule: epochs_base · 80 / P epochs, the rate scheduled over them."""
    settings = job.settings
    percent, replicate = job_id
    checked = validation_epochs(epochs)
    optimizer = make_optimizer(model, settings)
    rows: list[dict] = []
    start, steps = 1, 0
    state = _resume(out_dir, key, model, optimizer)
    if state is not None:
        rows, start = list(state["losses"]), int(state["epoch"]) + 1
        steps = int(state.get("steps", 0))
    bar = tqdm(
        range(start, epochs + 1),
        desc=f"train P{percent} r{replicate}",
        unit="epoch",
        disable=not progress,
    )
    last_saved = time.monotonic()
    for epoch in bar:
        began = time.perf_counter()
        rng = np.random.default_rng([settings.seed, epoch])
        torch.manual_seed(settings.seed * 1_000_003 + epoch)
        train_loss, batches = _guarded_epoch(model, job, rng, optimizer, (epoch, epochs), epoch)
        steps += batches
        val_loss = _check_loss(model, job) if epoch in checked else float("nan")
        lr = scheduled_lr(settings, epoch, epochs, 0, 1)
        rows.append(loss_row(epoch, steps, train_loss, val_loss, _since(began), lr))
        bar.set_postfix(train=f"{train_loss:.4g}", val=f"{val_loss:.4g}")
        if snapshot_every and epoch in checked:
            _snapshot(out_dir, job, model, _cpu_state(model), (job_id, epoch, steps))
        if epoch < epochs and time.monotonic() - last_saved >= RESUME_EVERY_S:
            extra = {"epoch": epoch, "steps": steps}
            _save_resume(out_dir, model, optimizer, job, percent, replicate, rows, key, extra)
            last_saved = time.monotonic()
    return rows, {"epochs": epochs, "steps": steps, "reason": f"{epochs} epochs (the budget)"}


def _epoch_windows(job: _Job, epoch: int) -> list:
    """Epoch `epoch`'s training windows in the order they are trained (seeded by (seed, epoch))."""
    rng = np.random.default_rng([job.settings.seed, epoch])
    torch.manual_seed(job.settings.seed * 1_000_003 + epoch)
    windows = sample_windows(job.ts, job.fit_idx, job.settings, rng)
    order = rng.permutation(len(windows))
    return [windows[k] for k in order]


def _stream(job: _Job, epoch: int, offset: int):
    """(epoch, batch, batches in the epoch, x, y) from batch `offset` of `epoch` on, epoch after
    epoch: the same stream whether or not a run was interrupted and resumed in between."""
    size = job.settings.batch_size
    while True:
        windows = _epoch_windows(job, epoch)
        batches = -(-len(windows) // size)
        for batch in range(offset, batches):
            chunk = windows[batch * size : (batch + 1) * size]
            (x, y), *_ = input_batches(job.ts, chunk, size, job.inputs)
            yield epoch, batch, batches, x, y
        epoch, offset = epoch + 1, 0


def _run_doubling(model, job: _Job, rule: Doubling, out_dir, key, progress, job_id, snapshot_every):
    """Cosine cycles, each as long as all before it, until one no longer pays on the holdout;
    the best weights checked are the model."""
    percent, replicate = job_id
    optimizer = make_optimizer(model, job.settings)
    best = _cpu_state(model)
    epoch, offset = 1, 0
    state = _resume(out_dir, key, model, optimizer)
    if state is not None:
        rows, best = list(state["losses"]), dict(state["best"])
        rule = Doubling.from_state(state["rule"])
        epoch, offset = int(state["epoch"]), int(state["offset"])
        torch.set_rng_state(state["torch_rng"])
    else:  # where it starts: the initial (pretrained or fresh) weights' own holdout error
        rule.best = _check_loss(model, job)
        rows = [loss_row(0, 0, float("nan"), rule.best, 0.0, rule.lr)]
    cap = max(rule.max_steps, rule.min_steps)
    bar = tqdm(
        total=cap, initial=rule.steps, desc=f"train {job.name}", unit="step", disable=not progress
    )
    stream = _stream(job, epoch, offset)
    last_saved = time.monotonic()
    while not rule.done:
        length, began = rule.next_cycle(), time.perf_counter()
        total, count = 0.0, 0
        for step in range(length):
            epoch, batch, batches, x, y = next(stream)
            total += _guarded_step(model, job, optimizer, x, y, rule.lr_at(step, length), epoch)
            count += len(x)
            bar.update(1)
        if rule.observe(rule.steps + length, _check_loss(model, job)):
            best = _cpu_state(model)
        position = round(epoch - 1 + (batch + 1) / batches, 3)
        rows.append(
            loss_row(
                position, rule.steps, total / count, rule.history[-1][1], _since(began), rule.lr
            )
        )
        bar.set_postfix(check=f"{rule.history[-1][1]:.4g}", best=f"{rule.best:.4g}")
        if snapshot_every and rule.cycle % snapshot_every == 0:
            _snapshot(out_dir, job, model, best, (job_id, epoch, rule.steps))
        epoch, offset = (epoch + 1, 0) if batch + 1 == batches else (epoch, batch + 1)
        stream = _stream(job, epoch, offset)
        if not rule.done and time.monotonic() - last_saved >= RESUME_EVERY_S:
            extra = {
                "epoch": epoch,
                "offset": offset,
                "steps": rule.steps,
                "rule": rule.state(),
                "best": best,
                "torch_rng": torch.get_rng_state(),
            }
            _save_resume(out_dir, model, optimizer, job, percent, replicate, rows, key, extra)
            last_saved = time.monotonic()
    bar.close()
    model.load_state_dict(best)
    if snapshot_every and rule.cycle % snapshot_every:
        _snapshot(out_dir, job, model, best, (job_id, epoch, rule.steps))
    return rows, {"epochs": epoch, "steps": rule.steps, "reason": rule.reason}


def _since(began: float) -> float:
    return round(time.perf_counter() - began, 3)


def _check_loss(model, job: _Job) -> float:
    args = (job.ts, job.check_windows, job.settings, job.device, job.normalisation, job.inputs)
    return windows_mse(model, *args)


def _guarded_epoch(model, job: _Job, rng, optimizer, position, epoch) -> tuple[float, int]:
    try:
        return train_epoch(
            model,
            job.ts,
            job.fit_idx,
            job.settings,
            rng,
            job.device,
            optimizer,
            job.normalisation,
            job.inputs,
            position,
            job.precision,
        )
    except TrainingError as exc:
        raise _job_error(job, epoch, exc) from None


def _guarded_step(model, job: _Job, optimizer, x, y, lr: float, epoch: int) -> float:
    """One optimiser step at rate `lr`: the batch's loss times its size."""
    for group in optimizer.param_groups:
        group["lr"] = lr
    try:
        value = optimizer_step(
            model,
            job.ts,
            job.settings,
            job.device,
            optimizer,
            job.normalisation,
            x,
            y,
            job.precision,
        )
    except TrainingError as exc:
        raise _job_error(job, epoch, TrainingError(f"the loss of a batch is {exc}")) from None
    return value * len(x)


def _job_error(job: _Job, epoch: int, exc: TrainingError) -> TrainingError:
    return TrainingError(
        f"training {job.name} ({job.settings.preset}), epoch {epoch}: {exc}; "
        + divergence_hint(job.precision)
    )


def _save_resume(out_dir, model, optimizer, job, percent, replicate, rows, key, extra) -> None:
    state = checkpoint_of(
        model, job.settings, job.ts, percent, replicate, extra["epoch"], job.normalisation
    )
    state.update(optimizer=optimizer.state_dict(), losses=rows, resume_key=key, **extra)
    save_checkpoint(out_dir / RESUME_NAME, state)


def _snapshot(out_dir: Path, job: _Job, model, weights: dict, position) -> None:
    """A usable checkpoint of `weights` (the best so far) after `steps`: one point of the
    error-against-time curve (losses.csv's row of that step says how long it took)."""
    (percent, replicate), epoch, steps = position
    snapshot = checkpoint_of(
        model, job.settings, job.ts, percent, replicate, epoch, job.normalisation
    )
    snapshot["state_dict"] = weights
    snapshot["training"]["steps"] = int(steps)
    save_checkpoint(out_dir / SNAPSHOT_DIR / snapshot_name(steps), snapshot)


def checkpoint_of(model, settings, ts, percent, replicate, epoch, normalisation) -> dict:
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "preset": settings.preset,
        "preset_args": preset_args(settings.preset)
        if settings.init is None
        else _init_args(settings, ts),
        "state_dict": _cpu_state(model),
        "normalisation": normalisation,
        "blank": torch.from_numpy(np.ascontiguousarray(ts.blank, dtype=np.float32)),
        "px_per_mm": float(ts.px_per_mm),
        "image_shape": list(ts.image_shape),
        # how camera frames become this model's input (DepthEstimator.rectify)
        "camera": {
            "lens": (ts.meta or {}).get("lens"),
            "downscale": int((ts.meta or {}).get("downscale", 1)),
        },
        # where the model's pixels lie on the printer and the gel (DepthEstimator.points); None for
        # an imported dataset (no printer)
        "registration": (ts.meta or {}).get("registration"),
        "dome": (ts.meta or {}).get("dome"),
        "training": {
            "percent": int(percent),
            "replicate": int(replicate),
            "epochs": int(epoch),
            "settings": {k: v for k, v in asdict(settings).items() if v is not None},
        },
    }


def _init_args(settings: TrainSettings, ts: TrainingSet) -> dict:
    return dict(read_checkpoint(init_path(settings.init, ts)).get("preset_args", {}))
