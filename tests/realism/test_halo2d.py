"""The realism check's 2-D halo figures (threedcal.realism.halo2d) against synthetic halos with known
answers, and its tolerance logic."""

import csv
import math

import numpy as np
import pytest

from threedcal.errors import ConfigError
from threedcal.realism import halo2d
from threedcal.realism.halo2d import (
    annulus,
    compare_halos,
    cutout,
    first_moments,
    mean_image,
    nrms,
    passes,
    radius_grid,
    third_moment,
    tolerance,
)


def halo_frame(shape, center, radius, kind, amplitude=30.0):
    """A change image (H, W, 3): a uniform contact disc (-40 DN) and a halo outside it. `round`:
    a ring exp(-(rho - 1) / 0.6) all around; `up`: the same ring only inside a triangle pointing up
    the image (apex 3 radii above the centre, base on the contact's lower edge)."""
    h, w = shape
    yy, xx = np.mgrid[:h, :w].astype(float)
    u, v = (xx - center[0]) / radius, (yy - center[1]) / radius
    rho = np.hypot(u, v)
    ring = np.where(rho > 1, amplitude * np.exp(-(rho - 1) / 0.6), 0.0)
    if kind == "up":
        # inside the triangle with apex (0, -3) and base corners (+-1.8, 1)
        ring = np.where((v <= 1) & (np.abs(u) <= 1.8 * (v + 3) / 4), ring, 0.0)
    img = np.repeat(ring[..., None], 3, axis=2)
    img[rho <= 1] = -40.0
    img[..., 1] *= 0.5  # channels differ: green half as strong, blue negative
    img[..., 2] *= -1.0
    return img


def test_grid_is_centred_and_spans_the_reach():
    u, v = radius_grid(3.0, 0.1)
    assert u.shape == (61, 61) and u[30, 30] == 0 and v[30, 30] == 0
    assert u[0, 0] == pytest.approx(-3.0) and v[-1, 0] == pytest.approx(3.0)  # v down the image


def test_cutout_samples_the_frame_in_contact_radii_and_leaves_the_frame_out():
    # a linear ramp on an odd-sized frame; radius 5 px: the blur (half a step, 0.25 px) is skipped,
    # and bilinear sampling of a linear ramp is exact
    h, w = 23, 37
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    ramp = np.stack([xx, yy, 2 * xx - yy + 7], axis=-1)
    cut = cutout(ramp, (6.0, 11.0), 5.0)
    u, v = radius_grid()
    x, y = 6.0 + 5 * u, 11.0 + 5 * v
    inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    assert np.isnan(cut[~inside]).all() and np.isfinite(cut[inside]).all()
    np.testing.assert_allclose(cut[inside, 0], x[inside], atol=1e-3)
    np.testing.assert_allclose(cut[inside, 2], (2 * x - y + 7)[inside], atol=1e-3)
    one = cutout(ramp[..., 0], (18.0, 11.0), 3.0)  # a single-channel image: one channel back
    assert one.shape == (61, 61, 1)


def test_the_same_halo_at_two_sizes_gives_the_same_cutout():
    small = cutout(halo_frame((201, 151), (75.0, 100.0), 20.0, "up"), (75.0, 100.0), 20.0)
    large = cutout(halo_frame((401, 301), (150.0, 200.0), 40.0, "up"), (150.0, 200.0), 40.0)
    ring = annulus(small.shape[:2])
    round_ = cutout(halo_frame((201, 151), (75.0, 100.0), 20.0, "round"), (75.0, 100.0), 20.0)
    assert nrms(small, large) < 0.1 < 0.5 < nrms(round_, large)  # the triangle's edge sampled
    assert np.isfinite(small[ring]).all()


