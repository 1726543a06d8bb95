"""The quick and scratch arms on the simulated bench: a tiny quick calibration, then a model from
fresh weights per round on that round's presses with that round's cumulative steps."""

import pandas as pd
import pytest
import torch
from test_quick_bench import scene

from threedcal.model.checkpoint import read_checkpoint
from threedcal.study.quick_arms import run_arm, scratch_arm
from threedcal.study.quick_loop import QuickLoop, quick_stage
from threedcal.study.session import prepare


@pytest.mark.long
@pytest.mark.slow
def test_scratch_models_train_on_each_rounds_presses_with_its_budget(tmp_path):
    settings = scene(margin=0.99)  # two rounds of six presses, 10 steps a round
    outputs = {k: tmp_path / "quick" / k for k in ("model", "rounds", "stop", "work")}
    store = tmp_path / "raw.zarr"
    quick_stage(
        "q",
        settings,
        store=store,
        staging=tmp_path / ".partial/raw.zarr",
        progress=False,
        **outputs,
    )
    rounds = pd.read_csv(outputs["rounds"])
    prepared = prepare(settings)
    loop = QuickLoop(
        settings, prepared.plan, store, tmp_path / "w", prepared.sensor, prepared.printer
    )
    start_min = loop.printer_s(loop.first_row) / 60
    quick = run_arm(rounds, outputs["work"], start_min)
    assert [(m.round, m.presses, m.steps) for m in quick] == [(0, 0, 0), (1, 6, 10), (2, 12, 20)]
    assert quick[0].printer_min == pytest.approx(start_min) and start_min > 0
    assert [m.printer_min * 60 for m in quick[1:]] == pytest.approx(rounds["printer_s"].tolist())

    scratch = scratch_arm(loop, quick, tmp_path / "scratch")
    assert [(m.arm, m.round, m.presses, m.steps) for m in scratch] == [
        ("scratch", 1, 6, 10),
        ("scratch", 2, 12, 20),
    ]
    for model in scratch:
        training = read_checkpoint(model.paths[0])["training"]
        quick_round = read_checkpoint(quick[model.round].paths[0])["training"]
        # the same presses (every labelled frame of the round's rows), the cumulative budget,
        # fresh weights (no `init` recorded)
        assert training["fit_frames"] == quick_round["fit_frames"] > 0
        assert training["steps"] == model.steps == training["settings"]["stopping"]["max_steps"]
        assert "init" not in training["settings"]
        assert training["settings"]["seed"] == settings["seed"]
    # this scene starts from fresh weights too: round 1's two arms are one training, bit for bit
    # (the same presses, seed and budget); round 2's quick model went on from round 1's
    states = [read_checkpoint(m.paths[0])["state_dict"] for m in (scratch[0], quick[1])]
    assert all(torch.equal(states[0][k], states[1][k]) for k in states[0])
    assert "init" in read_checkpoint(quick[2].paths[0])["training"]["settings"]
    states = [read_checkpoint(m.paths[0])["state_dict"] for m in (scratch[1], quick[2])]
    assert any(not torch.equal(states[0][k], states[1][k]) for k in states[0])
