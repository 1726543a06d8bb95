"""Model presets, training, checkpoints and the inference API (threedcal.model)."""

import os
import pickle
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
import torch

from threedcal.dataset.labels import sphere_gradients
from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import ConfigError, TrainingError
from threedcal.model import PRESET_NAMES
from threedcal.model.checkpoint import (
    OUR_NORMALISATION,
    CheckpointError,
    adapt_inputs,
    read_checkpoint,
)
from threedcal.model.inference import DepthEstimator
from threedcal.model.lookup import LookupTable
from threedcal.model.machine import BFLOAT16_SAFE
from threedcal.model.presets import TouchNet, build_model, reach_px
from threedcal.model.train import train
from threedcal.model.train_settings import TrainSettings

SHAPE = (40, 48)


def synthetic_set(n=6, seed=0) -> TrainingSet:
    """Frames whose colour change is a fixed function of the sphere's gradients (learnable exactly)."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform([14, 12], [34, 28], (n, 2))
    depths = rng.uniform(0.4, 0.9, n)
    frames = []
    blank = np.full((*SHAPE, 3), 100.0, np.float32)
    for (cx, cy), d in zip(centres, depths, strict=True):
        g = sphere_gradients(SHAPE, (cx, cy), 2.0, d, 8.0)
        frame = blank + np.stack(
            [40 * g[..., 0], 40 * g[..., 1], 20 * np.hypot(*g.transpose(2, 0, 1))], -1
        )
        frames.append(np.clip(np.rint(frame), 0, 255).astype(np.uint8))
    samples = pd.DataFrame(
        {
            "frame": np.arange(n),
            "point": np.arange(n),
            "center_x_px": centres[:, 0],
            "center_y_px": centres[:, 1],
            "depth_mm": depths,
            "eval_radius_px": np.full(n, 6.0),
            "split": ["train"] * (n - 2) + ["val"] * 2,
            "min_p": [20] * 2 + [80] * (n - 4) + [0, 0],
        }
    )
    return TrainingSet(np.stack(frames), blank, samples, px_per_mm=8.0, sphere_radius_mm=2.0)


def fresh_checkpoint(preset: str, ts: TrainingSet, seed: int) -> dict:
    """An untrained model of `preset` as a checkpoint for `ts`'s frames (inference tests)."""
    torch.manual_seed(seed)
    return {
        "preset": preset,
        "preset_args": {},
        "state_dict": build_model(preset).state_dict(),
        "normalisation": dict(OUR_NORMALISATION),
        "blank": ts.blank,
        "px_per_mm": 8.0,
        "image_shape": list(SHAPE),
    }


TINY = dict(epochs_base=1, patch_px=24, contact_patches=2, background_patches=1, torch_threads=1)


@pytest.mark.parametrize("preset", PRESET_NAMES)
def test_every_preset_maps_5_channels_to_2_at_the_input_size(preset):
    torch.manual_seed(0)
    model = build_model(preset).eval()
    with torch.no_grad():
        out = model(torch.zeros(2, 5, 17, 23))
    assert out.shape == (2, 2, 17, 23)
    assert torch.isfinite(out).all()


def test_unknown_preset_is_a_config_error():
    with pytest.raises(ConfigError, match="allowed: touchnet"):
        build_model("big")


def test_touchnet_has_the_papers_layers_and_the_authors_parameter_names():
    state = TouchNet().state_dict()
    chans = [5, 32, 64, 128, 256, 256, 128, 64, 32, 2]
    kernels = [7, 7, 7, 5, 5, 5, 3, 3, 1]
    for i in range(1, 10):
        assert state[f"conv{i}.weight"].shape == (
            chans[i],
            chans[i - 1],
            kernels[i - 1],
            kernels[i - 1],
        )
        assert state[f"conv{i}.bias"].shape == (chans[i],)
    for i in range(1, 9):
        for leaf in ("weight", "bias", "running_mean", "running_var", "num_batches_tracked"):
            assert f"bn{i}.{leaf}" in state
    assert len(state) == 9 * 2 + 8 * 5
    drops = [m.p for m in TouchNet().modules() if isinstance(m, torch.nn.Dropout2d)]
    assert drops == [0.2, 0.2, 0.2, 0.3, 0.3, 0.2, 0.2, 0.2]


