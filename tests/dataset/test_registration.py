import copy
import math

import numpy as np
import pytest
from scipy import stats

from threedcal.dataset.build import contact_material
from threedcal.dataset.camera_fit import fit_affine
from threedcal.dataset.contacts import (
    Contact,
    _median,
    difference_magnitude,
    find_contact,
    locate_contact,
)
from threedcal.dataset.dome_contacts import DomedContacts
from threedcal.dataset.labels import sphere_gradients
from threedcal.dataset.registration import register_camera
from threedcal.dataset.symmetry import (
    _axes_information,
    _levenberg_marquardt,
    _symmetric_outliers,
    refine_by_symmetry,
)
from threedcal.dataset.touch import (
    TOUCH_FIT_SPAN_MM,
    ChangeDetector,
    estimate_touch,
    fit_touch_onset,
    measure_touch_search,
)
from threedcal.errors import RegistrationError
from threedcal.profiles import load_profile
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator

PPM = 19.0
SHAPE = (320, 240)


def shaded_frame(center, depth=1.0, radius=2.0, noise=1.0, seed=0):
    """A stand-in sensor image: a smooth background plus shading linear in the surface gradient."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]]
    background = np.stack([120 + 0.1 * cols, 110 + 0.05 * rows, 130 - 0.05 * cols], axis=-1)
    g = sphere_gradients(SHAPE, center, radius, depth, PPM).astype(float)
    mixing = np.array([[40, 0, 25], [-20, 35, 25], [-20, -35, 25]], dtype=float)  # 3 lights
    shading = g[..., 0:1] * mixing[:, 0] + g[..., 1:2] * mixing[:, 1]
    shading += (np.hypot(g[..., 0], g[..., 1]) > 0)[..., None] * mixing[:, 2]
    frame = background + shading + rng.normal(0, noise, background.shape)
    blank = background + rng.normal(0, noise, background.shape)
    return np.clip(frame, 0, 255).astype(np.uint8), np.clip(blank, 0, 255).astype(np.uint8)


def rotation_scale(theta_deg, sx, sy, shear=0.0):
    t = math.radians(theta_deg)
    rot = np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])
    return rot @ np.array([[sx, shear], [0, sy]])


def test_find_contact_locates_a_subpixel_centre():
    contact = locate_contact(*shaded_frame((101.3, 180.6)))
    assert contact is not None
    assert abs(contact.x_px - 101.3) < 0.5 and abs(contact.y_px - 180.6) < 0.5
    a_px = math.sqrt(2 * 2.0 * 1.0 - 1.0) * PPM
    assert 0.6 * a_px < contact.radius_px < 1.1 * a_px


def test_no_contact_in_a_blank_frame():
    frame, blank = shaded_frame((100, 100), depth=0.0)
    assert find_contact(frame, blank) is None


def test_shape_mismatch_is_an_error():
    frame, blank = shaded_frame((100, 100))
    with pytest.raises(RegistrationError, match="shape"):
        find_contact(frame[:-1], blank)


def test_affine_with_rotation_and_unequal_scales_is_recovered_from_frames():
    linear = rotation_scale(3.0, 19.2, -18.7)  # printer y points up in the image: negative scale
    offset = np.array([118.0, 162.0])
    xs, ys = np.meshgrid(np.linspace(-3, 3, 5), np.linspace(-5, 5, 6))
    xy_mm = np.column_stack([xs.ravel(), ys.ravel()])
    truth = xy_mm @ linear.T + offset
    found = []
    for i, (cx, cy) in enumerate(truth):
        contact = locate_contact(*shaded_frame((cx, cy), seed=i))
        found.append((np.nan, np.nan) if contact is None else (contact.x_px, contact.y_px))
    assert np.isfinite(found).all(axis=1).sum() >= 15  # contacts cut by the frame edge are left out
    fit = fit_affine(xy_mm, np.array(found))
    np.testing.assert_allclose(fit.matrix[:, :2], linear, atol=0.05)
    # Error of the fitted map over the probed area, against the true one.
    error = np.linalg.norm(fit.apply(xy_mm) - truth, axis=1)
    assert error.max() < 0.3
    sx, sy = fit.px_per_mm
    assert sx == pytest.approx(19.2, abs=0.05) and sy == pytest.approx(18.7, abs=0.05)


def test_affine_fit_rejects_outliers():
    rng = np.random.default_rng(1)
    linear = rotation_scale(-2.0, 20.0, 21.0, shear=0.3)
    xy_mm = rng.uniform(-5, 5, (60, 2))
    px = xy_mm @ linear.T + [100, 150] + rng.normal(0, 0.1, (60, 2))
    px[[3, 17, 42]] += [[25, 0], [0, -40], [13, 13]]
    px[8] = np.nan  # a frame with no contact found
    fit = fit_affine(xy_mm, px)
    assert not fit.inliers[[3, 17, 42, 8]].any()
    assert fit.inliers.sum() == 56
    np.testing.assert_allclose(fit.matrix[:, :2], linear, atol=0.02)
    assert fit.residual_px < 0.2


def test_affine_needs_three_non_collinear_points():
    with pytest.raises(RegistrationError, match="not on one line"):
        fit_affine(np.array([[0, 0], [1, 1], [2, 2]]), np.array([[0, 0], [1, 1], [2, 2]]))


def test_touch_offset_recovered_from_contact_radii():
    R, delta = 2.0, 0.15
    commanded = np.array([0.3, 0.5, 0.8, 1.0, 1.2])
    true = commanded + delta
    a = np.sqrt(2 * R * true - true**2)
    estimate = estimate_touch(commanded, a, R)
    assert estimate.offset_mm == pytest.approx(delta, abs=1e-9)
    with pytest.raises(RegistrationError):
        estimate_touch(commanded, np.zeros(5), R)


def test_one_depth_takes_an_edge_offset_for_depth_several_depths_separate_them():
    R, delta, edge = 2.0, -0.05, 0.05  # the rim located 1 px (at 20 px/mm) outside the edge
    rng = np.random.default_rng(4)

    def radii(commanded):
        true = commanded + delta
        return np.sqrt(2 * R * true - true**2) + edge + rng.normal(0, 0.003, commanded.shape)

    one = np.full(40, 1.0)
    single = estimate_touch(one, radii(one), R)
    assert single.edge_mm is None
    # the median reads e / (da/dd) = 0.05 / ((R - d) / a) ≈ 0.08 mm of extra depth
    assert single.offset_mm - delta == pytest.approx(0.08, abs=0.02)
    several = np.repeat([0.5, 1.0, 1.5], 40)
    a = radii(several)
    a[:3] = 0.3  # a few halo-shrunk radii: the robust loss shrugs them off
    both = estimate_touch(several, a, R)
    assert both.offset_mm == pytest.approx(delta, abs=0.01)
    assert both.edge_mm == pytest.approx(edge, abs=0.005)


def sim_contacts(sensor, n=3, seed=1, margin=50):
    """Frames (mean of 3) of a 2 mm sphere 1 mm deep on an n x n grid of known sub-pixel centres."""
    sim = GelSimulator(load_profile("sensor", sensor), seed=seed)
    blank = np.mean([sim.blank(i).astype(np.float32) for i in range(10)], axis=0)
    rng = np.random.default_rng(seed)
    centres, frames = [], []
    for cx in np.linspace(margin, sim.width - 1 - margin, n):
        for cy in np.linspace(margin, sim.height - 1 - margin, n):
            centre = (cx + rng.uniform(-0.5, 0.5), cy + rng.uniform(-0.5, 0.5))
            shots = [sim.render(Sphere(2.0), centre, 0, 1.0, frame_index=k) for k in range(3)]
            mean = np.mean(np.asarray(shots, dtype=np.float32), axis=0)
            frames.append(np.clip(mean + 0.5, 0, 255).astype(np.uint8))
            centres.append(centre)
    return sim, np.array(centres), frames, blank


@pytest.fixture(scope="module")
def mini_contacts():
    return sim_contacts("gelsight_mini")


def test_symmetry_finds_centres_the_rim_misses_and_unmixes_the_leds(mini_contacts):
    sim, centres, frames, blank = mini_contacts
    rim = [locate_contact(f, blank) for f in frames]
    refined = refine_by_symmetry(frames, blank, rim)
    assert all(c is not None for c in refined.contacts)
    found = np.array([(c.x_px, c.y_px) for c in refined.contacts])
    rim_xy = np.array([(c.x_px, c.y_px) for c in rim])
    symmetry_error = np.linalg.norm(found - centres, axis=1)
    rim_error = np.linalg.norm(rim_xy - centres, axis=1)
    assert symmetry_error.max() < 0.35, symmetry_error
    assert np.sqrt(np.mean(symmetry_error**2)) < 0.5 * np.sqrt(np.mean(rim_error**2))
    # The unmixing matches the inverse of the simulator's LED colour matrix (diagonal scaled to 1).
    inverse = np.linalg.inv(sim._col).T
    np.testing.assert_allclose(refined.unmixing, inverse / np.diag(inverse)[:, None], atol=0.03)


def test_saturated_pixels_take_no_part_in_the_symmetric_centre(mini_contacts):
    sim, centres, frames, blank = mini_contacts
    # Overexposed by 20 %: about a third of every frame clips at 255, through the contacts too.
    frames = [np.clip(f.astype(np.float32) * 1.2, 0, 255).astype(np.uint8) for f in frames]
    blank = np.clip(blank * 1.2, 0, 255)
    assert np.mean([(f == 255).any(axis=-1).mean() for f in frames]) > 0.3
    rim = [locate_contact(f, blank) for f in frames]
    refined = refine_by_symmetry(frames, blank, rim)
    kept = [i for i, c in enumerate(refined.contacts) if c is not None]
    assert len(kept) >= 5  # contacts with too few unclipped mirror pairs are dropped, not guessed
    found = np.array([(refined.contacts[i].x_px, refined.contacts[i].y_px) for i in kept])
    error = np.linalg.norm(found - centres[kept], axis=1)
    rim_error = np.linalg.norm(
        np.array([(rim[i].x_px, rim[i].y_px) for i in kept]) - centres[kept], axis=1
    )
    assert error.max() < 0.3, error
    assert np.sqrt(np.mean(error**2)) < 0.5 * np.sqrt(np.mean(rim_error**2))


def test_register_keeps_the_locator_an_affine_explains_better(mini_contacts):
    sim, centres, frames, blank = mini_contacts
    truth = np.array([[15.7, 0.4], [0.4, -15.7]])
    xy_mm = (centres - [160, 120]) @ np.linalg.inv(truth).T
    result = register_camera(xy_mm, frames, blank)
    assert result.locator == "symmetry"
    assert result.residual_px["symmetry"] < result.residual_px["rim"]
    error = np.linalg.norm(result.fit.apply(xy_mm) - centres, axis=1)
    assert error.max() < 0.2
    # Grey frames carry one channel: no symmetry in 2D from one LED axis, the rim is used.
    grey = [f.mean(axis=-1) for f in frames]
    result = register_camera(xy_mm, grey, blank.mean(axis=-1))
    assert result.locator == "rim" and result.unmixing is None
    assert set(result.residual_px) == {"rim"}


def test_register_uses_only_the_rim_on_a_domed_gel_and_moves_its_centres_to_the_axis():
    """The DIGIT's domed blank is shaded on a slope, which breaks each LED image's symmetry: only
    the rim runs. Its contacts lean toward the dome's apex (the dome falls away from the ball);
    DomedContacts moves each centre back to its press's axis."""
    sim, centres, frames, blank = sim_contacts("digit", margin=60)
    xy_mm = (centres - [120, 160]) / 19.5
    dome = DomedContacts(
        load_profile("sensor", "digit")["gel"]["dome"],
        2.0,
        np.full(len(frames), 1.0),
        sim.px_per_mm,
        blank.shape,
    )
    result = register_camera(xy_mm, frames, blank, flat_gel=False, dome=dome)
    assert result.locator == "rim" and set(result.residual_px) == {"rim"}
    assert result.unmixing is None
    error = np.linalg.norm(result.fit.apply(xy_mm) - centres, axis=1)
    assert error.max() < 0.5
    leaning = register_camera(xy_mm, frames, blank, flat_gel=False)  # the contacts' own centres
    assert np.linalg.norm(leaning.fit.apply(xy_mm) - centres, axis=1).max() > 2 * error.max()


