import math

import numpy as np
import pytest

from threedcal.errors import ConfigError
from threedcal.profiles import load_profile
from threedcal.sim.indenters import Flat, Relief, Sphere
from threedcal.sim.optics import GelSimulator


@pytest.fixture(scope="module", params=["digit", "gelsight_mini"])
def sim(request):
    return GelSimulator(load_profile("sensor", request.param), seed=7)


def test_profiles_validate_and_hold_the_issue_constants():
    digit, mini = load_profile("sensor", "digit"), load_profile("sensor", "gelsight_mini")
    assert (digit["image"]["width_px"], digit["image"]["height_px"]) == (240, 320)
    assert (mini["image"]["width_px"], mini["image"]["height_px"]) == (320, 240)
    assert digit["gel"]["max_penetration_mm"] == 4.0 and mini["gel"]["max_penetration_mm"] == 3.5
    assert mini["px_per_mm"] == pytest.approx(1 / 0.0634, rel=1e-3)
    assert len(digit["lights"]) == 3 and digit["gel"]["dome"] is not None


def test_sensor_schema_is_closed(tmp_path):
    bad = tmp_path / "s.yaml"
    bad.write_text("name: s\ntype: vision\npx_per_mm: 10\ncolour: red\n")
    with pytest.raises(ConfigError, match="unknown key 'colour'"):
        load_profile("sensor", bad)
    incomplete = tmp_path / "t.yaml"
    incomplete.write_text("name: t\ntype: vision\n")
    with pytest.raises(ConfigError, match="'gel' is a required property"):
        load_profile("sensor", incomplete)


def test_same_seed_same_bytes_and_frames_differ_by_noise(sim):
    ball = Sphere(2.0)
    a = sim.render(ball, (100.3, 110.7), 0, 1.0, frame_index=5)
    b = GelSimulator(sim.profile, seed=7).render(ball, (100.3, 110.7), 0, 1.0, frame_index=5)
    assert a.dtype == np.uint8 and a.shape == (sim.height, sim.width, 3)
    assert np.array_equal(a, b)
    c = sim.render(ball, (100.3, 110.7), 0, 1.0, frame_index=6)
    diff = a.astype(int) - c.astype(int)
    assert 0.3 < diff.std() < 5  # about 1 DN of noise per frame, not a different image


def test_gel_follows_an_exact_sphere_inside_the_contact(sim):
    """In contact the gel is the ball; the contact is where the ball lies below the undeformed
    surface: the flat circle of radius sqrt(2Rd - d²), or on a dome a region off the axis."""
    R, d = 2.0, 0.8
    ball = Sphere(R)
    center = (sim.width / 2 + 0.37, sim.height / 2 - 0.21)
    win = sim.window(ball, center, d)
    z, contact = sim.surface(ball, center, 0.0, d, win)
    y0, y1, x0, x1 = win
    yy, xx = np.mgrid[y0:y1, x0:x1]
    r = np.hypot(xx - center[0], yy - center[1]) / sim.px_per_mm
    sag_c = float(
        sim.sag_mm((center[0] - sim._cx) / sim.px_per_mm, (center[1] - sim._cy) / sim.px_per_mm)
    )
    expected = sag_c + d - (R - np.sqrt(np.maximum(R * R - r**2, 0)))
    below = np.where(r < R, expected - sim.Z0[y0:y1, x0:x1], -1.0)
    mismatch = contact ^ (below > 0)
    assert not mismatch.any() or np.abs(below[mismatch]).max() < 1e-5  # float32 rounding only
    if not sim.domed:
        a = math.sqrt(2 * R * d - d * d)
        assert np.abs(r[contact].max() - a) < 1.5 / sim.px_per_mm
    np.testing.assert_allclose(z[contact], expected[contact], atol=1e-5)
    assert z[contact].max() == pytest.approx(sag_c + d, abs=2e-3)