def test_depth_estimator_rectifies_camera_frames_through_the_checkpoints_lens(tmp_path):
    from threedcal.dataset.trainset import pool_to
    from threedcal.lens import RadialLens

    torch.manual_seed(1)
    path = tmp_path / "weights.pth"
    torch.save(TouchNet().eval().state_dict(), path)
    checkpoint = read_checkpoint(path)
    blank = np.full((12, 10, 3), 90, np.uint8)
    plain = DepthEstimator(checkpoint, device="cpu", blank=blank, px_per_mm=10.0)
    frame = np.random.default_rng(0).integers(0, 255, (12, 10, 3), dtype=np.uint8)
    assert plain.rectify(frame) is frame  # no lens, the model's size: unchanged
    # a camera streaming 24 x 20 frames through a barrel lens, the model trained on them pooled 2x
    lens = RadialLens(centre_px=(9.7, 11.2), kappa1=-2e-4, shape=(24, 20))
    checkpoint["camera"] = {"lens": lens.record(), "downscale": 2}
    est = DepthEstimator(checkpoint, device="cpu", blank=blank, px_per_mm=10.0)
    camera = np.random.default_rng(1).integers(0, 255, (2, 24, 20, 3), dtype=np.uint8)
    expected = np.stack([pool_to(lens.rectify(f), (12, 10)) for f in camera])
    np.testing.assert_array_equal(est.rectify(camera), expected)
    np.testing.assert_array_equal(est.rectify(camera[0]), expected[0])
    assert not np.array_equal(expected[0], pool_to(camera[0], (12, 10)))  # the lens did something
    with pytest.raises(ConfigError, match=r"lens was fitted on \(24, 20\)"):
        est.rectify(frame)
    # a blank from the camera (threedcal predict --blank) is rectified and pooled like the frames
    camera_blank = np.random.default_rng(2).integers(80, 100, (24, 20, 3)).astype(np.uint8)
    from_camera = DepthEstimator(
        checkpoint, device="cpu", blank=camera_blank, px_per_mm=10.0, camera_blank=True
    )
    expected_blank = pool_to(lens.rectify(camera_blank.astype(np.float32)), (12, 10))
    np.testing.assert_allclose(
        from_camera._blank.permute(1, 2, 0).numpy(), expected_blank, rtol=0, atol=1e-4
    )


def test_authors_bare_state_dict_loads_with_their_normalisation(tmp_path):
    torch.manual_seed(1)
    authors = TouchNet().eval()
    path = tmp_path / "gsmini_pretrained_weights.pth"
    torch.save(authors.state_dict(), path)  # what the authors publish: a bare state_dict
    checkpoint = read_checkpoint(path)
    assert checkpoint["preset"] == "touchnet"
    assert checkpoint["normalisation"] == {
        "coords": "pixel_index",
        "gradient_sign": -1.0,
        "drift": "none",
    }
    blank = np.full((12, 10, 3), 90, np.uint8)
    frame = np.random.default_rng(0).integers(0, 255, (12, 10, 3), dtype=np.uint8)
    est = DepthEstimator(checkpoint, device="cpu", blank=blank, px_per_mm=10.0)
    # Reference: the authors' own input recipe, (frame − blank)/255 then 1-based pixel indices.
    diff = torch.from_numpy((frame.astype(np.float32) - blank) / 255).permute(2, 0, 1)
    xs = torch.arange(1, 11, dtype=torch.float32).repeat(12, 1)
    ys = torch.arange(1, 13, dtype=torch.float32)[:, None].repeat(1, 10)
    with torch.no_grad():
        theirs = authors(torch.cat([diff, xs[None], ys[None]])[None])[0].permute(1, 2, 0).numpy()
    np.testing.assert_allclose(est.gradients(frame), -theirs, atol=1e-5)