def test_domed_contacts_lean_toward_the_apex_and_are_moved_back_exactly():
    """The model's contact centre of a press left of and below the apex lies toward the apex;
    to_axis is its inverse (a fixed point); at the apex, or on a level dome, nothing moves."""
    dome = DomedContacts(
        {"kx_per_mm": 0.013, "ky_per_mm": 0.0043}, 2.0, [0.4, 0.4], 20.0, (240, 320)
    )
    axis = np.array([159.5 - 100.0, 119.5 + 60.0])  # 5 mm left of the apex, 3 mm below it
    seen = dome.contact_centre(axis, 0.4)
    assert seen[0] - axis[0] > 1.0 and seen[1] - axis[1] < -0.2  # toward the apex, by pixels
    back = dome.to_axis([Contact(*seen, 20.0, 10.0), None])
    assert back[1] is None
    assert np.hypot(back[0].x_px - axis[0], back[0].y_px - axis[1]) < 0.01
    np.testing.assert_allclose(dome.contact_centre((159.5, 119.5), 0.4), (159.5, 119.5), atol=1e-6)
    level = DomedContacts({"kx_per_mm": 0.0, "ky_per_mm": 0.0}, 2.0, [0.4], 20.0, (240, 320))
    np.testing.assert_allclose(level.contact_centre(axis, 0.4), axis, atol=1e-6)


