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
import math
import os
import time
from collections.abc import Mapping
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
    adapt_inputs,
    model_from_checkpoint,
    read_checkpoint,
    save_checkpoint,
)
from threedcal.model.drift import drift_offset, remove_drift
from threedcal.model.loss_log import plot_losses, write_losses
from threedcal.model.losses import gradient_loss
from threedcal.model.machine import describe as describe_machine
from threedcal.model.machine import resolve_precision, torch_device
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
from threedcal.schema import load_schema, section

RESUME_NAME = "checkpoint.pt"
# The resume checkpoint is rewritten after an epoch only when this long has passed since the last:
# a P = 1 % job runs 320 short epochs, and saving after each cost 5 % of its time. An interrupted
# job redoes at most this much, and ends with the same bytes either way.
RESUME_EVERY_S = 20.0


def _or(value, default):
    return default if value is None else value


@dataclass(frozen=True)
class TrainSettings:
    """Every setting a training reads: the scene's `model:` section plus seed and threads.

    No defaults of its own: `from_scene` / `of` fill what a config leaves out from the config
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
    def from_scene(cls, scene: Mapping) -> TrainSettings:
        return cls.of(
            seed=scene.get("seed"),
            torch_threads=scene.get("torch_threads"),
            **scene.get("model", {}),
        )

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


def _window(top: int, left: int, size: tuple[int, int]) -> tuple[slice, slice]:
    return slice(top, top + size[0]), slice(left, left + size[1])


def sample_windows(
    ts: TrainingSet, indices: np.ndarray, settings: TrainSettings, rng: np.random.Generator
) -> list[tuple[int, tuple[slice, slice]]]:
    """Contact patches (centre jittered by up to a third of the patch) and background patches."""
    height, width = ts.image_shape
    size = (min(settings.patch_px, height), min(settings.patch_px, width))
    out = []
    for i in indices:
        cx, cy = ts.center_px[i]
        # skirt_reach > 0 lets patches cover the gel outside the contact too: it deforms and changes
        # colour there, while its label is flat (and integrating wrong slopes there biases depth).
        reach = settings.skirt_reach * float(ts.eval_radius_px[i])
        jitter = (max(size[0] / 3, reach), max(size[1] / 3, reach))
        for _ in range(settings.contact_patches):
            jx, jy = rng.uniform(-jitter[1], jitter[1]), rng.uniform(-jitter[0], jitter[0])
            top = int(np.clip(round(cy + jy - size[0] / 2), 0, height - size[0]))
            left = int(np.clip(round(cx + jx - size[1] / 2), 0, width - size[1]))
            out.append((int(i), _window(top, left, size)))
        for _ in range(settings.background_patches):
            top = int(rng.integers(0, height - size[0] + 1))
            left = int(rng.integers(0, width - size[1] + 1))
            out.append((int(i), _window(top, left, size)))
    return out


class ModelInputs:
    """Network inputs of a TrainingSet's frames or windows, with the frame's lighting drift removed.

    The drift offset is estimated once per frame on the full frame (as inference does), then
    subtracted from every window of it.
    """

    def __init__(self, ts: TrainingSet, mode: str) -> None:
        self.ts, self.mode = ts, mode
        self._offsets: dict[int, torch.Tensor] = {}

    def offset(self, i: int) -> torch.Tensor:
        if i not in self._offsets:
            self._offsets[i] = drift_offset(torch.from_numpy(self.ts.inputs(i))[None])[0]
        return self._offsets[i]

    def __call__(self, i: int, window: tuple[slice, slice] | None = None) -> torch.Tensor:
        x = torch.from_numpy(self.ts.inputs(i, window))[None]
        if self.mode == "none":
            return x[0]
        return remove_drift(x, self.mode, self.offset(i)[None])[0]


def input_batches(ts, windows, batch_size, inputs: ModelInputs):
    for start in range(0, len(windows), batch_size):
        chunk = windows[start : start + batch_size]
        x = torch.stack([inputs(i, w) for i, w in chunk])
        y = np.stack([ts.labels(i, w) for i, w in chunk])
        yield x, torch.from_numpy(y)


def configure_torch(settings: TrainSettings) -> torch.device:
    """Threads, determinism and device, set before any tensor is made."""
    os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")  # deterministic cuBLAS
    reuse_freed_memory()
    torch.set_num_threads(settings.torch_threads)
    torch.use_deterministic_algorithms(True)
    torch.backends.cudnn.benchmark = False
    return torch_device(settings.device)


# Bumped when the same settings train differently: a checkpoint of an interrupted run of the older
# code is then not resumed under the newer one (2: the cosine rate per batch, no longer per epoch;
# 3: the stopping rules and the precision resolved per machine; 4: `auto` is float32 on GPUs).
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
    from threedcal.pretrained import shipped_weights

    return shipped_weights((ts.meta or {}).get("sensor"), ts.image_shape)


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
    from threedcal.dataset.splits import replicate_seed

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
    model.fit(_Pairs(job.ts, job.fit_idx, job.inputs))
    windows = sample_windows(job.ts, job.fit_idx, job.settings, rng)
    args = (job.ts, windows, job.settings, job.device, job.normalisation, job.inputs)
    train_loss = windows_mse(model, *args)
    val_loss = windows_mse(model, job.ts, job.check_windows, *args[2:])
    return [loss_row(1, 0, train_loss, val_loss, _since(began), 0.0)]


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
        return _train_epoch(
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


def _train_epoch(
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


class _Pairs:
    """Re-iterable (inputs, labels) of full frames, read lazily (the lookup fit reads them twice)."""

    def __init__(self, ts: TrainingSet, indices: np.ndarray, inputs: ModelInputs):
        self.ts, self.indices, self.inputs = ts, indices, inputs

    def __iter__(self):
        for i in self.indices:
            yield self.inputs(int(i)).numpy(), self.ts.labels(int(i))


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