def test_adapt_inputs_maps_unit_coordinates_to_one_based_pixel_indices():
    x = torch.zeros(1, 5, 3, 4)
    x[:, 3] = torch.tensor([-1.0, -1 / 3, 1 / 3, 1.0])
    x[:, 4] = torch.tensor([-1.0, 0.0, 1.0])[:, None]
    out = adapt_inputs(x, {"coords": "pixel_index"}, (3, 4))
    assert out[0, 3, 0].tolist() == pytest.approx([1, 2, 3, 4])
    assert out[0, 4, :, 0].tolist() == pytest.approx([1, 2, 3])
    assert adapt_inputs(x, {"coords": "unit"}, (3, 4)) is x


class _Exploit:
    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")
def test_a_malicious_pickle_is_refused_and_never_runs(tmp_path):
    marker = tmp_path / "pwned"
    exploit = _Exploit()
    exploit.marker = marker
    path = tmp_path / "evil.pt"
    with open(path, "wb") as handle:
        pickle.dump({"format": "threedcal-model", "payload": exploit}, handle)
    with pytest.raises(CheckpointError, match="refused"):
        read_checkpoint(path)
    torch.save({"format": "threedcal-model", "payload": exploit}, tmp_path / "evil2.pt")
    with pytest.raises(CheckpointError, match="refused"):
        DepthEstimator.from_checkpoint(tmp_path / "evil2.pt")
    assert not marker.exists()


def test_not_a_model_is_a_clear_error(tmp_path):
    torch.save({"weights": torch.zeros(2)}, tmp_path / "x.pt")
    with pytest.raises(CheckpointError, match="neither a threedcal checkpoint"):
        read_checkpoint(tmp_path / "x.pt")
    with pytest.raises(ConfigError, match="missing"):
        read_checkpoint(tmp_path / "nope.pt")


def test_epochs_scale_as_base_times_80_over_p():
    s = TrainSettings.of(epochs_base=3)
    assert [s.epochs(p) for p in (80, 40, 20, 1)] == [3, 6, 12, 240]
    with pytest.raises(ConfigError):
        s.epochs(0)


def test_training_is_deterministic_to_the_byte_and_writes_losses(tmp_path):
    ts = synthetic_set()
    settings = TrainSettings.of(preset="compact_tiny", seed=3, **TINY)
    train(ts, tmp_path / "a", 80, settings, progress=False)
    train(ts, tmp_path / "b", 80, settings, progress=False)
    assert (tmp_path / "a/model.pt").read_bytes() == (tmp_path / "b/model.pt").read_bytes()
    losses = pd.read_csv(tmp_path / "a/losses.csv")
    assert list(losses.columns) == ["epoch", "step", "train_loss", "val_loss", "seconds", "lr"]
    assert len(losses) == 1 and np.isfinite(losses[["train_loss", "val_loss"]]).all().all()
    assert (tmp_path / "a/losses.png").stat().st_size > 1000
    assert not (tmp_path / "a/checkpoint.pt").exists()
    other = TrainSettings.of(preset="compact_tiny", seed=4, **TINY)
    train(ts, tmp_path / "c", 80, other, progress=False)
    assert (tmp_path / "c/model.pt").read_bytes() != (tmp_path / "a/model.pt").read_bytes()


def test_bfloat16_training_runs_the_network_in_bfloat16_and_keeps_float32_weights(tmp_path):
    ts = synthetic_set()
    settings = TrainSettings.of(preset="compact_tiny", seed=3, precision="bfloat16", **TINY)
    seen = []
    real_build = build_model

    def spying_build(preset, **overrides):
        model = real_build(preset, **overrides)
        model.body[0].register_forward_hook(lambda m, i, out: seen.append((m.training, out.dtype)))
        return model

    import threedcal.model.train as module

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(module, "build_model", spying_build)
        half = train(ts, tmp_path / "bf16", 80, settings, progress=False)
        train(ts, tmp_path / "again", 80, settings, progress=False)
    assert {dtype for training, dtype in seen if training} == {torch.bfloat16}
    assert {dtype for training, dtype in seen if not training} == {torch.float32}  # validation
    assert all(v.dtype == torch.float32 for v in half["state_dict"].values())
    assert (tmp_path / "bf16/model.pt").read_bytes() == (tmp_path / "again/model.pt").read_bytes()
    full = train(ts, tmp_path / "fp32", 80, replace(settings, precision="float32"), progress=False)
    assert not torch.equal(half["state_dict"]["body.0.weight"], full["state_dict"]["body.0.weight"])


