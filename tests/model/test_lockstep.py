"""The ablation's lockstep training (threedcal.model.lockstep): equal steps for every model, the
stacked (vmap) step against each model trained alone, snapshots, twice the budget, resuming."""

import shutil

import numpy as np
import pandas as pd
import pytest
import torch
from test_model import synthetic_set

import threedcal.model.lockstep as lockstep
from threedcal.errors import ConfigError, TrainingError
from threedcal.model.checkpoint import read_checkpoint
from threedcal.model.lockstep import Member, WindowStream, train_lockstep
from threedcal.model.stopping import cycle_ends
from threedcal.model.train import _epoch_windows, _Job
from threedcal.model.train_settings import TrainSettings

TINY = dict(patch_px=24, contact_patches=2, background_patches=1, torch_threads=1, batch_size=3)


def two_replicate_set(n=12):
    ts = synthetic_set(n=n)
    train = n - 2
    ts.samples["min_p_r1"] = [80] * (train - 3) + [20] * 3 + [0, 0]
    return type(ts)(ts.frames, ts.blank, ts.samples, px_per_mm=8.0, sphere_radius_mm=2.0)


def settings(preset="compact_tiny", **changes):
    return TrainSettings.of(preset=preset, **{"seed": 5, "lr": 3e-3, **TINY, **changes})


MEMBERS = [(80, 0), (20, 0), (80, 1), (20, 1)]


def members(folder, keys=MEMBERS):
    return [Member(p, r, folder / f"P{p}" / f"r{r}") for p, r in keys]


def test_cycles_end_at_a_quarter_a_half_and_the_whole_budget_then_twice_it():
    assert cycle_ends(8) == [2, 4, 8]
    assert cycle_ends(4000, twice=True) == [1000, 2000, 4000, 8000]
    with pytest.raises(ConfigError, match=r"ablation.steps: 3 \(at least 4\)"):
        cycle_ends(3)


def test_the_stream_is_the_single_trainers_epochs_run_on_and_seekable_by_step():
    ts = two_replicate_set()
    s = settings()
    fit = ts.indices("train", percent=80)
    job = _Job(ts, fit, fit, [], s, torch.device("cpu"), "float32", "x")
    expected = _epoch_windows(job, 1) + _epoch_windows(job, 2) + _epoch_windows(job, 3)
    stream = WindowStream(ts, fit, s)
    stream.seek(0)
    taken = stream.take(len(expected))
    assert taken == expected
    for step in (0, 5, 13, 29):  # batches of 3 that straddle the epochs' ends (24 windows each)
        stream.seek(step)
        assert stream.take(3) == expected[3 * step : 3 * step + 3]


@pytest.mark.parametrize("preset", ["compact_tiny", "context_half"])
def test_a_model_trained_in_the_stack_equals_it_trained_alone(tmp_path, preset):
    s = settings(preset)
    ts = two_replicate_set()
    stacked = train_lockstep(ts, members(tmp_path / "vmap"), s, 8, batching="vmap", progress=False)
    for (p, r), together in zip(MEMBERS, stacked, strict=True):
        alone = train_lockstep(
            ts, members(tmp_path / "alone", [(p, r)]), s, 8, batching="loop", progress=False
        )[0]
        assert together["training"]["steps"] == alone["training"]["steps"] == 8
        for name, value in alone["state_dict"].items():
            torch.testing.assert_close(
                together["state_dict"][name], value, rtol=2e-4, atol=2e-6, msg=f"P{p} r{r} {name}"
            )


def test_the_loop_trains_each_model_exactly_as_alone(tmp_path):
    s, ts = settings(), two_replicate_set()
    together = train_lockstep(ts, members(tmp_path / "all"), s, 4, batching="loop", progress=False)
    alone = train_lockstep(
        ts, members(tmp_path / "one", [MEMBERS[2]]), s, 4, batching="loop", progress=False
    )[0]
    for name, value in alone["state_dict"].items():
        assert torch.equal(together[2]["state_dict"][name], value)
    # and the replicates differ: their own subsets and seeds
    last = list(alone["state_dict"])[-1]
    assert not torch.equal(together[0]["state_dict"][last], together[2]["state_dict"][last])


