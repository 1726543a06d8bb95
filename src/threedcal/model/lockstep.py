"""The ablation's trainings: every model of a fraction P (its replicates) trained together for the
same number of optimiser steps, with no stopping decision, snapshots at the ends of its cycles.

An ablation compares what each fraction's data can teach, so every model trains the same steps
(the paper keeps steps equal: N = 60 x 80/P epochs). Its learning rate runs in the `doubling`
rule's cycles (a half cosine each, each as long as all before it) from a quarter of the budget:
the cycles end at budget/4, budget/2 and the budget, and, with `twice`, one more cycle as long as
all before it ends at twice the budget. Each cycle end is a snapshot of every model: the error
against training time, and the ablation read again at twice the budget, come from the same
trainings.

Each model keeps its own subset, seed, patch stream and optimiser state; the models only share
the steps. Two ways to run them (`batching`), the same arithmetic up to float rounding:

loop   one model after another, each step: on a CPU these small networks are bound by their
       arithmetic, and `make bench` (bench_lockstep) finds the stacked form no faster there;
vmap   the models' weights stacked and the step vectorised (torch.func.vmap: the convolutions
       become one grouped convolution), one optimiser over the stacks (AdamW is elementwise, so
       it is each model's own): on a GPU one launch serves every model.
`auto` is vmap on a GPU and loop on a CPU: a choice of the machine, never of a timing, so one host
always trains the same bytes.
"""

from __future__ import annotations

import copy
import hashlib
import json
import logging
import pickle
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch.func import functional_call, stack_module_state, vmap
from tqdm import tqdm

from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError, TrainingError
from threedcal.model.checkpoint import adapt_inputs, save_checkpoint
from threedcal.model.loss_log import plot_losses, write_losses
from threedcal.model.losses import gradient_loss
from threedcal.model.machine import describe as describe_machine
from threedcal.model.machine import resolve_precision
from threedcal.model.patches import ModelInputs, input_batches, sample_windows
from threedcal.model.presets import is_learned, preferred_memory_format
from threedcal.model.stopping import SNAPSHOT_DIR, TWICE_DIR, Doubling, cycle_ends, snapshot_name
from threedcal.model.train import (
    RESUME_EVERY_S,
    TRAINING_SEMANTICS,
    checkpoint_of,
    configure_torch,
    initial_model,
)
from threedcal.model.train_settings import TrainSettings
from threedcal.model.train_step import (
    VALIDATION_WINDOWS,
    divergence_hint,
    loss_row,
    make_optimizer,
    optimizer_step,
    training_autocast,
    validation_settings,
    windows_mse,
)
from threedcal.seeds import replicate_seed

BATCHINGS = ("auto", "loop", "vmap")


def resolve_batching(batching: str, device: torch.device) -> str:
    """`auto`: vmap on a GPU, loop on a CPU (see the module docstring)."""
    if batching not in BATCHINGS:
        raise ConfigError(f"ablation.batching: {batching!r} (allowed: {', '.join(BATCHINGS)})")
    if batching != "auto":
        return batching
    return "loop" if device.type == "cpu" else "vmap"


@dataclass(frozen=True)
class Member:
    """One model of the lockstep: replicate r of fraction `percent`, written to out_dir."""

    percent: int
    replicate: int
    out_dir: Path