def test_a_domed_gels_contact_leans_toward_the_apex():
    """Off the apex a dome falls away from the ball: the contact's centroid lies toward the apex and
    outside it the gel returns to the dome, never above it (no lifted patch)."""
    profile = dict(load_profile("sensor", "digit"))
    profile["lens"] = None
    sim = GelSimulator(profile, seed=0)
    ball = Sphere(2.0)
    center = (sim.width / 2 - 60.0, sim.height / 2)  # left of the apex
    win = sim.window(ball, center, 0.5)
    z, contact = sim.surface(ball, center, 0.0, 0.5, win)
    y0, y1, x0, x1 = win
    xx = np.mgrid[y0:y1, x0:x1][1]
    assert xx[contact].mean() > center[0] + 0.5  # toward the apex (right), by pixels
    outside = ~contact
    rim_band = z[outside] - sim.Z0[y0:y1, x0:x1][outside]
    assert rim_band.max() < 1e-6  # a raised rim (toward the camera is +), never pushed in
    assert rim_band.min() < -1e-3  # ... and it is there


def test_contact_changes_the_image_where_the_ball_is(sim):
    blank = sim.blank(frame_index=3).astype(int)
    frame = sim.render(Sphere(2.0), (sim.width / 2, sim.height / 2), 0, 1.2, frame_index=3).astype(
        int
    )
    change = np.abs(frame - blank).sum(axis=2)
    cy, cx = sim.height // 2, sim.width // 2
    assert change[cy - 20 : cy + 20, cx - 20 : cx + 20].mean() > 20
    assert change[:10, :10].max() <= 6  # far corner: only quantisation and flicker


def test_depth_beyond_max_penetration_is_a_clear_error(sim):
    with pytest.raises(ConfigError, match="maximum safe penetration"):
        sim.render(Sphere(2.0), (50, 50), 0, sim.max_penetration_mm + 0.01)
    with pytest.raises(ConfigError):
        sim.render(Sphere(2.0), (50, 50), 0, float("nan"))
    with pytest.raises(ConfigError):
        sim.render(Sphere(2.0), (50, 50), 0, -0.1)


def test_indenter_outside_the_gel_leaves_the_image_unchanged(sim):
    far = (-10 * sim.width, 5 * sim.height)
    assert np.array_equal(sim.render(Sphere(2.0), far, 0, 1.0, frame_index=4), sim.blank(4))
    assert np.array_equal(sim.render(Sphere(2.0), (50, 50), 0, 0.0, frame_index=4), sim.blank(4))


@pytest.mark.parametrize("indenter", [Flat(3.0), Sphere(1.0)])
def test_vertical_walls_and_full_depth_stay_finite_and_clipped(sim, indenter):
    frame = sim.render(
        indenter, (sim.width / 2, sim.height / 2), 0, sim.max_penetration_mm, frame_index=1
    )
    assert frame.dtype == np.uint8
    delta = sim.contact_change(indenter, (sim.width / 2, sim.height / 2), 0, sim.max_penetration_mm)
    assert np.isfinite(delta[1]).all()
    # a very bright raw value saturates at 255 instead of wrapping to a dark one
    bright = sim._finish(np.full((sim.height, sim.width, 3), 400.0, np.float32), 0)
    dark = sim._finish(np.full((sim.height, sim.width, 3), -50.0, np.float32), 0)
    assert bright.min() == 255 and dark.max() == 0


def toward_led(light, contact_mm):
    dx, dy = light["P"][0] - contact_mm[0], light["P"][1] - contact_mm[1]
    return dx / math.hypot(dx, dy), dy / math.hypot(dx, dy)


@pytest.mark.parametrize("contact_mm", [(0.0, 0.0), (-8.0, 0.0), (8.0, 5.0)])
def test_steep_walls_cast_shadows_away_from_the_light(contact_mm):
    # The LED is a point at a finite distance: its shadows point away from it, so their direction
    # changes across the frame (by ~15 degrees 8 mm off the centre for the Mini's red LED).
    sim = GelSimulator(load_profile("sensor", "gelsight_mini"), seed=0)
    light = sim._lights[0]
    z = np.zeros((40, 40), np.float32)
    z[15:25, 15:25] = 2.0  # a 2 mm block toward the camera
    lit = sim._lit(z, light, contact_mm)
    ux, uy = toward_led(light, contact_mm)
    behind = (int(round(20 - 8 * uy)), int(round(20 - 8 * ux)))  # row, col on the far side
    toward = (int(round(20 + 10 * uy)), int(round(20 + 10 * ux)))
    # A shadow removes `shadow_strength` of the directional light (scattered light fills the rest).
    assert lit[behind] == pytest.approx(1 - sim.shadow_strength)
    assert lit[toward] == 1 and lit[20, 20] == 1