@pytest.mark.parametrize(
    "preset, batch, patch", [(p, 16, 32) for p in BFLOAT16_SAFE] + [("context", 32, 64)]
)
def test_bfloat16_gradients_follow_float32_for_every_network_auto_trains_in_it(
    preset, batch, patch
):
    # `precision: auto` trains these in bfloat16 on a CPU that has it. oneDNN's channels-last
    # bfloat16 weight gradients of dilated convolutions are NaN at some channel counts (24:
    # multiscale, which auto keeps in float32); these must stay finite and within bfloat16's
    # rounding of the float32 gradients, at the step shapes they train with.
    from threedcal.model.train_step import training_autocast

    torch.manual_seed(0)
    model = build_model(preset).to(memory_format=torch.channels_last)
    x = torch.randn(batch, 5, patch, patch).contiguous(memory_format=torch.channels_last)
    y = torch.randn(batch, 2, patch, patch)
    grads = {}
    for precision in ("float32", "bfloat16"):
        model.zero_grad()
        with training_autocast(precision, torch.device("cpu")):
            prediction = model(x)
        ((prediction.float() - y) ** 2).mean().backward()
        grads[precision] = {n: p.grad.clone() for n, p in model.named_parameters()}
    for name, exact in grads["float32"].items():
        half = grads["bfloat16"][name]
        assert torch.isfinite(half).all(), name
        assert float((half - exact).norm() / exact.norm()) < 0.05, name


@pytest.mark.parametrize("precision", ["float32", "bfloat16"])
def test_a_non_finite_loss_stops_training_with_the_job_and_what_to_change(
    tmp_path, monkeypatch, precision
):
    import threedcal.model.train_step as module

    ts = synthetic_set()
    settings = TrainSettings.of(
        preset="compact_tiny", seed=3, precision=precision, batch_size=2, **TINY
    )
    real_loss, calls = module.gradient_loss, []

    def loss_turning_nan(prediction, labels, kind):
        calls.append(1)
        value = real_loss(prediction, labels, kind)
        return value * float("nan") if len(calls) == 2 else value

    monkeypatch.setattr(module, "gradient_loss", loss_turning_nan)
    with pytest.raises(
        TrainingError, match=r"P=80 r0 \(compact_tiny\), epoch 1: the loss of batch 2 is nan"
    ) as info:
        train(ts, tmp_path / "m", 80, settings, progress=False)
    assert ("model.precision: float32" in str(info.value)) == (precision == "bfloat16")
    assert not (tmp_path / "m/model.pt").exists()


def test_a_resume_checkpoint_is_written_only_when_its_interval_has_passed(tmp_path, monkeypatch):
    import threedcal.model.train as module

    ts = synthetic_set()
    settings = TrainSettings.of(preset="compact_tiny", seed=5, **{**TINY, "epochs_base": 3})
    saved = []
    real_save = module.save_checkpoint
    monkeypatch.setattr(module, "save_checkpoint", lambda p, c: saved.append(p) or real_save(p, c))
    monkeypatch.setattr(module, "RESUME_EVERY_S", 3600.0)
    train(ts, tmp_path / "slow", 80, settings, progress=False)
    assert [p.name for p in saved] == ["model.pt"]  # three epochs, no resume checkpoint
    saved.clear()
    monkeypatch.setattr(module, "RESUME_EVERY_S", 0.0)
    train(ts, tmp_path / "every", 80, settings, progress=False)
    assert [p.name for p in saved] == ["checkpoint.pt", "checkpoint.pt", "model.pt"]
    assert (tmp_path / "slow/model.pt").read_bytes() == (tmp_path / "every/model.pt").read_bytes()