def test_empty_contacts_and_no_presses_are_refused_with_their_name():
    img = np.zeros((20, 20, 3))
    for bad in (0.0, -3.0, math.nan):
        with pytest.raises(ConfigError, match="0007.png: contact radius must be a positive"):
            cutout(img, (10.0, 10.0), bad, name="0007.png")
    with pytest.raises(ConfigError, match="contact centre must be finite"):
        cutout(img, (math.nan, 10.0), 5.0)
    with pytest.raises(ConfigError, match="no presses to average"):
        mean_image([])
    with pytest.raises(ConfigError, match="square with an odd side"):
        annulus((60, 60))


def test_mean_leaves_out_points_few_presses_see():
    a = np.full((3, 3, 1), 2.0)
    b = np.full((3, 3, 1), 4.0)
    c = np.full((3, 3, 1), np.nan)
    c[1, 1] = 9.0
    b[0, 0] = np.nan
    m = mean_image([a, b, c])
    assert m[1, 1, 0] == pytest.approx(5.0)  # all three
    assert m[0, 1, 0] == pytest.approx(3.0)  # two of three: at least half
    assert np.isnan(m[0, 0, 0])  # one of three


def test_identical_halos_are_zero_apart_and_a_flat_image_is_one():
    real = cutout(halo_frame((201, 151), (75.0, 100.0), 20.0, "up"), (75.0, 100.0), 20.0)
    assert nrms(real, real) == 0.0
    assert nrms(np.zeros_like(real), real) == pytest.approx(1.0)
    assert nrms(2 * real, real) == pytest.approx(1.0)
    assert math.isnan(nrms(real, np.zeros_like(real)))  # no real halo: undefined, not 0


def test_first_moments_of_a_round_halo_are_zero_and_of_a_triangle_up_positive():
    centre = (75.0, 100.0)
    round_ = cutout(halo_frame((201, 151), centre, 20.0, "round"), centre, 20.0)
    up = cutout(halo_frame((201, 151), centre, 20.0, "up"), centre, 20.0)
    r_up, r_right = first_moments(round_)
    assert abs(r_up) < 1e-3 and abs(r_right) < 1e-3
    t_up, t_right = first_moments(up)
    assert t_up > 0.15 and abs(t_right) < 1e-3
    # the same triangle flipped (pointing down the image): the same size, the other sign
    down = cutout(halo_frame((201, 151), centre, 20.0, "up")[::-1], (75.0, 100.0), 20.0)
    assert first_moments(down)[0] == pytest.approx(-t_up, abs=1e-3)
    # a halo only straight up: +1; one half-annulus uniformly lit: 2 / pi (continuous value)
    u, v = radius_grid()
    rho = np.hypot(u, v)
    spike = np.where((np.abs(u) < 1e-9) & (v < -1) & (rho <= 3), 1.0, 0.0)[..., None]
    assert first_moments(spike) == pytest.approx((1.0, 0.0), abs=1e-12)
    half = np.where((v < 0) & (rho > 1) & (rho <= 3), 1.0, 0.0)[..., None]
    assert first_moments(half)[0] == pytest.approx(2 / math.pi, abs=0.02)
    assert all(math.isnan(x) for x in first_moments(np.zeros_like(half)))


def test_tolerance_is_the_reference_intervals_upper_end_and_nan_never_passes():
    draws = np.arange(1, 201, dtype=float)  # 1 .. 200
    assert tolerance(draws) == pytest.approx(np.percentile(draws, 97.5))
    assert tolerance([*draws, math.nan]) == pytest.approx(np.percentile(draws, 97.5))
    assert math.isnan(tolerance([math.nan]))
    assert passes(0.1, 0.2) and passes(0.2, 0.2) and not passes(0.21, 0.2)
    assert not passes(math.nan, 0.2) and not passes(0.1, math.nan)


