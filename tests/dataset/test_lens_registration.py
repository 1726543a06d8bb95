"""Registration with the camera's lens: the fit itself, the simulated camera, and the dataset stage
that rectifies frames through the fitted lens."""

import copy
import json

import numpy as np
import pytest
from conftest import bench_scene, collect_and_register, elastic_gel, shared_across_workers

from threedcal.collect.store_read import open_checked
from threedcal.dataset.build import build_collected
from threedcal.dataset.camera_fit import MIN_LENS_CONTACTS, fit_affine, fit_camera, fit_lensed
from threedcal.dataset.contacts import locate_contact
from threedcal.dataset.dome_contacts import DomedContacts
from threedcal.dataset.symmetry import refine_by_symmetry
from threedcal.dataset.trainset import TrainingSet
from threedcal.errors import RegistrationError
from threedcal.lens import RadialLens
from threedcal.profiles import load_profile
from threedcal.sim.bench import BenchTruth, draw_lens
from threedcal.sim.camera import LensedGel
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator
from threedcal.study.scene import dataset_settings

SHAPE = (240, 320)


# a 3 mm grid and the default scenes' registration presses (a 1 mm lattice 0.4 mm deep)
REGISTRATION_PRESSES_PLAN = {
    "spacing_mm": 3.0,
    "depth_mm": 1.0,
    "frames": 1,
    "registration": {"spacing_mm": 1.0, "depth_mm": 0.4, "frames": 1},
}


def test_fit_lensed_recovers_an_exact_lens_and_affine_that_an_affine_cannot():
    lens = RadialLens(centre_px=(161.7, 118.2), kappa1=-8e-7, shape=SHAPE)
    affine = np.array([[15.6, 0.4, -1700.0], [0.5, -15.7, 1990.0]])
    gx, gy = np.meshgrid(np.linspace(100, 117, 18), np.linspace(114, 126, 13))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    camera = lens.distort(xy @ affine[:, :2].T + affine[:, 2])
    fit = fit_lensed(xy, camera, SHAPE)
    np.testing.assert_allclose(fit.matrix, affine, rtol=1e-7, atol=1e-5)
    np.testing.assert_allclose(fit.lens.centre_px, lens.centre_px, atol=1e-4)
    assert fit.lens.kappa1 == pytest.approx(lens.kappa1, rel=1e-6)
    assert fit.residual_px < 1e-6
    assert fit_affine(xy, camera).residual_px > 0.5  # the lens is not an affine


def test_a_free_k2_fits_a_locators_edge_bias_and_bends_it_into_the_band_without_contacts():
    """Why the stage fits κ₁ alone: contacts lie 45 px or more inside the frame, and the outermost
    ones are located up to 0.2 px inward (the Mini with its skin: -0.24 px on average beyond 120 px
    from the lens's centre, -0.05 px nearer it; docs/explanation/registration.md, The lens). κ₂ follows them
    more closely (a smaller residual) and carries that on into the outer band: over the whole frame
    it is far off where κ₁ alone stays within a few tenths of a pixel."""
    lens = RadialLens(centre_px=(161.7, 118.2), kappa1=-7e-7, shape=SHAPE)
    affine = np.array([[15.6, 0.4, -1700.0], [0.5, -15.7, 1990.0]])

    def camera(xy):
        return lens.distort(xy @ affine[:, :2].T + affine[:, 2])

    gx, gy = np.meshgrid(np.arange(100.0, 125.0), np.arange(100.0, 125.0))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    px = camera(xy)
    inside = (px >= 45).all(axis=1) & (px[:, 0] <= SHAPE[1] - 46) & (px[:, 1] <= SHAPE[0] - 46)
    xy, px = xy[inside], px[inside]
    outward = px - np.array(lens.centre_px)
    reach = np.hypot(*outward.T)
    located = px - 0.2 * outward / reach[:, None] * (reach / reach.max())[:, None] ** 8
    fx, fy = np.meshgrid(np.arange(96.0, 130.0, 0.25), np.arange(96.0, 130.0, 0.25))
    frame_xy = np.column_stack([fx.ravel(), fy.ravel()])
    truth = camera(frame_xy)
    view = (truth >= 0).all(axis=1) & (truth[:, 0] <= SHAPE[1] - 1) & (truth[:, 1] <= SHAPE[0] - 1)
    fits = {k2: fit_lensed(xy, located, SHAPE, kappa2=k2) for k2 in (False, True)}
    error = {
        k2: np.linalg.norm(fit.apply(frame_xy[view]) - truth[view], axis=1)
        for k2, fit in fits.items()
    }
    assert fits[True].residual_px < fits[False].residual_px
    assert error[False].max() < 0.6 and np.sqrt(np.mean(error[False] ** 2)) < 0.15
    assert error[True].max() > 3 * error[False].max()