def test_a_replicate_trains_on_its_own_subset_with_its_own_seed(tmp_path, monkeypatch):
    import threedcal.model.train as module
    from threedcal.seeds import replicate_seed

    ts = synthetic_set()
    ts.samples["min_p_r1"] = [80, 80, 20, 20, 0, 0]  # replicate 1's P = 20 subset: points 2, 3
    ts = TrainingSet(ts.frames, ts.blank, ts.samples, px_per_mm=8.0, sphere_radius_mm=2.0)
    used = []
    real = module.train_epoch
    monkeypatch.setattr(
        module, "train_epoch", lambda m, t, idx, *a: used.append(list(idx)) or real(m, t, idx, *a)
    )
    settings = TrainSettings.of(preset="compact_tiny", seed=3, **TINY)
    zero = train(ts, tmp_path / "r0", 20, settings, progress=False)
    one = train(ts, tmp_path / "r1", 20, settings, progress=False, replicate=1)
    assert used[0] == [0, 1] and used[-1] == [2, 3]
    assert zero["training"]["replicate"] == 0 and zero["training"]["settings"]["seed"] == 3
    assert one["training"]["replicate"] == 1
    assert one["training"]["settings"]["seed"] == replicate_seed(3, 1)
    with pytest.raises(ConfigError, match="replicates 0..1, not 2"):
        train(ts, tmp_path / "r2", 20, settings, progress=False, replicate=2)


