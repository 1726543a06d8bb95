"""Units of a sensor model (threedcal.sim.units) and their simulated presses (threedcal.dataset.unit_presses)."""

import numpy as np
import pytest

from threedcal.dataset.trainset import TrainingSet, downscale
from threedcal.dataset.unit_presses import simulate_units
from threedcal.errors import ConfigError
from threedcal.profiles import load_profile
from threedcal.sim.units import draw_unit


@pytest.fixture(scope="module")
def mini():
    return load_profile("sensor", "gelsight_mini")


def test_a_unit_is_the_same_for_its_seed_and_another_for_another(mini):
    a, b, c = draw_unit(mini, 7), draw_unit(mini, 7), draw_unit(mini, 8)
    assert a == b and a != c
    assert draw_unit(mini, None) == dict(mini)
    assert mini["lights"][0]["gain_dn"] == 100  # the profile itself is untouched


def test_only_the_constants_given_a_spread_vary(mini):
    still = {**mini, "unit_variation": {"light_gain": 0.2}}
    unit = draw_unit(still, 3)
    gains = [light["gain_dn"] for light in unit["lights"]]
    assert all(g != 100 for g in gains)
    for light, original in zip(unit["lights"], mini["lights"], strict=True):
        assert {k: v for k, v in light.items() if k != "gain_dn"} == {
            k: v for k, v in original.items() if k != "gain_dn"
        }
    assert unit["optics"] == mini["optics"] and unit["gel"] == mini["gel"]


def test_the_spread_over_units_is_the_profiles(mini):
    spread = mini["unit_variation"]
    gains = np.log([draw_unit(mini, u)["lights"][0]["gain_dn"] / 100 for u in range(400)])
    azimuths = [draw_unit(mini, u)["lights"][1]["azimuth_deg"] for u in range(400)]
    assert np.std(gains) == pytest.approx(spread["light_gain"], rel=0.15)
    assert np.std(azimuths) == pytest.approx(spread["light_azimuth_deg"], rel=0.15)
    assert np.mean(azimuths) == pytest.approx(mini["lights"][1]["azimuth_deg"], abs=0.6)


def test_a_profile_without_a_spread_cannot_be_drawn(mini):
    with pytest.raises(ConfigError, match="no unit_variation block"):
        draw_unit({k: v for k, v in mini.items() if k != "unit_variation"}, 1)


def test_unit_presses_know_their_units_blank_and_their_exact_labels(mini):
    ts = simulate_units(mini, [3, 4, 5], 4, (0.6, 1.2), 2.0, factor=2, val_units=1, progress=False)
    assert ts.frames.shape == (12, 120, 160, 3) and ts.unit_blanks.shape == (3, 120, 160, 3)
    assert list(ts.samples["unit"]) == [0] * 4 + [1] * 4 + [2] * 4
    assert list(ts.split) == ["train"] * 8 + ["val"] * 4
    assert ts.px_per_mm == pytest.approx(mini["px_per_mm"] / 2) and ts.meta["units"] == [3, 4, 5]
    # each frame's input is measured from its own unit's blank
    np.testing.assert_allclose(
        ts.inputs(5)[:3],
        (ts.frames[5].astype(np.float32) - ts.unit_blanks[1]).transpose(2, 0, 1) / 255,
    )
    # the contact shows where the label's slopes are: the colour change peaks inside the disc
    for i in range(len(ts.frames)):
        change = np.abs(ts.inputs(i)[:3]).sum(0)
        slope = np.hypot(*ts.labels(i))
        assert change[slope > 0].mean() > 3 * change[slope == 0].mean()


def test_a_set_of_units_round_trips_and_pools(tmp_path, mini):
    ts = simulate_units(mini, [9, 10], 2, (0.5, 1.0), 2.0, val_units=0, progress=False)
    ts.save(tmp_path / "set")
    back = TrainingSet.load(tmp_path / "set")
    np.testing.assert_array_equal(back.unit_blanks, ts.unit_blanks)
    assert list(back.unit) == [0, 0, 1, 1]
    pooled = downscale(back, 4)
    assert pooled.unit_blanks.shape == (2, 60, 80, 3)
    np.testing.assert_allclose(pooled.blank_of(3), pooled.unit_blanks[1])


def test_unit_presses_refuse_depths_past_the_ball(mini):
    with pytest.raises(ConfigError, match=r"must lie within \(0, 2.0\]"):
        simulate_units(mini, [1, 2], 2, (0.5, 2.5), 2.0, progress=False)
