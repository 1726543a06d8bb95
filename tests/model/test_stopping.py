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
from threedcal.model.stopping import Doubling, holdout_split
from threedcal.model.train import train
from threedcal.model.train_settings import TrainSettings

RULE = {"rule": "doubling", "holdout": 0.2, "first_cycle": 10, "min_gain": 0.05, "max_steps": 1000}


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
    # several frames a coordinate: a coordinate is held out whole
    points = np.repeat(np.arange(10), 2)
    fit, hold = holdout_split(frames, 0.2, seed=3, points=points)
    assert len(hold) == 4 and set(points[hold - 100]).isdisjoint(points[fit - 100])


def test_doubling_cycles_double_the_training_and_stop_when_a_cycle_no_longer_pays():
    rule = Doubling.of(RULE, lr=1e-2)
    rule.best = 2.0  # the starting weights' error
    lengths = []
    for error in (1.0, 0.9, 0.8):  # each cycle gains more than 5 %
        lengths.append(rule.next_cycle())
        assert rule.observe(rule.steps + lengths[-1], error)
        assert not rule.done
    assert lengths == [10, 10, 20] and rule.steps == 40  # 10, 20, 40 steps in all
    assert rule.lr_at(0, 20) == pytest.approx(1e-2) and rule.lr_at(20, 20) == pytest.approx(1e-4)
    assert rule.lr_at(10, 20) == pytest.approx((1e-2 + 1e-4) / 2)
    assert rule.next_cycle() == 40
    assert rule.observe(80, 0.78)  # better, by 2.5 %: twice the training no longer pays
    assert rule.done and "lowered the holdout error by less than 5%" in rule.reason
    assert rule.best == 0.78 and rule.best_step == 80
    assert Doubling.from_state(rule.state()) == rule


def test_doubling_keeps_an_earlier_cycle_when_a_later_one_is_worse_and_stops_at_the_cap():
    rule = Doubling.of(RULE, lr=1.0)
    rule.best = 2.0
    assert rule.observe(10, 1.0)
    assert not rule.observe(20, 1.2)  # overfitting: worse, so stop and keep step 10's
    assert rule.done and rule.best_step == 10
    capped = Doubling.of({**RULE, "max_steps": 25}, lr=1.0)
    capped.best = 2.0
    for error in (1.0, 0.5):
        capped.observe(capped.steps + capped.next_cycle(), error)
    assert capped.next_cycle() == 5  # cut at the cap
    capped.observe(25, 0.2)
    assert capped.done and "max_steps (25)" in capped.reason


def test_twice_the_budget_stretches_the_cap_and_cannot_stop_before_min_steps():
    rule = Doubling.of(RULE, lr=1.0, scale=2.0, min_steps=40)
    assert rule.max_steps == 2000
    rule.best = 1.0
    for steps in (10, 20, 40):  # never better: still no stop before 40 steps
        assert not rule.done
        rule.observe(steps, 1.0)
    assert rule.done
    with pytest.raises(ConfigError, match="holdout error after 7 steps is nan"):
        rule.observe(7, float("nan"))


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
    # on a GPU, bfloat16 or not, float32 trains every network faster (bench_model --device cuda)
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: True)
    assert resolve_precision("auto", torch.device("cuda"), "context_half") == "float32"
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


def doubling_settings(**changes):
    return TrainSettings.of(
        preset="compact_tiny",
        seed=5,
        lr=1e-2,
        stopping={**RULE, "first_cycle": 3, "max_steps": 48, **changes},
        **{**TINY, "batch_size": 2},
    )


def test_doubling_training_never_fits_its_holdout_and_says_why_it_stopped(tmp_path, monkeypatch):
    import threedcal.model.train as module

    ts = synthetic_set(n=12)
    ts.samples["split"] = ["train"] * 10 + ["val"] * 2
    ts.samples["min_p"] = [80] * 10 + [0, 0]
    ts = replace(ts)  # re-derive the arrays
    fitted = []
    real = module.sample_windows
    monkeypatch.setattr(
        module, "sample_windows", lambda t, idx, *a: fitted.append(set(idx)) or real(t, idx, *a)
    )
    checkpoint = train(ts, tmp_path, 80, doubling_settings(), progress=False)
    training = checkpoint["training"]
    assert training["holdout_frames"] == 2 and training["fit_frames"] == 8
    train_idx = ts.indices("train", percent=80)
    _, hold = holdout_split(train_idx, 0.2, 5, ts.point[train_idx])
    trained = [idx for idx in fitted if idx != set(hold)]  # the holdout's own check windows aside
    assert trained and all(not (idx & set(hold)) for idx in trained)
    assert all(not (idx & {10, 11}) for idx in fitted)  # nor the stats stage's validation frames
    assert "less than 5%" in training["stopped"] or "max_steps" in training["stopped"]
    losses = pd.read_csv(tmp_path / "losses.csv")
    assert losses["step"].iloc[0] == 0 and losses["step"].is_monotonic_increasing
    assert training["steps"] == losses["step"].iloc[-1]


def test_doubling_keeps_the_best_weights_it_checked(tmp_path, monkeypatch):
    import threedcal.model.train as module

    errors = iter([1.0, 0.6, 0.5, 0.7])  # the start, then three cycles: the second is best
    states = []
    real_check = module._check_loss

    def scripted(model, job):
        real_check(model, job)
        states.append({k: v.detach().cpu().clone() for k, v in model.state_dict().items()})
        return next(errors)

    monkeypatch.setattr(module, "_check_loss", scripted)
    checkpoint = train(synthetic_set(n=12), tmp_path, 80, doubling_settings(), progress=False)
    best = states[2]  # the 0.5
    for name, value in checkpoint["state_dict"].items():
        assert torch.equal(value, best[name])


def test_an_interrupted_doubling_training_resumes_to_the_same_bytes(tmp_path, monkeypatch):
    import threedcal.model.train as module

    ts = synthetic_set(n=12)
    settings = doubling_settings(min_gain=0.0)  # cycles of 3, 3, 6, 12, 24 steps
    train(ts, tmp_path / "full", 80, settings, progress=False)
    real = module.optimizer_step
    calls = []

    def crash_on_step_20(*args, **kwargs):
        calls.append(1)
        if len(calls) == 20:  # in the fourth cycle, after three resume checkpoints
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(module, "optimizer_step", crash_on_step_20)
    monkeypatch.setattr(module, "RESUME_EVERY_S", 0.0)
    with pytest.raises(KeyboardInterrupt):
        train(ts, tmp_path / "resumed", 80, settings, progress=False)
    assert read_checkpoint(tmp_path / "resumed/checkpoint.pt")["steps"] == 12
    monkeypatch.setattr(module, "optimizer_step", real)
    train(ts, tmp_path / "resumed", 80, settings, progress=False)
    full, resumed = (read_checkpoint(tmp_path / d / "model.pt") for d in ("full", "resumed"))
    for name, value in full["state_dict"].items():
        assert torch.equal(value, resumed["state_dict"][name])
    assert full["training"]["steps"] == resumed["training"]["steps"]


def test_twice_the_budget_trains_at_least_twice_the_steps_and_snapshots_the_best(tmp_path):
    ts = synthetic_set(n=12)
    settings = doubling_settings(max_steps=12)
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