@pytest.mark.parametrize("schedule", ["constant", "cosine"])
def test_an_interrupted_training_resumes_to_the_same_bytes(tmp_path, monkeypatch, schedule):
    import threedcal.model.train as module

    ts = synthetic_set()
    settings = TrainSettings.of(
        preset="compact_tiny", seed=5, lr_schedule=schedule, **{**TINY, "epochs_base": 3}
    )
    train(ts, tmp_path / "full", 80, settings, progress=False)
    real = module.train_epoch
    calls = []

    def crash_on_third(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(module, "train_epoch", crash_on_third)
    monkeypatch.setattr(module, "RESUME_EVERY_S", 0.0)  # a checkpoint after every epoch
    with pytest.raises(KeyboardInterrupt):
        train(ts, tmp_path / "resumed", 80, settings, progress=False)
    assert read_checkpoint(tmp_path / "resumed/checkpoint.pt")["epoch"] == 2
    monkeypatch.setattr(module, "train_epoch", real)
    train(ts, tmp_path / "resumed", 80, settings, progress=False)
    full, resumed = (tmp_path / d / "model.pt" for d in ("full", "resumed"))
    assert full.read_bytes() == resumed.read_bytes()
    assert len(pd.read_csv(tmp_path / "resumed/losses.csv")) == 3


def test_checkpoint_round_trip_carries_what_inference_needs(tmp_path):
    ts = synthetic_set()
    checkpoint = train(
        ts, tmp_path, 20, TrainSettings.of(preset="compact_tiny", **TINY), progress=False
    )
    assert checkpoint["training"]["percent"] == 20 and checkpoint["training"]["epochs"] == 4
    est = DepthEstimator.from_checkpoint(tmp_path / "model.pt", device="cpu")
    assert est.image_shape == SHAPE and est.px_per_mm == 8.0 and est.preset == "compact_tiny"
    np.testing.assert_array_equal(
        np.asarray(read_checkpoint(tmp_path / "model.pt")["blank"]), ts.blank
    )
    model = build_model("compact_tiny")
    model.load_state_dict(checkpoint["state_dict"])
    with torch.no_grad():
        direct = model(torch.from_numpy(ts.inputs(0))[None])[0].permute(1, 2, 0).numpy()
    frames = np.asarray(ts.frames[:3])
    batch = est.gradients(frames)
    assert batch.shape == (3, *SHAPE, 2)
    np.testing.assert_allclose(batch[0], direct, atol=1e-5)
    np.testing.assert_allclose(est.gradients(frames[1]), batch[1], atol=1e-6)
    depth = est.depth(frames)
    assert depth.shape == (3, *SHAPE) and depth.dtype == np.float32
    with pytest.raises(ConfigError, match=r"\(H, W\) = \(40, 48\)"):
        est.gradients(np.zeros((10, 10, 3), np.uint8))


@pytest.mark.parametrize("preset", [p for p in PRESET_NAMES if p != "touchnet"])
def test_channels_last_inference_gives_the_contiguous_layouts_gradients(preset):
    ts = synthetic_set()
    checkpoint = fresh_checkpoint(preset, ts, seed=0)
    frames = np.asarray(ts.frames[:2])
    fast = DepthEstimator(checkpoint, device="cpu", channels_last=True)
    plain = DepthEstimator(checkpoint, device="cpu", channels_last=False)
    # the lookup table has no convolution to gain from NHWC
    expected = torch.contiguous_format if preset == "lookup" else torch.channels_last
    assert fast.memory_format == expected
    np.testing.assert_allclose(fast.gradients(frames), plain.gradients(frames), atol=1e-5)


@pytest.mark.parametrize("preset", ["compact_tiny", "context"])
def test_training_in_nhwc_follows_the_contiguous_layouts_losses(tmp_path, monkeypatch, preset):
    import threedcal.model.train as trainer
    import threedcal.model.train_step as train_step

    ts = synthetic_set()
    # the CPU's layouts (on a GPU, cuDNN picks other kernels per layout, in TF32)
    settings = TrainSettings.of(preset=preset, seed=2, loss="normal", device="cpu", **TINY)
    fast = train(ts, tmp_path / "nhwc", 20, settings, progress=False)
    assert fast["state_dict"][
        "stem.weight" if preset == "context" else "body.0.weight"
    ].is_contiguous(memory_format=torch.channels_last)
    for module in (trainer, train_step):
        monkeypatch.setattr(
            module, "preferred_memory_format", lambda model: torch.contiguous_format
        )
    plain = train(ts, tmp_path / "nchw", 20, settings, progress=False)
    losses = [pd.read_csv(tmp_path / name / "losses.csv") for name in ("nhwc", "nchw")]
    assert len(losses[0]) == settings.epochs(20) > 1
    np.testing.assert_allclose(losses[0]["train_loss"], losses[1]["train_loss"], rtol=1e-4)
    for key, value in plain["state_dict"].items():
        np.testing.assert_allclose(fast["state_dict"][key], value, rtol=1e-3, atol=1e-5)


def test_fine_tuning_starts_from_the_given_checkpoint(tmp_path):
    ts = synthetic_set()
    base = train(
        ts, tmp_path / "base", 80, TrainSettings.of(preset="compact_tiny", **TINY), progress=False
    )
    tuned_settings = TrainSettings.of(
        preset="compact_tiny", init=str(tmp_path / "base/model.pt"), lr=1e-12, **TINY
    )
    tuned = train(ts, tmp_path / "tuned", 80, tuned_settings, progress=False)
    for key, value in base["state_dict"].items():
        torch.testing.assert_close(tuned["state_dict"][key], value, atol=1e-8, rtol=0)
    with pytest.raises(ConfigError, match="holds a 'compact_tiny' model"):
        train(
            ts,
            tmp_path / "x",
            80,
            TrainSettings.of(preset="compact", init=str(tmp_path / "base/model.pt"), **TINY),
        )


def reached_offsets(preset: str, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Row and column offsets of the outputs that one bright input pixel at the centre changes."""
    torch.manual_seed(0)
    model = build_model(preset).eval()
    x = torch.zeros(1, 5, size, size)
    bumped = x.clone()
    bumped[0, :3, size // 2, size // 2] = 1.0
    with torch.no_grad():
        changed = (model(bumped) - model(x)).abs().amax(dim=(0, 1)) > 0
    rows, cols = torch.nonzero(changed, as_tuple=True)
    return (rows - size // 2).abs(), (cols - size // 2).abs()


@pytest.mark.parametrize(
    ("preset", "reach"), [("compact", 3), ("compact_tiny", 1), ("context", 33), ("touchnet", None)]
)
def test_a_preset_sees_exactly_its_receptive_field(preset, reach):
    # `context` exists to see where in the contact a pixel lies: ±33 px (7x7 stem, dilations 2..16).
    torch.manual_seed(0)
    computed = reach_px(build_model(preset))
    reach = computed if reach is None else reach
    rows, cols = reached_offsets(preset, 2 * reach + 11)
    assert int(rows.max()) == reach == computed
    assert int(cols.max()) == reach


def test_a_pooled_preset_has_no_window_reach_and_lookup_is_per_pixel():
    assert reach_px(build_model("multiscale")) is None
    assert reach_px(build_model("lookup")) == 0


@pytest.mark.parametrize("preset", [p for p in PRESET_NAMES if p != "touchnet"])
@pytest.mark.parametrize(
    "window",
    [
        (slice(12, 30), slice(9, 40)),  # inside
        (slice(0, 7), slice(41, 48)),  # a corner: the crop meets the frame's edge
        (slice(20, 21), slice(0, 48)),  # one row
        (slice(0, 40), slice(0, 48)),  # the whole frame
    ],
)
def test_a_window_is_scored_as_the_whole_frame_would_score_it(preset, window):
    ts = synthetic_set()
    est = DepthEstimator(fresh_checkpoint(preset, ts, seed=1), device="cpu")
    frame = np.asarray(ts.frames[3])
    # a lighting drift for the whole-frame median to remove
    frame = np.clip(frame.astype(int) + 9, 0, 255).astype(np.uint8)
    part = est.gradients_in(frame, window)
    assert part.shape == (window[0].stop - window[0].start, window[1].stop - window[1].start, 2)
    np.testing.assert_allclose(part, est.gradients(frame)[window], atol=1e-5)
    with pytest.raises(ConfigError, match="one frame"):
        est.gradients_in(np.stack([frame, frame]), window)


def test_compact_net_overfits_one_batch():
    ts = synthetic_set()
    windows = [(i, (slice(0, 40), slice(0, 48))) for i in range(4)]
    x = torch.from_numpy(np.stack([ts.inputs(i, w) for i, w in windows]))
    y = torch.from_numpy(np.stack([ts.labels(i, w) for i, w in windows]))
    torch.manual_seed(0)
    torch.set_num_threads(1)
    model = build_model("compact")
    optimizer = torch.optim.AdamW(model.parameters(), lr=1e-2, weight_decay=0)
    first = None
    for _ in range(150):
        optimizer.zero_grad()
        loss = torch.nn.functional.mse_loss(model(x), y)
        loss.backward()
        optimizer.step()
        first = first if first is not None else float(loss.detach())
    assert float(loss.detach()) < 0.1 * first


def test_lookup_recovers_a_colour_coded_gradient_and_fills_empty_bins():
    rng = np.random.default_rng(0)
    lut = LookupTable(rgb_bins=8, pos_bins=1)
    # Label = the red change, exactly: one colour per bin, so the table must return it.
    levels = (np.arange(8) + 0.5) / 8 * 2 - 1  # bin centres over [-1, 1]
    red = rng.choice(levels[::2], (1, 30, 30))  # only even bins are seen in training
    x = np.concatenate([red, np.zeros((2, 30, 30)), np.zeros((2, 30, 30))]).astype(np.float32)
    x[1:3, 0, 0] = [-1.0, 1.0]  # stretch the G/B ranges so the table spans them
    y = np.concatenate([red, -red]).astype(np.float32)
    lut.fit([(x, y)])
    with torch.no_grad():
        out = lut(torch.from_numpy(x)[None])[0].numpy()
    np.testing.assert_allclose(out[:, 1:, 1:], y[:, 1:, 1:], atol=1e-6)
    assert (lut.table[..., 0] != 0).any()  # no empty bin left at zero by default
    assert set(np.unique(lut.table[..., 0].numpy().round(6))) <= set(levels[::2].round(6))


def test_predict_cli_writes_depth_and_colour_map(tmp_path):
    import cv2

    from threedcal.cli import main

    ts = synthetic_set()
    train(ts, tmp_path, 80, TrainSettings.of(preset="compact_tiny", **TINY), progress=False)
    cv2.imwrite(
        str(tmp_path / "img.png"), cv2.cvtColor(np.asarray(ts.frames[0]), cv2.COLOR_RGB2BGR)
    )
    args = [
        "predict",
        "--checkpoint",
        str(tmp_path / "model.pt"),
        "--image",
        str(tmp_path / "img.png"),
    ]
    assert main([*args, "--out", str(tmp_path / "d.npy"), "--device", "cpu"]) == 0
    assert np.load(tmp_path / "d.npy").shape == SHAPE
    assert cv2.imread(str(tmp_path / "d.png")).shape == (*SHAPE, 3)
    ts.save(tmp_path / "set")
    live = ["live", "--checkpoint", str(tmp_path / "model.pt"), "--source", str(tmp_path / "set")]
    assert main([*live, "--out", str(tmp_path / "v.gif"), "--frames", "3", "--device", "cpu"]) == 0
    assert (tmp_path / "v.gif").stat().st_size > 0


def test_scheduled_lr_constant_and_a_cosine_over_the_steps():
    from threedcal.model.train_settings import scheduled_lr

    constant = TrainSettings.of(lr=0.01)
    assert {scheduled_lr(constant, e, 5, b, 3) for e in (1, 3, 5) for b in range(3)} == {0.01}
    cosine = TrainSettings.of(lr=0.01, lr_schedule="cosine")
    floor = 0.01 / 100
    assert scheduled_lr(cosine, 1, 4, 0, 10) == pytest.approx(0.01)
    assert scheduled_lr(cosine, 3, 4, 0, 10) == pytest.approx(floor + 0.99 * 0.01 / 2)  # halfway
    rates = [scheduled_lr(cosine, e, 4, b, 10) for e in range(1, 5) for b in range(10)]
    assert all(later < earlier for earlier, later in zip(rates, rates[1:], strict=False))
    assert rates[-1] < floor + 0.002 * 0.01  # the last step ends within a step of the floor
    # the rate falls within an epoch: a 4-epoch run (P = 80 %) does not spend its last epoch at
    # the floor, as a rate held per epoch did, but anneals through it as a 320-epoch run does
    last_epoch = rates[30:]
    assert last_epoch[0] > 10 * floor and np.mean(last_epoch) > 3 * floor
    assert scheduled_lr(cosine, 1, 1, 1, 2) == pytest.approx(floor + 0.99 * 0.01 / 2)
    with pytest.raises(ConfigError, match="allowed: constant, cosine"):
        scheduled_lr(TrainSettings.of(lr_schedule="step"), 1, 5, 0, 1)


def test_skirt_reach_moves_contact_patches_off_the_contact():
    from threedcal.model.patches import sample_windows

    ts = synthetic_set()
    centre = ts.center_px[0]

    def offsets(reach):
        settings = TrainSettings.of(
            patch_px=12, contact_patches=200, background_patches=0, skirt_reach=reach
        )
        windows = sample_windows(ts, np.array([0]), settings, np.random.default_rng(0))
        return np.array(
            [[(w[1].start + 6) - centre[0], (w[0].start + 6) - centre[1]] for _, w in windows]
        )

    assert np.abs(offsets(0.0)).max() <= 12 / 3 + 1
    far = np.abs(offsets(2.0))
    assert far.max() > 8 and far.max() <= 2.0 * 6.0 + 1  # eval_radius_px is 6


def test_multiscale_sees_past_the_contact_at_a_fraction_of_its_cost():
    # the quarter-resolution branch reaches about +-70 px (context: +-33), where a 40 px contact ends
    rows, cols = reached_offsets("multiscale", 161)
    assert int(rows.min()) == 0
    assert 60 <= int(rows.max()) <= 80 and 60 <= int(cols.max()) <= 80
    # an odd-sized input keeps its size (the pooled branch is upsampled back to it)
    with torch.no_grad():
        out = build_model("multiscale").eval()(torch.zeros(1, 5, 37, 45))
    assert out.shape == (1, 2, 37, 45)


def test_depth_integrates_with_one_blas_thread_and_restores_the_pool(monkeypatch):
    # On the CPU, BLAS's workers would compete with torch's for the cores (docs/explanation/models.md).
    from threadpoolctl import ThreadpoolController

    import threedcal.model.inference as inference

    ts = synthetic_set()
    est = DepthEstimator(fresh_checkpoint("compact_tiny", ts, seed=0), device="cpu")
    frame = np.asarray(ts.frames[2])
    expected = est.depth(frame)

    def blas_threads():
        return {i["num_threads"] for i in ThreadpoolController().info() if i["user_api"] == "blas"}

    outside = blas_threads()
    with ThreadpoolController().limit(limits=2, user_api="blas"):
        inside = []
        real = inference.integrate
        monkeypatch.setattr(
            inference, "integrate", lambda *a, **k: inside.append(blas_threads()) or real(*a, **k)
        )
        np.testing.assert_array_equal(est.depth(frame), expected)
        assert inside == [{1}]
        assert blas_threads() == {2}
    assert blas_threads() == outside
