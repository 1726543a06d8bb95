"""Units of a sensor model (threedcal.sim.units) and their simulated presses (threedcal.dataset.unit_presses)."""

import numpy as np
import pytest
from numpy.polynomial import legendre

from threedcal.dataset.trainset import TrainingSet, downscale
from threedcal.dataset.unit_presses import simulate_units
from threedcal.errors import ConfigError
from threedcal.profiles import load_profile
from threedcal.sim.units import FIELD_DEGREE, draw_unit, legendre_terms, smooth_field_coefficients


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
    # the mean of 400 draws: within three standard errors of the profile's
    standard_error = spread["light_azimuth_deg"] / np.sqrt(len(azimuths))
    assert np.mean(azimuths) == pytest.approx(
        mini["lights"][1]["azimuth_deg"], abs=3 * standard_error
    )


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


def _legendre_field(weights, degree, u, v):
    """sum_t w_t sqrt((2i+1)(2j+1)) P_i(u) P_j(v), per channel, straight from Legendre's series."""
    out = np.zeros((3, *u.shape))
    for t, (i, j) in enumerate(legendre_terms(degree)):
        pi = legendre.legval(u, np.eye(i + 1)[i]) * np.sqrt(2 * i + 1)
        pj = legendre.legval(v, np.eye(j + 1)[j]) * np.sqrt(2 * j + 1)
        out += weights[:, t, None, None] * (pi * pj)[None]
    return out


@pytest.mark.parametrize("degree", [1, 2, 4])
def test_a_units_own_field_is_its_legendre_series_in_the_simulators_basis(degree):
    from threedcal.sim.background_field import field_terms
    from threedcal.sim.units import legendre_terms, smooth_field_coefficients

    coefficients = smooth_field_coefficients(np.random.default_rng(5), 6.0, degree)
    count = len(legendre_terms(degree))
    weights = np.random.default_rng(5).normal(0, 6.0 / np.sqrt(count), (3, count))
    width, height = 31, 17  # odd sizes: u, v run -1..1 from edge pixel to edge pixel
    monomials = np.einsum("khw,ck->chw", np.stack(field_terms(width, height, degree)), coefficients)
    u, v = np.meshgrid(np.linspace(-1, 1, width), np.linspace(-1, 1, height))
    # field_terms is float32: equal to its rounding
    np.testing.assert_allclose(monomials, _legendre_field(weights, degree, u, v), atol=1e-5)
    # mean zero over the square (Gauss-Legendre quadrature is exact for these degrees)
    nodes, w = np.polynomial.legendre.leggauss(degree + 1)
    uu, vv = np.meshgrid(nodes, nodes)
    mean = np.einsum("chw,h,w->c", _legendre_field(weights, degree, uu, vv), w, w) / 4
    np.testing.assert_allclose(mean, 0.0, atol=1e-9)


def test_a_units_own_field_has_the_stated_rms_over_units():
    nodes, w = np.polynomial.legendre.leggauss(6)
    uu, vv = np.meshgrid(nodes, nodes)
    terms = np.stack([uu ** (k - j) * vv**j for k in range(5) for j in range(k + 1)])
    rng = np.random.default_rng(0)
    fields = [
        np.einsum("khw,ck->chw", terms, smooth_field_coefficients(rng, 4.0)) for _ in range(2000)
    ]
    mean_square = np.mean([np.einsum("chw,h,w->c", f * f, w, w) / 4 for f in fields], axis=0)
    np.testing.assert_allclose(np.sqrt(mean_square), 4.0, rtol=0.05)


def test_a_unit_gets_its_own_background_field_on_top_of_the_profiles():
    digit = load_profile("sensor", "digit_fots")
    spread = {"background_field_dn": 10.0}
    unit = draw_unit({**digit, "unit_variation": spread}, 4)
    assert unit == draw_unit({**digit, "unit_variation": spread}, 4)
    own = np.asarray(digit["optics"]["background_field"]["coefficients_dn"])
    drawn = np.asarray(unit["optics"]["background_field"]["coefficients_dn"])
    assert drawn.shape == own.shape and not np.allclose(drawn, own)
    # a profile without a field (the Mini) gets one of the units' degree; the rest is untouched
    mini = load_profile("sensor", "gelsight_mini")
    assert not mini["optics"].get("background_field")
    unit = draw_unit({**mini, "unit_variation": spread}, 4)
    assert unit["optics"]["background_field"]["degree"] == FIELD_DEGREE
    assert unit["lights"] == mini["lights"] and unit["gel"] == mini["gel"]


def test_a_units_skin_is_drawn_in_its_range_and_a_bad_range_refused():
    digit = load_profile("sensor", "digit_fots")
    spread = {"skin_tension_range_n_per_mm": [0.5, 1.5]}
    tensions = [
        draw_unit({**digit, "unit_variation": spread}, u)["gel"]["skin_tension_n_per_mm"]
        for u in range(200)
    ]
    assert 0.5 <= min(tensions) < 0.6 and 1.4 < max(tensions) <= 1.5
    with pytest.raises(ConfigError, match="skin_tension_range_n_per_mm"):
        draw_unit({**digit, "unit_variation": {"skin_tension_range_n_per_mm": [2.0, 1.0]}}, 1)


def test_pretraining_frames_drift_from_their_blank_by_a_smooth_field_of_the_stated_rms(mini):
    from threedcal.dataset.unit_presses import DRIFT_DEGREE, drifted_frames
    from threedcal.sim.background_field import field_terms

    bare = {k: v for k, v in mini.items() if k != "lens"}  # no lens: the frames as rendered
    still = {**bare, "unit_variation": {"light_gain": 0.1}}
    drifted = {**bare, "unit_variation": {"light_gain": 0.1, "blank_drift_dn": 6.0}}
    a = simulate_units(still, [3], 6, (0.5, 1.0), 2.0, val_units=0, progress=False)
    b = simulate_units(drifted, [3], 6, (0.5, 1.0), 2.0, val_units=0, progress=False)
    np.testing.assert_array_equal(a.unit_blanks, b.unit_blanks)  # the blank does not drift
    np.testing.assert_array_equal(b.frames, drifted_frames(a.frames, 6.0, 3))
    # each frame's drift is its own quadratic field (then one rounding), about 6 DN rms
    height, width = a.image_shape
    terms = np.stack(field_terms(width, height, DRIFT_DEGREE)).reshape(6, -1).T.astype(float)
    fields = []
    for fa, fb in zip(a.frames, b.frames, strict=True):
        diff = (fb.astype(float) - fa.astype(float)).reshape(-1, 3)
        inside = ((fb > 0) & (fb < 255)).reshape(-1, 3).all(axis=1)  # not clipped
        fitted, *_ = np.linalg.lstsq(terms[inside], diff[inside], rcond=None)
        assert (diff[inside] - terms[inside] @ fitted).std() < 0.35  # rounding: 0.29
        fields.append(terms @ fitted)
    assert not np.allclose(fields[0], fields[1])
    assert 2.0 < np.sqrt(np.mean(np.square(fields))) < 12.0