def test_an_elastic_contacts_pressure_leans_toward_the_apex_and_vanishes_at_it():
    """The pressure model (an elastic layer of the DIGIT's constants, interpolated over a lattice
    of axes): left of and below the apex the pressure's centroid lies toward it, by more than the
    rigid overlap's area centroid there (the pressure gathers where the ball presses deepest);
    at the apex it stays on the axis."""
    from threedcal.profiles import load_profile
    from threedcal.sim.layer_kernel import GelMaterial

    gel = load_profile("sensor", "digit")["gel"]
    dome = DomedContacts(
        gel["dome"], 2.0, [0.4], 20.0, (240, 320), material=GelMaterial.from_profile(gel)
    )
    assert dome.elastic
    axis = np.array([159.5 - 100.0, 119.5 + 60.0])
    pressure = dome.contact_centre(axis, 0.4, "pressure") - axis
    area = dome.contact_centre(axis, 0.4, "area") - axis
    assert pressure[0] > area[0] > 1.0 and pressure[1] < -0.2
    np.testing.assert_allclose(
        dome.contact_centre((159.5, 119.5), 0.4, "pressure"), (159.5, 119.5), atol=0.02
    )


class _CircleThroughPoints:
    """Least squares with a known zero-residual answer: a circle (centre, radius) through points."""

    def __init__(self, centre, radius, n=40):
        angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
        self.points = np.column_stack(
            [centre[0] + radius * np.cos(angles), centre[1] + radius * np.sin(angles)]
        )
        self.evaluations = 0

    def normal_equations(self, params):
        self.evaluations += 1
        d = self.points - params[:2]
        distance = np.hypot(d[:, 0], d[:, 1])
        r = distance - params[2]
        jacobian = np.column_stack([-d[:, 0] / distance, -d[:, 1] / distance, -np.ones(len(r))])
        return float(r @ r), jacobian.T @ r, jacobian.T @ jacobian