def test_lensed_gel_images_a_press_where_the_lens_puts_it_and_darkens_the_corners():
    digit = load_profile("sensor", "digit")
    lens = RadialLens(centre_px=(121.0, 157.5), kappa1=-1.2e-6, shape=(320, 240))
    gel = LensedGel(digit, seed=2, lens=lens)
    ball, ideal = Sphere(2.0), np.array([50.0, 70.0])  # 113 px from the centre: 1.7 px of bend
    frame = gel.render(ball, tuple(ideal), 0.0, 0.5, frame_index=1)
    found = locate_contact(frame, gel.background)
    # the same press without the lens, located by the same rim locator (its own shading bias)
    canvas = gel.inner.render(ball, tuple(ideal + gel.pad), 0.0, 0.5, frame_index=1)
    plain = locate_contact(canvas, gel.inner.background)
    plain_xy = np.array([plain.x_px, plain.y_px]) - gel.pad
    assert np.hypot(*(lens.distort(ideal) - ideal)) > 1.5
    # within what the lens's bend of the contact itself moves its rim (about κ r a², 0.4 px here)
    assert np.hypot(*(lens.distort(plain_xy) - [found.x_px, found.y_px])) < 0.5
    # vignetting: the whole image loses `vignetting` of its light at the corners, none at the centre
    inner = gel.inner.background
    centre = gel._camera(np.ones_like(inner))
    v = digit["lens"]["vignetting"]
    assert centre[159, 119, 0] == pytest.approx(1.0, abs=2e-4)
    assert centre[0, 0, 0] == pytest.approx(1.0 - v, abs=2e-3)


def test_bench_draws_a_lens_apart_from_the_profiles_and_reports_where_it_images():
    digit = load_profile("sensor", "digit")
    nominal = RadialLens.from_profile(digit)
    drawn = [draw_lens(digit, seed) for seed in range(20)]
    assert all(abs(d.kappa1 / nominal.kappa1 - 1) <= 0.2 for d in drawn)
    assert max(abs(d.kappa1 / nominal.kappa1 - 1) for d in drawn) > 0.1
    assert all(np.hypot(*np.subtract(d.centre_px, nominal.centre_px)) <= 3 * 2**0.5 for d in drawn)
    truth = BenchTruth(
        (0.0, 0.0), 0.0, 0.0, [[19.5, 0, -2000], [0, -19.5, 2400]], drawn[0].record()
    )
    xy = np.array([[106.0, 121.0]])
    ideal = xy @ np.array([[19.5, 0], [0, -19.5]]).T + np.array([-2000, 2400])
    np.testing.assert_allclose(truth.camera_px(xy), drawn[0].distort(ideal))


@pytest.fixture(scope="session")
def mini_with_lens(tmp_path_factory):
    """Built once for the run (read-only), whichever workers its two tests land on."""
    plan = {"spacing_mm": 1.0, "depth_mm": 1.0, "frames": 1}
    return shared_across_workers(
        tmp_path_factory,
        "mini_lens",
        lambda folder: collect_and_register(folder, "gelsight_mini", plan, 4),
    )