class WindowStream:
    """A model's training windows as one endless sequence, epoch after epoch: epoch e's windows are
    drawn and shuffled with the seed (seed, e), as the single trainer draws them; batches run on
    across epoch ends, so every step has a full batch and step k's windows depend on k alone."""

    def __init__(self, ts: TrainingSet, fit_idx: np.ndarray, settings: TrainSettings):
        self.ts, self.fit_idx, self.settings = ts, fit_idx, settings
        self.per_epoch = len(fit_idx) * (settings.contact_patches + settings.background_patches)
        if self.per_epoch == 0:
            raise ConfigError("a training needs at least one patch per frame")
        self.epoch, self.position, self.windows = 0, 0, []

    def _epoch(self, epoch: int) -> list:
        rng = np.random.default_rng([self.settings.seed, epoch])
        windows = sample_windows(self.ts, self.fit_idx, self.settings, rng)
        order = rng.permutation(len(windows))
        return [windows[k] for k in order]

    def seek(self, step: int) -> None:
        """Place the stream at the first window of step `step` (0-based)."""
        start = step * self.settings.batch_size
        epoch = start // self.per_epoch + 1
        if epoch != self.epoch:
            self.epoch, self.windows = epoch, self._epoch(epoch)
        self.position = start % self.per_epoch

    def take(self, count: int) -> list:
        out = []
        while len(out) < count:
            if self.position == len(self.windows):
                self.epoch, self.position = self.epoch + 1, 0
                self.windows = self._epoch(self.epoch)
            chunk = self.windows[self.position : self.position + count - len(out)]
            out += chunk
            self.position += len(chunk)
        return out

    @property
    def epochs_done(self) -> float:
        return round(self.epoch - 1 + self.position / self.per_epoch, 3)


@dataclass
class _Model:
    """A member's fixed inputs and running state."""

    member: Member
    settings: TrainSettings  # its seed is the replicate's
    fit_idx: np.ndarray
    check_windows: list  # the validation split's windows its loss log reads (chooses nothing)
    stream: WindowStream
    inputs: ModelInputs
    normalisation: dict
    module: torch.nn.Module
    optimizer: torch.optim.Optimizer | None = None
    rows: list | None = None

    @property
    def name(self) -> str:
        return f"P={self.member.percent} r{self.member.replicate}"


def _prepare(ts: TrainingSet, member: Member, settings: TrainSettings, device) -> _Model:
    settings = replace(settings, seed=replicate_seed(settings.seed, member.replicate))
    fit_idx = ts.indices("train", percent=member.percent, replicate=member.replicate)
    if len(fit_idx) == 0:
        raise ConfigError(
            f"P={member.percent}, replicate {member.replicate}: no training frames in this "
            "dataset's split"
        )
    check_rng = np.random.default_rng([settings.seed, 1 << 20])
    windows = sample_windows(ts, ts.indices("val"), validation_settings(settings), check_rng)
    if len(windows) > VALIDATION_WINDOWS:
        keep = np.sort(check_rng.choice(len(windows), VALIDATION_WINDOWS, replace=False))
        windows = [windows[k] for k in keep]
    module, normalisation = initial_model(settings, ts)
    module.to(device=device, memory_format=preferred_memory_format(module))
    inputs = ModelInputs(ts, normalisation["drift"])
    return _Model(
        member,
        settings,
        fit_idx,
        windows,
        WindowStream(ts, fit_idx, settings),
        inputs,
        normalisation,
        module,
        rows=[],
    )


class _Diverged(Exception):
    """Model `index`'s loss of a step is `value`, not finite."""

    def __init__(self, index: int, value: float):
        super().__init__(index, value)
        self.index, self.value = index, value


class _Loop:
    """One model after another: each its own module and AdamW (the single trainer's step)."""

    def __init__(self, models: Sequence[_Model], ts, device, precision):
        self.models, self.ts, self.device, self.precision = models, ts, device, precision
        for model in models:
            model.optimizer = make_optimizer(model.module, model.settings)

    def step(self, batches, lr: float) -> list[float]:
        losses = []
        for index, (model, (x, y)) in enumerate(zip(self.models, batches, strict=True)):
            for group in model.optimizer.param_groups:
                group["lr"] = lr
            try:
                value = optimizer_step(
                    model.module,
                    self.ts,
                    model.settings,
                    self.device,
                    model.optimizer,
                    model.normalisation,
                    x,
                    y,
                    self.precision,
                )
            except TrainingError as exc:
                raise _Diverged(index, float(str(exc))) from None
            losses.append(value)
        return losses

    def sync(self) -> None:
        """The modules hold the weights already."""

    def state(self) -> dict:
        return {
            "modules": [m.module.state_dict() for m in self.models],
            "optimizers": [m.optimizer.state_dict() for m in self.models],
        }

    def restore(self, state: dict) -> None:
        for model, weights, optimizer in zip(
            self.models, state["modules"], state["optimizers"], strict=True
        ):
            model.module.load_state_dict(weights)
            model.optimizer.load_state_dict(optimizer)