def test_mirror_axes_fix_a_centre_in_2d_only_when_they_are_not_one_line():
    # two equally usable axes at right angles fix both directions alike
    spread, _ = _axes_information(np.radians([0.0, 90.0]), [0.5, 0.5])
    assert spread == pytest.approx(1.0)
    # facing LEDs (the Mini's red and green) share one line: nothing fixes the centre along it;
    # what they fix is across it (an axis along x fixes y)
    spread, across = _axes_information(np.radians([183.0, 3.0]), [0.4, 0.4])
    assert spread == pytest.approx(0.0, abs=1e-12)
    assert abs(across[1]) == pytest.approx(np.cos(np.radians(3.0)))
    # a third axis that is barely usable adds little: its share against theirs
    spread, _ = _axes_information(np.radians([180.0, 0.0, 90.0]), [0.4, 0.4, 0.08])
    assert spread == pytest.approx(0.08 / 0.8)
    assert _axes_information(np.radians([0.0, 90.0]), [0.0, 0.0])[0] == 0.0


def test_a_fit_far_less_symmetric_than_the_sets_is_an_outlier():
    costs = np.array([0.5, 0.6, 0.7, 1.2, 2.9, 3.1, 14.0])
    np.testing.assert_array_equal(_symmetric_outliers(costs), costs > 5 * 1.2)
    assert not _symmetric_outliers([1.0, 50.0]).any()  # two fits have no typical one