@pytest.mark.long
def test_registration_fits_the_lens_within_0_3_px_of_the_benchs_over_the_view(mini_with_lens):
    folder, record = mini_with_lens
    truth = json.loads((folder / "truth.json").read_text())["lens"]
    fitted = record["lens"]
    assert fitted is not None and record["contacts_used"] >= 30
    assert record["error_px"] <= 0.3, record
    # κ₁ is the lens's shape; its centre is not pinned by the view: a few px of it trade against
    # the affine's offset (seeds 4 and 5: 5.1 and 4.2 px off at 0.12 and 0.07 px over the view)
    assert fitted["kappa1_per_px2"] == pytest.approx(truth["kappa1_per_px2"], rel=0.15)
    assert np.hypot(*np.subtract(fitted["centre_px"], truth["centre_px"])) < 8.0


@pytest.mark.long
def test_shallow_registration_presses_register_the_digit_within_0_3_px(tmp_path):
    """The DIGIT's grid contacts (1-3 mm deep, up to R across) leave a 45 px band along each edge of
    its 240 px wide frame where no contact lies whole and the lens fit extrapolates (0.35 px in the
    default study). Shallow presses over the whole area reach nearer the edges: the registration
    takes them alone, not the grid's."""
    plan = REGISTRATION_PRESSES_PLAN
    record = collect_and_register(tmp_path, "digit", plan, 5)
    assert record["contacts_from"] == "register" and record["locator"] == "rim"
    # the grid's 3 mm lattice holds ~20 presses in view; the 1 mm registration lattice ~100
    assert record["contacts_used"] >= 60, record
    assert record["error_px"] <= 0.3, record


@pytest.mark.long
def test_the_elastic_mini_with_its_skin_registers_within_0_3_px_with_k1_alone(tmp_path):
    """The skin's shading halo reaches far past the rim. A free κ₂ followed the few outermost
    contacts, located a fraction of a pixel inward, and bent that into the outer band where no
    contact lies (registration presses alone, seeds 11-14: 0.17-0.57 px over the view, up to
    3.8 px); κ₁ alone extrapolates it mildly (docs/explanation/registration.md, The lens)."""
    plan = REGISTRATION_PRESSES_PLAN
    record = collect_and_register(tmp_path, elastic_gel("gelsight_mini"), plan, 11)
    assert record["locator"] == "symmetry" and record["contacts_used"] >= 100, record
    assert record["lens"]["kappa2_per_px4"] == 0.0
    assert record["error_px"] <= 0.3, record


@pytest.mark.long
def test_on_the_elastic_digit_centres_moved_by_the_elastic_pressure_register_within_0_3_px(
    tmp_path, monkeypatch
):
    """On the DIGIT's dome an elastic contact leans toward the apex by up to ~3.5 px. Its symmetric
    centre lies where the elastic layer's pressure is centred: moved from there to the press's
    axis (DomedContacts, the profile's dome and gel constants), the lens and affine register the
    view within 0.3 px. The rigid overlap's centroid, which places a rim on a gel that follows the
    ball, moves them less well."""
    plan = REGISTRATION_PRESSES_PLAN
    record = collect_and_register(tmp_path, elastic_gel("digit"), plan, 11)
    assert record["locator"] == "symmetry", record
    assert record["error_px"] <= 0.3, record
    monkeypatch.setattr(DomedContacts, "_pressure_shift", DomedContacts._area_shift)
    scene = bench_scene(elastic_gel("digit"), plan, 11)
    paths = [tmp_path / f"area_{n}" for n in ("ts", "splits.csv", "reg.json", "reg.png")]
    rigid = build_collected(
        dataset_settings(scene),
        tmp_path / "raw.zarr",
        *paths,
        tmp_path / "truth.json",
        progress=False,
    )
    assert rigid["error_px"] > record["error_px"] + 0.05, rigid