class _Vmap:
    """The models' weights stacked, one vectorised step for all, one AdamW over the stacks."""

    def __init__(self, models: Sequence[_Model], ts, device, precision):
        self.models, self.ts, self.device, self.precision = models, ts, device, precision
        first = models[0]
        if any(m.normalisation != first.normalisation for m in models):
            raise ConfigError("models trained in lockstep must share their input normalisation")
        self.template = copy.deepcopy(first.module).to("meta")
        params, self.buffers = stack_module_state([m.module for m in models])
        self.params = {k: v.detach().clone().requires_grad_() for k, v in params.items()}
        settings = first.settings
        self.optimizer = torch.optim.AdamW(
            list(self.params.values()), lr=settings.lr, weight_decay=settings.weight_decay
        )
        self.sign = first.normalisation["gradient_sign"]
        self.loss_kind = settings.loss
        self.normalisation = first.normalisation

    def _loss(self, params, buffers, x, y):
        prediction = functional_call(self.template, (params, buffers), (x,))
        return gradient_loss(prediction.float() * self.sign, y, self.loss_kind)

    def step(self, batches, lr: float) -> list[float]:
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        shape = self.ts.image_shape
        x = torch.stack(
            [adapt_inputs(x.to(self.device), self.normalisation, shape) for x, _ in batches]
        )
        y = torch.stack([y for _, y in batches]).to(self.device)
        self.optimizer.zero_grad(set_to_none=True)
        with training_autocast(self.precision, self.device):
            losses = vmap(self._loss)(self.params, self.buffers, x, y)
        values = losses.detach().cpu().tolist()
        for index, value in enumerate(values):
            if not np.isfinite(value):
                raise _Diverged(index, value)
        losses.sum().backward()
        self.optimizer.step()
        return values

    def sync(self) -> None:
        """Copy the stacked weights back into each model's module (for its checkpoint)."""
        with torch.no_grad():
            for i, model in enumerate(self.models):
                model.module.load_state_dict(
                    {k: v[i].detach() for k, v in self.params.items()}, strict=False
                )

    def state(self) -> dict:
        return {
            "params": {k: v.detach() for k, v in self.params.items()},
            "optimizer": self.optimizer.state_dict(),
        }

    def restore(self, state: dict) -> None:
        with torch.no_grad():
            for key, value in state["params"].items():
                self.params[key].copy_(value)
        self.optimizer.load_state_dict(state["optimizer"])


def _lr(rule: Doubling, ends: Sequence[int], step: int) -> float:
    """The rate of step `step` (0-based): a half cosine over the cycle it lies in."""
    start = 0
    for end in ends:
        if step < end:
            return rule.lr_at(step - start, end - start)
        start = end
    raise ValueError(f"step {step} lies past the last cycle ({ends[-1]})")


def _resume_key(ts, members, settings, budget, twice, batching, precision) -> str:
    described = {
        "semantics": TRAINING_SEMANTICS,
        "settings": asdict(settings),
        "members": [(m.percent, m.replicate) for m in members],
        "budget": int(budget),
        "twice": bool(twice),
        "batching": batching,
        "precision": precision,
        "frames": list(ts.frames.shape),
        "meta": ts.meta or {},
    }
    return hashlib.sha256(json.dumps(described, sort_keys=True, default=str).encode()).hexdigest()


def _checked(ts, members: Sequence[Member], settings: TrainSettings) -> TrainingSet:
    """The training set (loaded from its folder if need be), once the members and the preset are
    ones that can train in lockstep."""
    if not members:
        raise ConfigError("train_lockstep needs at least one model")
    if len({(m.percent, m.replicate) for m in members}) < len(members):
        raise ConfigError("train_lockstep: a model (P, replicate) is listed twice")
    if not isinstance(ts, TrainingSet):
        ts = TrainingSet.load(ts)
    if not is_learned(settings.preset):
        raise ConfigError(f"model.preset {settings.preset!r} is fitted, not trained in steps")
    return ts