def test_levenberg_marquardt_reaches_a_known_minimum():
    problem = _CircleThroughPoints((3.2, -1.7), 5.0)
    x, converged, _ = _levenberg_marquardt(
        problem, np.array([0.0, 0.0, 1.0]), np.ones(3), tolerance=1e-9
    )
    assert converged
    np.testing.assert_allclose(x, [3.2, -1.7, 5.0], atol=1e-9)
    assert problem.evaluations < 30
    # A start far off (radius 100x, centre outside the circle) still lands: the damping holds
    # the steps where Gauss-Newton alone would overshoot.
    x, converged, _ = _levenberg_marquardt(
        problem, np.array([40.0, 30.0, 500.0]), np.ones(3), tolerance=1e-9
    )
    assert converged
    np.testing.assert_allclose(x, [3.2, -1.7, 5.0], atol=1e-9)


def test_levenberg_marquardt_reports_a_non_finite_problem():
    class Broken(_CircleThroughPoints):
        def normal_equations(self, params):
            cost, gradient, normal = super().normal_equations(params)
            return float("nan"), gradient, normal

    x, converged, _ = _levenberg_marquardt(
        Broken((0, 0), 1.0), np.array([0.1, 0.2, 1.5]), np.ones(3), tolerance=1e-6
    )
    assert not converged
    np.testing.assert_array_equal(x, [0.1, 0.2, 1.5])


# ---------------------------------------------------------------- first-contact search


def onset_series(
    delta, alphas=(12.0, 9.0, 15.0), step=0.02, uncertainty=0.2, beyond=0.1, exponent=1.0
):
    """Steps of a search at each place with signal α (c + δ)^p once c + δ > 0 (a detection floor
    of 0.01 at p = 1)."""
    c = np.round(-uncertainty + step * np.arange(int((2 * uncertainty + beyond) / step) + 1), 6)
    depth, place, area = [], [], []
    for p, alpha in enumerate(alphas):
        a = alpha * np.clip(c + delta, 0.0, None) ** exponent
        depth.append(c)
        place.append(np.full(c.shape, p))
        area.append(np.where(a > 0.01**exponent, a, 0.0))
    area = np.concatenate(area)
    return np.concatenate(depth), np.concatenate(place), area, area > 0


