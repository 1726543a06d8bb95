"""Training losses on gradients against closed-form values, walls and infinite slopes included."""

import math

import numpy as np
import pytest
import torch
from test_model import TINY, synthetic_set

from threedcal.model.losses import gradient_loss, unit_normals
from threedcal.model.train import train
from threedcal.model.train_settings import TrainSettings


def field(gx, gy=0.0, shape=(3, 4)) -> torch.Tensor:
    out = torch.zeros(1, 2, *shape)
    out[:, 0], out[:, 1] = gx, gy
    return out


def test_unit_normals_flat_45_degrees_vertical_and_huge_slopes():
    assert torch.allclose(unit_normals(field(0.0))[0, :, 0, 0], torch.tensor([0.0, 0.0, 1.0]))
    half = 1 / math.sqrt(2)
    assert torch.allclose(unit_normals(field(1.0))[0, :, 1, 2], torch.tensor([-half, 0.0, half]))
    # a slope toward -y of 3-4-5 proportions
    assert torch.allclose(unit_normals(field(0.0, -0.75))[0, :, 0, 0], torch.tensor([0, 0.6, 0.8]))
    for wall in (math.inf, 3.0e38):  # a vertical wall, and a slope whose square overflows
        normal = unit_normals(field(wall))[0, :, 0, 0]
        assert torch.isfinite(normal).all()
        assert torch.allclose(normal, torch.tensor([-1.0, 0.0, 0.0]))


def test_mse_and_huber_closed_form():
    pred, target = field(0.5), field(0.0)
    assert float(gradient_loss(pred, target, "mse")) == pytest.approx(0.25 / 2)  # gy error is 0
    # below the delta the Huber loss is the squared error; above it 2|e| - 1
    assert float(gradient_loss(pred, target, "huber")) == pytest.approx(0.25 / 2)
    assert float(gradient_loss(field(5.0), target, "huber")) == pytest.approx((2 * 5 - 1) / 2)
    assert float(gradient_loss(field(5.0), target, "mse")) == pytest.approx(25 / 2)


def test_normal_loss_matches_mse_for_small_slopes_and_is_bounded_on_a_wall():
    small = float(gradient_loss(field(1e-3), field(0.0), "normal"))
    assert small == pytest.approx(float(gradient_loss(field(1e-3), field(0.0), "mse")), rel=1e-3)
    # 45 degrees against flat: |n1 - n2|^2 = 2 - 2 cos 45, over the 2 gradient components
    assert float(gradient_loss(field(1.0), field(0.0), "normal")) == pytest.approx(
        (2 - 2 * math.cos(math.pi / 4)) / 2, rel=1e-6
    )
    # a wall's label (34: a 1 mm wall's cell average) against a 60-degree prediction pulls little;
    # the squared gradient error of the same pixel is a thousand times more
    wall, sixty = field(34.0), field(math.tan(math.radians(60)))
    normal = float(gradient_loss(sixty, wall, "normal"))
    assert normal == pytest.approx(
        (2 - 2 * math.cos(math.radians(90 - 60) - math.atan(1 / 34))) / 2, rel=1e-5
    )
    assert float(gradient_loss(sixty, wall, "mse")) > 1000 * normal
    assert float(gradient_loss(field(-math.inf), field(math.inf), "normal")) == pytest.approx(2.0)


def test_unknown_loss_is_refused():
    with pytest.raises(ValueError, match="allowed: mse, huber, normal"):
        gradient_loss(field(0.0), field(0.0), "l1")


def test_the_loss_setting_trains_another_model_and_is_recorded(tmp_path):
    ts = synthetic_set()
    models = {}
    for loss in ("mse", "normal"):
        settings = TrainSettings.of(preset="compact_tiny", seed=3, loss=loss, **TINY)
        checkpoint = train(ts, tmp_path / loss, 80, settings, progress=False)
        assert checkpoint["training"]["settings"]["loss"] == loss
        models[loss] = (tmp_path / loss / "model.pt").read_bytes()
    assert models["mse"] != models["normal"]
    assert TrainSettings.of().loss == "mse"  # the paper's, the schema's default
    assert np.isfinite(
        np.loadtxt(tmp_path / "normal/losses.csv", delimiter=",", skiprows=1, usecols=(1, 2))
    ).all()