def train_lockstep(
    ts: TrainingSet | str | Path,
    members: Sequence[Member],
    settings: TrainSettings,
    budget: int,
    *,
    twice: bool = False,
    batching: str = "auto",
    resume: str | Path | None = None,
    progress: bool = True,
) -> list[dict]:
    """Train every member for `budget` steps (and on to twice that with `twice`), together.

    Writes per member: out_dir/model.pt, losses.csv, losses.png at the budget; out_dir/snapshots/
    step{n}.pt at each earlier cycle end; out_dir/twice/{model.pt, losses.csv, losses.png} at twice
    the budget. `resume`: a file the state is kept in every RESUME_EVERY_S, so that an interrupted
    job goes on where it stopped and ends with the same bytes. Returns the checkpoints at the budget.
    """
    ts = _checked(ts, members, settings)
    ends = cycle_ends(budget, twice)
    device = configure_torch(settings)
    precision = resolve_precision(settings.precision, device, settings.preset)
    batching = resolve_batching(batching, device)
    logging.getLogger(__name__).info(
        "training %d models in lockstep (%s) on %s in %s: %d steps%s",
        len(members),
        batching,
        device,
        precision,
        budget,
        ", then on to twice that" if twice else "",
    )
    models = [_prepare(ts, member, settings, device) for member in members]
    runner = (_Loop if batching == "loop" else _Vmap)(models, ts, device, precision)
    rule = Doubling.of(
        {"first_cycle": ends[0], "min_gain": 0.0, "max_steps": ends[-1]}, settings.lr
    )
    key = _resume_key(ts, members, settings, budget, twice, batching, precision)
    state = _read_resume(resume, key)
    step, totals, written = _start(state, runner, models, ts, device, settings.lr, budget)
    bar = tqdm(
        total=ends[-1],
        initial=step,
        desc=f"train {len(models)} models",
        unit="step",
        disable=not progress,
    )
    began, saved = time.perf_counter(), time.monotonic()
    for index, end in enumerate(ends):
        start = ends[index - 1] if index else 0
        if step >= end:
            continue
        while step < end:
            batches = _batches(models, ts, step, settings.batch_size)
            try:
                values = runner.step(batches, _lr(rule, ends, step))
            except _Diverged as exc:
                raise TrainingError(
                    f"training {models[exc.index].name} ({settings.preset}), step {step + 1}: "
                    f"the loss of a batch is {exc.value}; " + divergence_hint(precision)
                ) from None
            totals += np.asarray(values) * settings.batch_size
            step += 1
            bar.update(1)
            if resume is not None and step < end and time.monotonic() - saved >= RESUME_EVERY_S:
                _save_resume(resume, key, runner, models, step, totals, written)
                saved = time.monotonic()
        runner.sync()
        seconds = round(time.perf_counter() - began, 3)
        _log_cycle(models, ts, device, totals, (start, end), settings.batch_size, seconds, rule)
        totals[:] = 0.0
        written[end] = _cycle_checkpoints(models, ts, end, precision, batching)
        _write_outputs(models, written[end], end, budget)
        if resume is not None:
            _save_resume(resume, key, runner, models, step, totals, written)
        began, saved = time.perf_counter(), time.monotonic()
    bar.close()
    if resume is not None:
        Path(resume).unlink(missing_ok=True)
    return written[budget]


def _start(state, runner, models, ts, device, lr: float, budget: int):
    """(step, loss totals, checkpoints written per cycle end) where the run starts: restored from
    an interrupted run's `state` (its checkpoints written again: Snakemake removed them), else at
    step 0 with each model's first row the check loss of its initial weights."""
    step, totals = 0, np.zeros(len(models))
    written: dict[int, list[dict]] = {}
    if state is not None:
        runner.restore(state["runner"])
        step, totals = int(state["step"]), np.asarray(state["totals"], float)
        for model, rows in zip(models, state["rows"], strict=True):
            model.rows = list(rows)
        written = {int(end): checkpoints for end, checkpoints in state["written"].items()}
        for end, checkpoints in sorted(written.items()):
            _write_outputs(models, checkpoints, end, budget)
    else:
        for model in models:
            model.rows = [loss_row(0, 0, float("nan"), _check(model, ts, device), 0.0, lr)]
    return step, totals, written