@pytest.mark.parametrize("delta", [-0.19, -0.0374, 0.0, 0.0831, 0.17])
def test_touch_onset_is_where_the_contact_area_line_meets_zero(delta):
    depth, place, area, touching = onset_series(delta)
    result = fit_touch_onset(depth, place, area, touching, span_mm=0.1)
    assert result.offset_mm == pytest.approx(delta, abs=1e-9)
    np.testing.assert_allclose(result.place_offsets_mm, delta, atol=1e-9)
    assert np.all(result.steps_fitted >= 5)  # 0.1 mm past the onset at 0.02 mm steps
    # the onset step is the first with contact: within one step below -δ
    assert np.all(
        (result.onset_depth_mm > -delta) & (result.onset_depth_mm <= -delta + 0.02 + 1e-9)
    )


@pytest.mark.parametrize("exponent", [1.5, 2.0, 2.5])
@pytest.mark.parametrize("delta", [-0.0374, 0.0831])
def test_touch_onset_measures_how_the_signal_grows(delta, exponent):
    """Signal α (c + δ)^p: p is found from the steps (an elastic gel's about 1.5, a rigid cap's 2)
    and δ where the line through signal^(1/p) meets zero. Fitted as a straight line instead (p = 1),
    the same steps put δ 10 to 35 micrometres off."""
    depth, place, signal, touching = onset_series(delta, exponent=exponent)
    result = fit_touch_onset(depth, place, signal, touching, span_mm=0.1)
    assert result.exponent == pytest.approx(exponent, abs=1e-9)
    assert result.offset_mm == pytest.approx(delta, abs=1e-9)
    straight = fit_touch_onset(depth, place, signal, touching, span_mm=0.1, exponent=1.0)
    assert abs(straight.offset_mm - delta) > 0.008


def test_touch_onset_takes_the_median_over_places():
    depth, place, area, touching = onset_series(0.05)
    area[place == 1] *= 1.3  # a place that reads every signal 30 % large still meets zero there
    area[(place == 2) & touching] += 0.5  # one whose signals carry a constant offset is off...
    result = fit_touch_onset(depth, place, area, touching, span_mm=0.1, exponent=1.0)
    assert result.place_offsets_mm[2] > 0.05 + 0.02
    assert result.offset_mm == pytest.approx(0.05, abs=1e-9)  # ...and outvoted


@pytest.mark.parametrize(
    "change, message",
    [
        ("early", "contact already at the first step .* probing.touch_uncertainty_mm"),
        ("late", "no contact even at the last step"),
        ("short", "at least 3 are needed"),
    ],
)
def test_a_search_that_misses_the_onset_says_which_setting_to_change(change, message):
    delta = {"early": 0.25, "late": -0.32, "short": -0.19}[change]
    depth, place, area, touching = onset_series(delta, beyond=0.1 if change != "short" else 0.02)
    with pytest.raises(RegistrationError, match=message):
        fit_touch_onset(depth, place, area, touching, span_mm=0.1 if change != "short" else 0.02)


@pytest.fixture(scope="module")
def mini_sim():
    sim = GelSimulator(load_profile("sensor", "gelsight_mini"), seed=2)
    blanks = np.stack([sim.blank(frame_index=100 + i) for i in range(10)])
    return sim, blanks


def test_change_detector_sees_no_contact_in_blank_frames(mini_sim):
    sim, blanks = mini_sim
    detector = ChangeDetector.from_blanks(blanks, smooth_px=1.0)
    assert detector.threshold >= stats.chi2.isf(1e-6, 3)
    for k in range(5):  # other noise, another exposure (the simulator's 1 % flicker)
        assert detector.significance(sim.blank(frame_index=500 + k)).max() <= detector.threshold


