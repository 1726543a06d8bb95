"""Stopping rules (threedcal.model.stopping) and the machine-chosen precision (threedcal.model.machine)."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
import torch
from test_model import TINY, synthetic_set

from threedcal.errors import ConfigError
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.machine import resolve_precision
from threedcal.model.stopping import Plateau, holdout_split
from threedcal.model.train import TrainSettings, train

RULE = {
    "rule": "plateau",
    "holdout": 0.2,
    "check_every": 10,
    "patience": 2,
    "min_improvement": 0.05,
    "lr_drops": 1,
    "drop_factor": 0.1,
    "max_steps": 1000,
}


def test_holdout_is_a_seeded_share_of_the_models_own_frames_and_none_when_too_few():
    frames = np.arange(100, 120)
    fit, hold = holdout_split(frames, 0.2, seed=3)
    assert len(hold) == 4 and len(fit) == 16
    assert set(fit) | set(hold) == set(frames) and not set(fit) & set(hold)
    assert np.array_equal(hold, holdout_split(frames, 0.2, seed=3)[1])
    assert not np.array_equal(hold, holdout_split(frames, 0.2, seed=4)[1])
    assert len(holdout_split(frames[:5], 0.2, seed=0)[1]) == 1  # at least one
    fit, hold = holdout_split(frames[:2], 0.2, seed=0)  # two frames: both train
    assert len(hold) == 0 and len(fit) == 2


def test_plateau_drops_the_rate_after_patience_then_stops_after_the_last_drop():
    rule = Plateau.of(RULE, lr=1e-2)
    assert rule.current_lr == 1e-2 and not rule.due(9) and rule.due(10)
    assert rule.observe(10, 1.0) == (True, False)
    assert rule.observe(20, 0.9) == (True, False)  # a 10 % gain
    assert rule.observe(30, 0.88) == (True, False)  # better, but by less than 5 %: stale 1
    assert rule.observe(40, 0.95) == (False, True)  # stale 2 = patience: the rate drops
    assert rule.current_lr == pytest.approx(1e-3) and not rule.done
    assert rule.best == 0.88 and rule.best_step == 30
    rule.observe(50, 0.87)
    assert not rule.done
    rule.observe(60, 0.87)
    assert rule.done and "stopped falling" in rule.reason
    restored = Plateau.from_state(rule.state())
    assert restored == rule


def test_plateau_stops_at_max_steps_and_a_scale_stretches_patience_and_cap():
    rule = Plateau.of({**RULE, "max_steps": 25}, lr=1.0)
    for step in (10, 20, 30):
        rule.observe(step, 1.0 / step)
    assert rule.done and "max_steps (25)" in rule.reason
    long = Plateau.of(RULE, lr=1.0, scale=2.0, min_steps=500)
    assert long.patience == 4 and long.max_steps == 2000
    for step in range(10, 500, 10):  # never improves, yet cannot stop before min_steps
        long.observe(step, 1.0)
        assert not long.done
    with pytest.raises(ConfigError, match="holdout error at step 7 is nan"):
        long.observe(7, float("nan"))


def test_auto_precision_is_bfloat16_only_where_the_cpu_has_it(monkeypatch):
    import threedcal.model.machine as machine

    cpu = torch.device("cpu")
    monkeypatch.setattr(machine, "native_bfloat16", lambda: False)
    assert resolve_precision("auto", cpu) == "float32"
    monkeypatch.setattr(machine, "native_bfloat16", lambda: True)
    assert resolve_precision("auto", cpu) == "bfloat16"
    assert resolve_precision("float32", cpu) == "float32"
    assert resolve_precision("auto", cpu, "context_half") == "bfloat16"
    assert resolve_precision("auto", cpu, "multiscale") == "float32"  # NaN in bfloat16
    assert resolve_precision("auto", cpu, "touchnet") == "float32"  # not checked in it
    with pytest.raises(ConfigError, match="allowed: auto, float32, bfloat16"):
        resolve_precision("half", cpu)


def test_an_avx2_cap_rules_out_native_bfloat16(monkeypatch):
    import threedcal.model.machine as machine

    machine.native_bfloat16.cache_clear()
    try:
        monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX2")
        assert machine.native_bfloat16() is False
    finally:
        machine.native_bfloat16.cache_clear()


def test_the_model_records_the_precision_it_trained_in_and_the_machine(tmp_path, monkeypatch):
    import threedcal.model.machine as machine

    monkeypatch.setattr(machine, "native_bfloat16", lambda: False)
    settings = TrainSettings.of(preset="compact_tiny", seed=3, precision="auto", **TINY)
    checkpoint = train(synthetic_set(), tmp_path, 80, settings, progress=False)
    assert checkpoint["training"]["precision"] == "float32"
    assert checkpoint["training"]["settings"]["precision"] == "auto"
    assert {"cpu_capability", "native_bfloat16", "cores"} <= set(checkpoint["training"]["machine"])


def plateau_settings(**changes):
    return TrainSettings.of(
        preset="compact_tiny",
        seed=5,
        lr=1e-2,
        stopping={**RULE, "check_every": 2, **changes},
        **{**TINY, "batch_size": 2},
    )


def test_plateau_training_never_fits_its_holdout_and_says_why_it_stopped(tmp_path, monkeypatch):
    import threedcal.model.train as module

    ts = synthetic_set(n=12)
    ts.samples["split"] = ["train"] * 10 + ["val"] * 2
    ts.samples["min_p"] = [80] * 10 + [0, 0]
    ts = replace(ts)  # re-derive the arrays
    fitted = []
    real = module._train_epoch
    monkeypatch.setattr(
        module, "_train_epoch", lambda m, t, idx, *a: fitted.append(set(idx)) or real(m, t, idx, *a)
    )
    checkpoint = train(ts, tmp_path, 80, plateau_settings(), progress=False)
    training = checkpoint["training"]
    assert training["holdout_frames"] == 2 and training["fit_frames"] == 8
    _, hold = holdout_split(ts.indices("train", percent=80), 0.2, 5)
    assert all(not (idx & set(hold)) for idx in fitted)
    assert all(not (idx & {10, 11}) for idx in fitted)  # nor the stats stage's validation frames
    assert "stopped falling" in training["stopped"] or "max_steps" in training["stopped"]
    losses = pd.read_csv(tmp_path / "losses.csv")
    assert losses["step"].iloc[0] == 0 and losses["step"].is_monotonic_increasing
    assert training["steps"] == losses["step"].iloc[-1]


def test_plateau_keeps_the_best_weights_it_checked(tmp_path, monkeypatch):
    import threedcal.model.train as module

    errors = iter([1.0, 0.5, 0.7, 0.9, 0.95, 0.99, 1.0, 1.0, 1.0, 1.0])
    states = []
    real_check = module._check_loss

    def scripted(model, job):
        real_check(model, job)
        states.append({k: v.clone() for k, v in model.state_dict().items()})
        return next(errors)

    monkeypatch.setattr(module, "_check_loss", scripted)
    checkpoint = train(synthetic_set(n=12), tmp_path, 80, plateau_settings(), progress=False)
    best = states[1]  # the 0.5
    for name, value in checkpoint["state_dict"].items():
        assert torch.equal(value, best[name])


def test_an_interrupted_plateau_training_resumes_to_the_same_bytes(tmp_path, monkeypatch):
    import threedcal.model.train as module

    ts = synthetic_set(n=12)
    settings = plateau_settings(max_steps=40, patience=3)
    train(ts, tmp_path / "full", 80, settings, progress=False)
    real = module._train_epoch
    calls = []

    def crash_on_fourth(*args, **kwargs):
        calls.append(1)
        if len(calls) == 4:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(module, "_train_epoch", crash_on_fourth)
    monkeypatch.setattr(module, "RESUME_EVERY_S", 0.0)
    with pytest.raises(KeyboardInterrupt):
        train(ts, tmp_path / "resumed", 80, settings, progress=False)
    assert (tmp_path / "resumed/checkpoint.pt").is_file()
    monkeypatch.setattr(module, "_train_epoch", real)
    train(ts, tmp_path / "resumed", 80, settings, progress=False)
    full, resumed = (read_checkpoint(tmp_path / d / "model.pt") for d in ("full", "resumed"))
    for name, value in full["state_dict"].items():
        assert torch.equal(value, resumed["state_dict"][name])
    assert full["training"]["steps"] == resumed["training"]["steps"]


def test_twice_the_budget_trains_at_least_twice_the_steps_and_snapshots_the_best(tmp_path):
    ts = synthetic_set(n=12)
    settings = plateau_settings(max_steps=30)
    once = train(ts, tmp_path / "once", 80, settings, progress=False)
    twice = train(
        ts,
        tmp_path / "twice",
        80,
        settings,
        progress=False,
        budget_scale=2.0,
        min_steps=2 * once["training"]["steps"],
        snapshot_every=1,
    )
    assert twice["training"]["steps"] >= 2 * once["training"]["steps"]
    snapshots = sorted((tmp_path / "twice/snapshots").glob("step*.pt"))
    assert len(snapshots) >= 2
    last = read_checkpoint(snapshots[-1])
    assert last["training"]["steps"] == twice["training"]["steps"]
    for name, value in twice["state_dict"].items():
        assert torch.equal(value, last["state_dict"][name])