def _batches(models, ts: TrainingSet, step: int, batch_size: int) -> list:
    """Every member's (x, y) batch of training step `step`."""
    batches = []
    for model in models:
        model.stream.seek(step)
        windows = model.stream.take(batch_size)
        (x, y), *_ = input_batches(ts, windows, batch_size, model.inputs)
        batches.append((x, y))
    return batches


def _log_cycle(models, ts, device, totals, span, batch_size: int, seconds: float, rule) -> None:
    """Each member's losses row at the end of the cycle `span` (start, end step)."""
    start, end = span
    for i, model in enumerate(models):
        model.stream.seek(end)
        train_loss = float(totals[i] / ((end - start) * batch_size))
        check = _check(model, ts, device)
        share = seconds / len(models)
        model.rows.append(
            loss_row(model.stream.epochs_done, end, train_loss, check, share, rule.lr_at(0, 1))
        )


def _read_resume(path, key) -> dict | None:
    if path is None or not Path(path).is_file():
        return None
    try:  # our own file of plain tensors and numbers
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (RuntimeError, EOFError, OSError, pickle.UnpicklingError):
        return None  # damaged: trained anew
    whole = isinstance(state, dict) and "written" in state
    return state if whole and state.get("resume_key") == key else None


def _save_resume(path, key, runner, models, step, totals, written) -> None:
    state = {
        "resume_key": key,
        "step": int(step),
        "totals": [float(t) for t in totals],
        "rows": [m.rows for m in models],
        "runner": runner.state(),
        "written": {str(end): checkpoints for end, checkpoints in written.items()},
    }
    save_checkpoint(path, state)


def _check(model: _Model, ts: TrainingSet, device) -> float:
    """The validation split's loss on a fixed set of windows: the loss log's, chooses nothing."""
    args = (ts, model.check_windows, model.settings, device, model.normalisation, model.inputs)
    return windows_mse(model.module, *args)


def _cycle_checkpoints(models, ts, steps, precision, batching) -> list[dict]:
    """Every model's checkpoint at a cycle end."""
    checkpoints = []
    for model in models:
        member = model.member
        checkpoint = checkpoint_of(
            model.module,
            model.settings,
            ts,
            member.percent,
            member.replicate,
            int(np.ceil(model.stream.epochs_done)),
            model.normalisation,
        )
        checkpoint["training"].update(
            steps=int(steps),
            stopped=f"{steps} steps: every model of the ablation trains the same steps",
            precision=precision,
            batching=batching,
            machine=describe_machine(),
            fit_frames=int(len(model.fit_idx)),
            holdout_frames=0,
        )
        checkpoints.append(checkpoint)
    return checkpoints


def _write_outputs(models, checkpoints, steps, budget) -> None:
    """Snapshots at an earlier cycle end; model.pt and losses at the budget; twice/ after it."""
    for model, checkpoint in zip(models, checkpoints, strict=True):
        member, out = model.member, Path(model.member.out_dir)
        if steps < budget:
            save_checkpoint(out / SNAPSHOT_DIR / snapshot_name(steps), checkpoint)
            continue
        folder = out if steps == budget else out / TWICE_DIR
        folder.mkdir(parents=True, exist_ok=True)
        save_checkpoint(folder / "model.pt", checkpoint)
        rows = [r for r in model.rows if r["step"] <= steps]
        write_losses(folder / "losses.csv", rows)
        title = f"{model.settings.preset}, P={member.percent}, replicate {member.replicate}"
        if steps > budget:
            title += f", {steps} steps"
        plot_losses(folder / "losses.png", rows, title=title)