def shallow_search(sim, blanks, delta=-0.03, centre=(120.3, 159.6)):
    """measure_touch_search on one place of 0.01 mm steps rendered by `sim` (commanded c, true
    depth c + δ)."""
    c = np.round(np.arange(-0.1, 0.2501, 0.01), 4)
    frames = [
        sim.render(Sphere(2.0), centre, 0.0, max(d + delta, 0.0), frame_index=20 + i)
        for i, d in enumerate(c)
    ]
    centres = np.tile(centre, (len(c), 1))
    return measure_touch_search(
        frames,
        blanks,
        c,
        np.zeros(len(c), int),
        centres,
        sim.px_per_mm,
        2.0,
        span_mm=TOUCH_FIT_SPAN_MM,
    )


def test_touch_signal_is_the_same_through_a_sharp_and_a_blurred_camera(mini_sim):
    """The contact signal projects each step's change on the deepest steps': linear in the image, so
    a 6 px camera blur changes neither where it grows from nor how (a contact's half-peak size,
    which the search used before, is mostly blur there). Both find δ within 0.01 mm."""
    sim, blanks = mini_sim
    results = []
    for blur in (0.8, 6.0):
        profile = copy.deepcopy(sim.profile)
        profile["optics"]["blur_sigma_px"] = blur
        gel = GelSimulator(profile, seed=2)
        blank = np.stack([gel.blank(frame_index=100 + i) for i in range(10)])
        results.append(shallow_search(gel, blank))
    for result in results:
        assert result.offset_mm == pytest.approx(-0.03, abs=0.01), result
    sharp, blurred = results
    assert sharp.exponent == pytest.approx(blurred.exponent, abs=0.2)
    assert blurred.onset_depth_mm[0] - sharp.onset_depth_mm[0] <= 0.02 + 1e-9


def test_contacts_are_modelled_as_elastic_where_the_gel_is(caplog):
    """A simulated bench's contacts are elastic when it renders the elastic gel; a real gel's always,
    unless its profile lacks the constants (then the rim alone, with a warning naming them)."""
    digit = load_profile("sensor", "digit")
    assert contact_material(digit, simulated=True, bench_gel_mechanics=None) is None  # geometric
    elastic = contact_material(digit, simulated=True, bench_gel_mechanics="elastic")
    assert elastic.youngs_modulus_mpa == digit["gel"]["youngs_modulus_mpa"]
    assert contact_material(digit, simulated=False, bench_gel_mechanics=None) == elastic
    bare = {**digit, "gel": {k: v for k, v in digit["gel"].items() if k != "poisson_ratio"}}
    with caplog.at_level("WARNING"):
        assert contact_material(bare, simulated=False, bench_gel_mechanics=None) is None
    assert "gel.poisson_ratio" in caplog.text


@pytest.mark.parametrize("size", [1, 2, 7, 240 * 320])
def test_the_contact_medians_are_numpys_to_the_bit_with_ties_and_nan(size):
    """find_contact's one-partition median stands in for np.median: the same float every time."""
    rng = np.random.default_rng(size)
    values = rng.normal(0, 3, size).astype(np.float32)
    cases = [values, np.round(values), values.reshape(-1, 1), values.astype(np.float64)]
    cases.append(np.arange(size))  # integers: np.median itself
    if size > 1:
        cases.append(np.where(np.arange(size) == size - 1, np.nan, values).astype(np.float32))
    for case in cases:
        expected = float(np.median(case))
        assert _median(case) == expected or (math.isnan(expected) and math.isnan(_median(case)))


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_the_colour_change_magnitude_is_the_euclidean_norm_over_channels(channels):
    rng = np.random.default_rng(channels)
    frame = rng.integers(0, 256, (9, 11, channels), dtype=np.uint8)
    blank = rng.integers(0, 256, (9, 11, channels), dtype=np.uint8)
    diff = frame.astype(np.float32) - blank.astype(np.float32)
    expected = np.sqrt((diff * diff).sum(axis=-1))
    np.testing.assert_array_equal(difference_magnitude(frame, blank, blur_px=0), expected)
    gray = difference_magnitude(frame[..., 0], blank[..., 0], blur_px=0)
    np.testing.assert_array_equal(gray, np.abs(diff[..., 0]))
