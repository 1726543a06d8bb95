"""Training and inference on a CUDA device: what a user with a GPU runs (`model.device: auto`,
`threedcal predict --device cuda`). Skipped without one; on a GPU machine:
`python -m pytest tests/model/test_cuda.py`."""

from dataclasses import replace

import numpy as np
import pytest
import torch
from test_model import SHAPE, TINY, synthetic_set

from threedcal.model import PRESET_NAMES
from threedcal.model.drift import drift_offset
from threedcal.model.inference import DepthEstimator
from threedcal.model.train import configure_torch, train
from threedcal.model.train_settings import TrainSettings

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")

CUDA = torch.device("cuda")


def _gpu_trained(tmp_path, preset, name="a", **overrides):
    settings = TrainSettings.of(preset=preset, seed=3, device="cuda", **{**TINY, **overrides})
    return train(synthetic_set(), tmp_path / name, 80, settings, progress=False)


@pytest.mark.parametrize("preset", PRESET_NAMES)
def test_every_preset_trains_on_the_gpu_to_the_byte_under_deterministic_algorithms(
    tmp_path, preset
):
    checkpoint = _gpu_trained(tmp_path, preset, "a")
    _gpu_trained(tmp_path, preset, "b")
    assert (tmp_path / "a/model.pt").read_bytes() == (tmp_path / "b/model.pt").read_bytes()
    # the checkpoint is the CPU's: it loads and predicts on a machine without CUDA
    assert {v.device.type for v in checkpoint["state_dict"].values()} == {"cpu"}


def test_auto_trains_on_the_gpu():
    settings = TrainSettings.of(preset="context_half", device="auto", **TINY)
    assert configure_torch(settings).type == "cuda"


@pytest.mark.parametrize("preset", ["context_half", "touchnet", "multiscale"])
def test_a_gpu_trained_model_predicts_on_the_cpu_as_on_the_gpu(tmp_path, preset):
    checkpoint = _gpu_trained(tmp_path, preset)
    frames = np.asarray(synthetic_set().frames[:3])
    on_cpu = DepthEstimator(checkpoint, device="cpu").gradients(frames)
    gpu = DepthEstimator(checkpoint, device="cuda")
    on_gpu = gpu.gradients(frames)
    assert on_gpu.shape == on_cpu.shape == (3, *SHAPE, 2) and np.isfinite(on_gpu).all()
    # cuDNN convolutions may run in TF32 (10-bit mantissa): agreement to a part in a hundred
    scale = float(np.abs(on_cpu).max())
    assert float(np.abs(on_gpu - on_cpu).max()) <= 1e-2 * scale
    np.testing.assert_allclose(gpu.gradients(frames[1]), on_gpu[1], atol=1e-3 * scale)
    depth = gpu.depth(frames)
    assert depth.shape == (3, *SHAPE) and np.isfinite(depth).all()


def test_the_drift_offset_is_the_cpus_on_the_gpu_under_deterministic_algorithms():
    x = torch.randn(2, 5, 40, 48)
    x[0, 1, :2] = float("nan")
    before = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True)  # as after a training in this process
    try:
        on_gpu = drift_offset(x.to(CUDA))
    finally:
        torch.use_deterministic_algorithms(before)
    assert on_gpu.device.type == "cuda"
    torch.testing.assert_close(on_gpu.cpu(), drift_offset(x), rtol=0, atol=0, equal_nan=True)


def test_a_gpu_training_follows_the_cpus_losses(tmp_path):
    """Same seed, windows and float32 arithmetic (TF32 aside): the losses of every epoch agree."""
    import pandas as pd

    _gpu_trained(tmp_path, "context_half", "gpu", epochs_base=4, precision="float32")
    settings = TrainSettings.of(
        preset="context_half", seed=3, device="cpu", **{**TINY, "epochs_base": 4}
    )
    train(
        synthetic_set(),
        tmp_path / "cpu",
        80,
        replace(settings, precision="float32"),
        progress=False,
    )
    gpu, cpu = (pd.read_csv(tmp_path / d / "losses.csv") for d in ("gpu", "cpu"))
    assert len(gpu) == len(cpu) == 4
    for column in ("train_loss", "val_loss"):
        np.testing.assert_allclose(gpu[column], cpu[column], rtol=0.05)


def test_predict_and_live_run_on_the_gpu(tmp_path):
    import cv2

    from threedcal.cli import main

    ts = synthetic_set()
    _gpu_trained(tmp_path, "compact_tiny")
    image = tmp_path / "img.png"
    cv2.imwrite(str(image), cv2.cvtColor(np.asarray(ts.frames[0]), cv2.COLOR_RGB2BGR))
    model = str(tmp_path / "a/model.pt")
    predict = ["predict", "--checkpoint", model, "--image", str(image), "--device", "cuda"]
    assert main([*predict, "--out", str(tmp_path / "d.npy")]) == 0
    assert np.load(tmp_path / "d.npy").shape == SHAPE
    ts.save(tmp_path / "set")
    live = ["live", "--checkpoint", model, "--source", str(tmp_path / "set"), "--device", "cuda"]
    assert main([*live, "--out", str(tmp_path / "v.gif"), "--frames", "3"]) == 0
    assert (tmp_path / "v.gif").stat().st_size > 0