def test_every_model_takes_the_same_steps_with_snapshots_and_a_twice_reading(tmp_path):
    s, ts = settings(), two_replicate_set()
    finals = train_lockstep(ts, members(tmp_path), s, 8, twice=True, progress=False)
    for (p, r), final in zip(MEMBERS, finals, strict=True):
        folder = tmp_path / f"P{p}" / f"r{r}"
        assert final["training"]["steps"] == 8 and final["training"]["percent"] == p
        snapshots = sorted(f.name for f in (folder / "snapshots").iterdir())
        assert snapshots == ["step0000002.pt", "step0000004.pt"]
        twice = read_checkpoint(folder / "twice" / "model.pt")
        assert twice["training"]["steps"] == 16
        losses = pd.read_csv(folder / "losses.csv")
        assert losses["step"].tolist() == [0, 2, 4, 8]
        assert pd.read_csv(folder / "twice" / "losses.csv")["step"].tolist() == [0, 2, 4, 8, 16]
        assert (folder / "losses.png").is_file() and (folder / "twice" / "losses.png").is_file()
        assert np.isfinite(losses["train_loss"][1:]).all()
        for name, value in final["state_dict"].items():  # the twice reading trained on
            if value.dtype.is_floating_point:
                assert not torch.equal(value, twice["state_dict"][name])


def test_an_interrupted_lockstep_resumes_to_the_same_bytes(tmp_path, monkeypatch):
    s, ts = settings(), two_replicate_set()
    keys = MEMBERS[:2]
    train_lockstep(ts, members(tmp_path / "full", keys), s, 8, twice=True, progress=False)
    real = lockstep.optimizer_step
    calls = []

    def crash(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2 * 11 + 1:  # step 12 of 16, the first model's
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(lockstep, "optimizer_step", crash)
    monkeypatch.setattr(lockstep, "RESUME_EVERY_S", 0.0)
    resume = tmp_path / "resumed" / "resume.pt"
    with pytest.raises(KeyboardInterrupt):
        train_lockstep(
            ts, members(tmp_path / "resumed", keys), s, 8, twice=True, resume=resume, progress=False
        )
    assert torch.load(resume, weights_only=True)["step"] == 11
    # Snakemake removes an incomplete job's outputs before running it again
    for p, r in keys:
        shutil.rmtree(tmp_path / f"resumed/P{p}/r{r}")
    monkeypatch.setattr(lockstep, "optimizer_step", real)
    train_lockstep(
        ts, members(tmp_path / "resumed", keys), s, 8, twice=True, resume=resume, progress=False
    )
    assert not resume.exists()
    for p, r in keys:
        for leaf in (
            "model.pt",
            "snapshots/step0000002.pt",
            "snapshots/step0000004.pt",
            "twice/model.pt",
        ):
            full, resumed = (
                read_checkpoint(tmp_path / d / f"P{p}/r{r}" / leaf) for d in ("full", "resumed")
            )
            for name, value in full["state_dict"].items():
                assert torch.equal(value, resumed["state_dict"][name]), (p, r, leaf, name)
        for leaf in ("losses.csv", "twice/losses.csv"):
            full_losses = pd.read_csv(tmp_path / f"full/P{p}/r{r}/{leaf}")
            resumed_losses = pd.read_csv(tmp_path / f"resumed/P{p}/r{r}/{leaf}")
            pd.testing.assert_series_equal(full_losses["train_loss"], resumed_losses["train_loss"])


@pytest.mark.parametrize("batching", ["loop", "vmap"])
def test_a_diverging_model_is_named(tmp_path, batching):
    s, ts = settings(lr=1e30), two_replicate_set()
    with pytest.raises(
        TrainingError, match=r"training P=\d+ r\d \(compact_tiny\), step \d+: the loss"
    ):
        train_lockstep(ts, members(tmp_path), s, 8, batching=batching, progress=False)


def test_bad_members_and_batching_are_refused(tmp_path):
    s, ts = settings(), two_replicate_set()
    with pytest.raises(ConfigError, match="listed twice"):
        train_lockstep(ts, members(tmp_path, [(80, 0), (80, 0)]), s, 8, progress=False)
    with pytest.raises(
        ConfigError, match=r"ablation.batching: 'gpu' \(allowed: auto, loop, vmap\)"
    ):
        train_lockstep(ts, members(tmp_path), s, 8, batching="gpu", progress=False)
    with pytest.raises(ConfigError, match="replicates 0..1, not 2"):
        train_lockstep(ts, members(tmp_path, [(80, 2)]), s, 8, progress=False)
    assert not any(tmp_path.iterdir())  # refused before anything was written