def presses(kind, n, seed, noise=2.0):
    """n noisy cut-outs of a press of `kind` at varying places and sizes (one press each)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        cx, cy, r = rng.uniform(50, 100), rng.uniform(60, 140), rng.uniform(16, 24)
        img = halo_frame((201, 151), (cx, cy), r, kind)
        img += rng.normal(0, noise, img.shape)
        out.append(cutout(img, (cx, cy), r))
    return out


def test_compare_halos_passes_the_real_shape_and_fails_a_round_one():
    real, other = presses("up", 8, 1), presses("up", 8, 2)
    groups = [[i] for i in range(8)]
    good = compare_halos(real, presses("up", 8, 3), other, groups, groups, draws=60)
    assert good.ok, good.rows
    bad = compare_halos(real, presses("round", 8, 4), other, groups, groups, draws=60)
    rows = {r["figure"]: r for r in bad.rows}
    assert not bad.ok and not rows["halo_nrms"]["ok"] and not rows["halo_m1_up"]["ok"]
    assert rows["halo_m3_up"]["real"] > 0.05 and abs(rows["halo_m3_up"]["sim"]) < 0.02
    assert rows["halo_m1_up"]["real"] > 0.15 and abs(rows["halo_m1_up"]["sim"]) < 0.05
    assert rows["halo_m1_up"]["sim_lo"] <= rows["halo_m1_up"]["sim"] <= rows["halo_m1_up"]["sim_hi"]
    # the simulator identical to the real frames: zero distance, within any tolerance
    same = compare_halos(real, real, other, groups, groups, draws=20)
    assert same.ok and all(r["sim_distance"] == 0 for r in same.rows)
    # images of one press are resampled together; groups must cover every cut-out once
    with pytest.raises(ConfigError, match="held-out half: the press groups must cover"):
        compare_halos(real, real, other, [[0, 1]], groups, draws=2)
    with pytest.raises(ConfigError, match="8 real cut-outs but 7 simulated"):
        compare_halos(real, real[:7], other, groups, groups, draws=2)


def test_table_csv_and_figure(tmp_path):
    real, other = presses("up", 4, 1), presses("up", 4, 2)
    groups = [[0, 1], [2], [3]]  # two images of one press
    res = compare_halos(
        real, presses("round", 4, 3), other, groups, [[i] for i in range(4)], draws=10
    )
    text = halo2d.format_halos(res)
    assert "4 held-out real images (3 presses)" in text and "halo 2-D: FAIL" in text
    halo2d.write_csv([("data/x", "digit", res)], tmp_path / "h.csv")

    rows = list(csv.DictReader(open(tmp_path / "h.csv")))
    assert [r["figure"] for r in rows] == list(halo2d.FIGURES)
    assert rows[0]["real"] == "" and rows[0]["presses"] == "3" and rows[0]["other_images"] == "4"
    halo2d.draw([("data/x", "digit", res)], tmp_path / "h.png")
    assert (tmp_path / "h.png").stat().st_size > 1000


def test_third_moment_sees_a_three_lobed_triangle_about_its_centre():
    u, v = radius_grid()
    rho = np.hypot(u, v)
    alpha = np.arctan2(-v, u)  # counter-clockwise from the right, up = 90 degrees
    ring = (rho > 1) & (rho <= 3)

    def lobes(at_deg):
        m = np.zeros_like(u)
        for a in at_deg:
            d = np.angle(np.exp(1j * (alpha - np.radians(a))))
            m += np.exp(-0.5 * (d / 0.3) ** 2)
        return np.where(ring, m, 0.0)[..., None]

    up = third_moment(lobes([90, 210, 330]))
    # lobes of angular sigma s, far apart: the mean of cos(3 d) under a normal d is exp(-9 s^2 / 2)
    assert up == pytest.approx(math.exp(-4.5 * 0.3**2), abs=0.005)
    assert third_moment(lobes([270, 30, 150])) == pytest.approx(-up, abs=1e-9)
    assert abs(third_moment(np.where(ring, 1.0, 0.0)[..., None])) < 1e-9  # round
    assert first_moments(lobes([90, 210, 330])) == pytest.approx((0.0, 0.0), abs=1e-3)
    spike = np.where((np.abs(u) < 1e-9) & (v < -1) & (rho <= 3), 1.0, 0.0)[..., None]
    assert third_moment(spike) == pytest.approx(1.0, abs=1e-12)
    assert math.isnan(third_moment(np.zeros_like(spike)))
