import copy

import numpy as np
import pytest

from threedcal.cli import main
from threedcal.profiles import load_profile
from threedcal.sim.optics import sphere_normals
from threedcal.sim.realism import BallLabel, compare, image_figures, load_ball_dataset


def test_realism_passes_on_the_vendored_real_data(real_data, capsys):
    code = main(["sim", "realism", "--real", str(real_data / "gelsight_ball_fots")])
    out = capsys.readouterr().out
    assert "bg_lowfreq_std" in out and "r2_G" in out and "hf_noise_std" in out
    assert code == 0, out


def test_realism_passes_with_the_elastic_gel_too(real_data):
    """The Mini with gel.mechanics: elastic (its contact at a given depth is smaller, so each label's
    depth comes from the elastic gel's own contact radius) stays within every tolerance."""
    data = load_ball_dataset(real_data / "gelsight_ball_fots")
    profile = copy.deepcopy(load_profile("sensor", "gelsight_mini"))
    profile["gel"]["mechanics"] = "elastic"
    rows = compare(data, profile)
    assert all(r["ok"] for r in rows), [r for r in rows if not r["ok"]]


def test_realism_fails_when_the_simulator_is_too_noisy(real_data):
    data = load_ball_dataset(real_data / "gelsight_ball_fots")
    data = type(data)(
        data.root,
        data.px_per_mm,
        data.ball_radius_mm,
        data.width_px,
        data.height_px,
        data.labels[:6],
    )
    profile = copy.deepcopy(load_profile("sensor", "gelsight_mini"))
    profile["optics"]["noise_dn"] = [6.0, 6.0, 6.0]
    rows = {r["figure"]: r for r in compare(data, profile)}
    assert not rows["hf_noise_std"]["ok"]


def test_r2_is_one_for_exactly_linear_shading():
    h, w, R = 120, 100, 30.0
    label = BallLabel("x", (50.0, 60.0), 25.0)
    nx, ny, nz = (np.nan_to_num(v) for v in sphere_normals((h, w), label.center_px, R))
    bg = np.full((h, w, 3), 120.0)
    img = bg.copy()
    img[..., 0] += 40 * nx
    img[..., 1] += 30 * ny - 10 * nz
    img[..., 2] += 20 * nz
    fig = image_figures(img, bg, label, R)
    for c in "RGB":
        assert fig[f"r2_{c}"] == pytest.approx(1.0, abs=1e-9)
    # 1 % of a uniform disc of radius rho lies beyond x = -0.9236 rho: (acos t - t sqrt(1 - t^2)) / pi
    assert fig["dI_p1_R"] == pytest.approx(-40 * 0.9236 * (0.9 * 25 / R), abs=1.0)