@pytest.mark.long
def test_dataset_frames_are_rectified_so_contacts_sit_at_their_labels(mini_with_lens):
    folder, record = mini_with_lens
    ts = TrainingSet.load(folder / "ts")
    lens = RadialLens.from_record(ts.meta["lens"])
    assert ts.meta["lens"] == record["lens"]
    # the presses farthest from the centre whose contacts lie whole in the frame (50 px margin):
    # rectified, their contacts are where their labels say
    height, width = ts.image_shape
    x, y = ts.center_px.T
    whole = (x > 50) & (x < width - 51) & (y > 50) & (y < height - 51)
    reach = np.where(whole, np.hypot(*(ts.center_px - np.array(lens.centre_px)).T), -1)
    farthest = int(np.argmax(reach))
    rectified = locate_contact(np.asarray(ts.frames[farthest]), ts.blank)
    raw = open_checked(folder / "raw.zarr")
    camera = locate_contact(
        raw["frames"].values[ts.meta["store_frames"][farthest]],
        raw["blank_frames"].values.astype(np.float32).mean(axis=0),
    )
    camera_xy, rectified_xy = [np.array([c.x_px, c.y_px]) for c in (camera, rectified)]
    # the rectified contact is the camera's one taken back through the lens (up to the lens's bend
    # of the contact itself, which rectifying removes)
    assert np.hypot(*(lens.undistort(camera_xy) - rectified_xy)) < 0.35
    # and so, found as the registration found it (the symmetric centre: the rim's own bias reaches
    # 1 px at the Mini's side edges, where its red and green LEDs face each other), the eight
    # farthest whole contacts lie at their labels in the rectified frames and a bend off them in
    # the camera's
    far = np.argsort(-reach)[:8]
    assert (reach[far] > 0).all()
    frames = [np.asarray(ts.frames[i]) for i in far]
    shots = [raw["frames"].values[ts.meta["store_frames"][i]] for i in far]
    camera_blank = raw["blank_frames"].values.astype(np.float32).mean(axis=0)
    rectified = refine_by_symmetry(frames, ts.blank, [locate_contact(f, ts.blank) for f in frames])
    camera = refine_by_symmetry(
        shots, camera_blank, [locate_contact(f, camera_blank) for f in shots]
    )
    for i, here, there in zip(far, rectified.contacts, camera.contacts, strict=True):
        label = ts.center_px[i]
        bend = np.hypot(*(lens.distort(label) - label))
        assert bend > 1.0
        assert np.hypot(here.x_px - label[0], here.y_px - label[1]) < 0.3
        assert np.hypot(there.x_px - label[0], there.y_px - label[1]) > 0.5 * bend


def test_a_distortion_free_lens_keeps_the_frames_constants_hot_spots_field_markers_vignetting():
    """With k1 = k2 = 0 the lens only crops the canvas: the background must equal the plain
    simulator's, so hot spots, the fitted colour field, the LEDs' vignetting and the markers stay
    where the frame has them, not where the wider canvas would put them."""
    profile = copy.deepcopy(load_profile("sensor", "digit_fots"))  # a fitted colour field
    profile["optics"].update(
        texture_dn=0.0,  # drawn per canvas pixel: not comparable
        vignetting=0.3,
        hot_spots=[{"x": 0.2, "y": 0.9, "sigma": 0.05, "amplitude_dn": [20, 5, 5]}],
        markers={"spacing_mm": 1.5, "radius_mm": 0.3, "darkness": 0.5},
    )
    profile["lens"] = {"fov_deg": 60.0, "k1": 0.0, "k2": 0.0, "vignetting": 0.0}
    lensed = LensedGel(profile, seed=1)
    plain = GelSimulator(profile, seed=1)
    assert lensed.pad > 0 and lensed.inner.width == 240 + 2 * lensed.pad
    # the camera blur reaches past the frame's edge on the canvas and replicates the edge without
    # it: compare where it does not reach
    edge = int(np.ceil(4 * plain.blur_sigma)) + 2
    inner = np.s_[edge:-edge, edge:-edge]
    np.testing.assert_allclose(lensed.background[inner], plain.ideal()[inner], atol=2e-3)