def test_shadow_direction_follows_the_led_position():
    sim = GelSimulator(load_profile("sensor", "gelsight_mini"), seed=0)
    light = sim._lights[0]
    z = np.zeros((60, 60), np.float32)
    z[28:32, 28:32] = 2.0  # a thin post: its shadow is a narrow streak
    streaks = []
    # two contacts 8 mm either side of the line from the centre to the LED: across it the
    # direction to the LED turns most
    px, py = light["P"][0], light["P"][1]
    across = (-py / math.hypot(px, py), px / math.hypot(px, py))
    for contact_mm in [(-8.0 * across[0], -8.0 * across[1]), (8.0 * across[0], 8.0 * across[1])]:
        shadow = np.argwhere(sim._lit(z, light, contact_mm) < 1) - 29.5  # (row, col) from the post
        streaks.append(math.atan2(shadow[:, 0].mean(), shadow[:, 1].mean()))
        expected = toward_led(light, contact_mm)
        assert (
            math.degrees(
                abs(math.remainder(streaks[-1] - math.atan2(-expected[1], -expected[0]), math.tau))
            )
            < 6
        )
    assert abs(math.degrees(math.remainder(streaks[0] - streaks[1], math.tau))) > 15


def test_cast_shadows_end_at_their_reach():
    sim = GelSimulator(load_profile("sensor", "gelsight_mini"), seed=0)
    light = sim._lights[0]
    z = np.zeros((80, 80), np.float32)
    z[35:45, 35:45] = 2.0  # 2 mm high: an unbounded shadow at 14 degrees would run 8 mm
    lit = sim._lit(z, light, (0.0, 0.0))
    ux, uy = toward_led(light, (0.0, 0.0))
    reach_px = sim.shadow_reach_mm * sim.px_per_mm
    far = 5 + reach_px + 3  # from the block's centre: past its wall and the shadow's reach
    beyond = (int(round(40 - far * uy)), int(round(40 - far * ux)))
    assert lit[beyond] == 1


def test_height_map_sphere_matches_the_analytic_sphere():
    R, s = 2.0, 40.0
    yy, xx = (np.mgrid[:161, :161] - 80) / s
    r2 = xx**2 + yy**2
    relief = np.where(r2 <= R * R, np.sqrt(np.maximum(R * R - r2, 0)), np.nan)
    hm, sp = Relief(relief, s), Sphere(R)
    dx = np.array([0.0, 0.3, -1.1, 1.5, 5.0])
    dy = np.array([0.0, 0.2, 0.4, -0.9, 0.0])
    g_hm, g_sp = hm.gap(dx, dy), sp.gap(dx, dy)
    np.testing.assert_allclose(g_hm[:4], g_sp[:4], atol=2e-3)
    assert np.isinf(g_hm[4]) and np.isinf(g_sp[4])


def test_rotation_turns_an_asymmetric_indenter():
    sim = GelSimulator(load_profile("sensor", "gelsight_mini"), seed=0)
    relief = np.zeros((20, 80))  # a 1 x 4 mm bar at 20 px/mm
    bar = Relief(relief, 20.0)
    c = (160.0, 120.0)
    win = sim.window(bar, c, 0.5)
    _, along = sim.surface(bar, c, 0.0, 0.5, win)
    _, across = sim.surface(bar, c, 90.0, 0.5, win)
    cols = lambda m: np.ptp(np.nonzero(m)[1])  # noqa: E731
    rows = lambda m: np.ptp(np.nonzero(m)[0])  # noqa: E731
    assert cols(along) > 3 * rows(along) and rows(across) > 3 * cols(across)


def test_creep_deepens_a_hold_slightly_and_monotonically(sim):
    depths = [sim.effective_depth_mm(1.0, k) for k in (0, 1, 5, 30, 1000)]
    assert depths[0] == 1.0 and all(b > a for a, b in zip(depths, depths[1:], strict=False))
    assert depths[-1] <= 1.0 + sim.creep_fraction + 1e-12


def test_bad_indenters_are_config_errors():
    for make in (lambda: Sphere(0), lambda: Flat(-1), lambda: Relief(np.ones(3), 10)):
        with pytest.raises(ConfigError):
            make()