PRIOR = RadialLens(centre_px=(159.5, 119.5), kappa1=-7e-7, shape=SHAPE)
TRUE_AFFINE = np.array([[15.6, 0.4, -1700.0], [0.5, -15.7, 1990.0]])


def contacts_of(lens, count, rng=None, noise_px=0.0):
    """`count` contacts spread over the inner frame (printer mm) and where `lens` images them."""
    rng = rng or np.random.default_rng(0)
    xy = np.column_stack([rng.uniform(103, 115, count), rng.uniform(114, 124, count)])
    camera = lens.distort(xy @ TRUE_AFFINE[:, :2].T + TRUE_AFFINE[:, 2])
    return xy, camera + rng.normal(0, noise_px, camera.shape) if noise_px else camera


def test_fit_camera_refits_a_lens_the_profile_gets_wrong_once_the_contacts_pin_it_down():
    truth = RadialLens(centre_px=(162.5, 117.0), kappa1=-8.4e-7, shape=SHAPE)  # κ₁ 20 % off, 3 px
    xy, camera = contacts_of(truth, 60)
    fit = fit_camera(xy, camera, SHAPE, PRIOR)
    assert fit.lens_free == "all" and set(fit.lens_cv_px) == {"none", "kappa1", "all"}
    assert fit.lens_cv_px["all"] < 1e-4 < fit.lens_cv_px["none"]
    np.testing.assert_allclose(fit.matrix, TRUE_AFFINE, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(fit.lens.centre_px, truth.centre_px, atol=1e-3)
    assert fit.lens.kappa1 == pytest.approx(truth.kappa1, rel=1e-5)


def test_fit_camera_keeps_the_profiles_lens_under_the_contacts_that_pin_one_down():
    """Eight contacts located to 0.3 px through the profile's own lens: the profile's lens, and
    the cross-validation is not run for the others."""
    xy, camera = contacts_of(PRIOR, 8, np.random.default_rng(3), noise_px=0.3)
    fit = fit_camera(xy, camera, SHAPE, PRIOR)
    assert fit.lens_free == "none" and fit.lens == PRIOR and set(fit.lens_cv_px) == {"none"}
    ideal = xy @ TRUE_AFFINE[:, :2].T + TRUE_AFFINE[:, 2]
    assert np.abs(fit.ideal(xy) - ideal).max() < 0.5
    # exact contacts of a lens the profile gets wrong: kept under MIN_LENS_CONTACTS, refitted from it
    truth = RadialLens(centre_px=(162.5, 117.0), kappa1=-8.4e-7, shape=SHAPE)
    xy, camera = contacts_of(truth, MIN_LENS_CONTACTS, np.random.default_rng(4))
    below = fit_camera(xy[:-1], camera[:-1], SHAPE, PRIOR)
    assert below.lens_free == "none" and below.lens == PRIOR
    at = fit_camera(xy, camera, SHAPE, PRIOR)
    assert at.lens_free == "all" and at.lens.kappa1 == pytest.approx(truth.kappa1, rel=1e-5)


def test_fit_camera_needs_four_contacts_off_one_line_and_leaves_missing_ones_out():
    xy, camera = contacts_of(PRIOR, 6)
    missing = camera.copy()
    missing[2] = np.nan  # a press whose contact was not whole: no point, never an inlier
    fit = fit_camera(xy, missing, SHAPE, PRIOR)
    assert not fit.inliers[2] and fit.inliers.sum() == 5
    np.testing.assert_allclose(fit.matrix, TRUE_AFFINE, rtol=1e-7, atol=1e-5)
    with pytest.raises(RegistrationError, match=">= 4 contacts"):
        fit_camera(xy[:3], camera[:3], SHAPE, PRIOR)
    line = np.column_stack([np.linspace(103, 115, 8), np.linspace(114, 124, 8)])
    on_line = PRIOR.distort(line @ TRUE_AFFINE[:, :2].T + TRUE_AFFINE[:, 2])
    with pytest.raises(RegistrationError, match="not on one line"):
        fit_camera(line, on_line, SHAPE, PRIOR)
