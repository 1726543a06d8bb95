"""Depth → points in the sensor's and the printer's frame: exact geometry, a sphere pressed on the
bench at a known printer position coming back there, the CLI's PLY, and what is refused."""

import json

import cv2
import numpy as np
import pytest
import trimesh
from conftest import (
    bench_scene,
    collect_and_register,
    lens_free,
    shared_across_workers,
    write_untrained_model,
)
from scipy.optimize import least_squares

from threedcal.cli import main
from threedcal.dataset.labels import local_dome, sphere_depth, sphere_gradients
from threedcal.dataset.trainset import TrainingSet
from threedcal.depth import integrate
from threedcal.errors import ConfigError
from threedcal.model.checkpoint import (
    CheckpointError,
    read_checkpoint,
    save_checkpoint,
)
from threedcal.model.inference import DepthEstimator
from threedcal.model.points import (
    CONTACT_RGB,
    PointCloud,
    Registration,
    SensorGeometry,
    contact_mask,
    write_ply,
)
from threedcal.profiles import load_profile
from threedcal.sim.bench import SimBench, plan_centre_printer_mm

RADIUS = 2.0
DOME = {"kx_per_mm": 0.013, "ky_per_mm": 0.0043, "apex_x_mm": 0.4, "apex_y_mm": -0.3}


def similarity(scale_px_per_mm, turn_deg, shift_px):
    """A printer → pixel affine of a seated sensor: turned, Y flipped (printer +Y runs up the image)."""
    t = np.radians(turn_deg)
    linear = scale_px_per_mm * np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    return np.column_stack([linear @ np.diag([1.0, -1.0]), shift_px])


def fit_sphere(points, radius=RADIUS):
    """Least-squares centre of a sphere of known radius through `points`; and each one's residual."""
    start = points.mean(axis=0) + [0.0, 0.0, radius]
    centre = least_squares(lambda c: np.linalg.norm(points - c, axis=1) - radius, start).x
    return centre, np.linalg.norm(points - centre, axis=1) - radius


@pytest.mark.parametrize("dome", [None, DOME], ids=["flat", "domed"])
@pytest.mark.parametrize("downscale", [1, 2])
def test_an_exact_cap_lies_on_its_sphere_in_both_frames(dome, downscale):
    """A sphere's exact imprint (odd frame sizes, a turned affine, pooled model frames): every
    contact point lies on the sphere to 1e-9 mm, centred where the printer put it (sensor frame:
    over the press pixel, its bottom d below the gel's undeformed surface there)."""
    shape, px = (41, 37), 10.0
    X, Y, depth = 3.0, 24.0, 0.8  # printer mm; the ball's bottom `depth` below the gel
    centre_px = (15.3, 22.6)  # where the model's frame sees it
    camera = (np.array(centre_px) + 0.5) * downscale - 0.5
    linear = similarity(px * downscale, 7.0, (0.0, 0.0))[:, :2]
    affine = np.column_stack([linear, camera - linear @ [X, Y]])
    registration = Registration(affine, contact_z_mm=120.0)
    geometry = SensorGeometry(shape, px, dome, registration, downscale)
    local = local_dome(dome, centre_px, shape, px)
    depth_map = sphere_depth(shape, centre_px, RADIUS, depth, px, local)
    depth_map[depth_map < 0] = 0.0  # the gel outside the contact stays where it was
    contact = contact_mask(depth_map, 1e-6)
    assert contact.sum() > 100

    sag = geometry.sag_mm().reshape(-1)
    axis = np.array([(c - (n - 1) / 2) / px for c, n in zip(centre_px, shape[::-1], strict=True)])
    ax, ay = (dome or {}).get("apex_x_mm", 0.0), (dome or {}).get("apex_y_mm", 0.0)
    sag_axis = 0.0 if dome is None else dome["kx_per_mm"] * (axis[0] - ax) ** 2
    sag_axis += 0.0 if dome is None else dome["ky_per_mm"] * (axis[1] - ay) ** 2
    sensor = geometry.points(depth_map, "sensor")
    centre = [*axis, sag_axis + depth - RADIUS]
    on_sphere = np.linalg.norm(sensor[contact] - centre, axis=1) - RADIUS
    assert np.abs(on_sphere).max() < 1e-9
    np.testing.assert_allclose(sensor[~contact, 2], sag[~contact], atol=1e-12)  # the rest plane

    printer = geometry.points(depth_map, "printer")
    bottom_z = registration.contact_z_mm - sag_axis - depth
    on_sphere = np.linalg.norm(printer[contact] - [X, Y, bottom_z + RADIUS], axis=1) - RADIUS
    assert np.abs(on_sphere).max() < 1e-9


def test_sensor_frame_axes_and_origin_follow_the_image():
    """x along columns (right), y along rows (down), origin under the centre pixel, z into the gel."""
    geometry = SensorGeometry((3, 5), px_per_mm=2.0)
    depth = np.zeros((3, 5))
    depth[0, 4] = 0.5
    points = geometry.points(depth).reshape(3, 5, 3)
    np.testing.assert_allclose(points[1, 2], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(points[0, 4], [1.0, -0.5, 0.5])
    np.testing.assert_allclose(points[2, 0], [-1.0, 0.5, 0.0])


def test_nan_depth_is_no_contact_and_no_ply_point(tmp_path):
    geometry = SensorGeometry((4, 6), px_per_mm=5.0)
    depth = np.zeros((4, 6))
    depth[1, 2], depth[2, 3] = np.nan, 0.3
    cloud = PointCloud(geometry.points(depth), contact_mask(depth))
    assert cloud.contact.tolist().count(True) == 1 and cloud.contact[2 * 6 + 3]
    assert np.isnan(cloud.points[1 * 6 + 2, 2])
    write_ply(tmp_path / "c.ply", cloud)
    loaded = trimesh.load(tmp_path / "c.ply")
    assert len(loaded.vertices) == 23  # the NaN pixel left out
    orange = np.all(loaded.colors[:, :3] == CONTACT_RGB, axis=1)
    assert orange.sum() == 1
    np.testing.assert_allclose(loaded.vertices[orange][0], cloud.points[2 * 6 + 3], atol=1e-6)
    with pytest.raises(ConfigError, match="no finite point"):
        write_ply(tmp_path / "nan.ply", PointCloud(np.full((2, 3), np.nan), np.zeros(2, bool)))
    assert not (tmp_path / "nan.ply").exists()


def test_bad_frames_and_registrations_are_named():
    geometry = SensorGeometry((4, 6), px_per_mm=5.0)
    with pytest.raises(ConfigError, match="frame_of 'camera' is not allowed"):
        geometry.points(np.zeros((4, 6)), "camera")
    with pytest.raises(ConfigError, match=r"depth map of \(6, 4\)"):
        geometry.points(np.zeros((6, 4)))
    with pytest.raises(ConfigError, match="registration.json"):
        geometry.points(np.zeros((4, 6)), "printer")
    with pytest.raises(ConfigError, match="reg: affine_px_per_mm is singular"):
        Registration.from_record(
            {"affine_px_per_mm": [[1, 0, 0], [2, 0, 0]], "contact_z_mm": 1}, "reg"
        )
    with pytest.raises(ConfigError, match="reg: needs affine_px_per_mm"):
        Registration.from_record({"affine_px_per_mm": [[1, 0, 0], [0, 1, 0]]}, "reg")
    with pytest.raises(ConfigError, match="contact threshold"):
        contact_mask(np.zeros(3), float("nan"))


# ---------------------------------------------------------------------------- the bench
PLAN = {"spacing_mm": 2.0, "depth_mm": 1.0, "frames": 1}
SEED = 3


@pytest.fixture(scope="module")
def bench_model(tmp_path_factory):
    """A DIGIT calibrated on the bench (2 mm grid, 1 mm presses) and a `lookup` model trained on it
    (the classic calibration: seconds, and good at the presses it saw), built once for both
    workers: (folder, model.pt)."""

    def build(folder):
        from threedcal.model.train import train
        from threedcal.model.train_settings import TrainSettings

        collect_and_register(folder, lens_free("digit"), PLAN, SEED)
        settings = TrainSettings.of(preset="lookup", epochs_base=1, torch_threads=2)
        train(TrainingSet.load(folder / "ts"), folder / "model", 80, settings, progress=False)

    folder, _ = shared_across_workers(tmp_path_factory, "bench_points_model", build)
    return folder, folder / "model" / "model.pt"


def bench_press(x_offset_mm, y_offset_mm, depth_mm):
    """A sphere pressed on the bench `depth_mm` into the gel, its axis at the plan centre plus the
    offsets: (frame, true ball centre in printer mm, true pixel centre, true depth)."""
    scene = bench_scene(lens_free("digit"), PLAN, SEED)
    sensor = load_profile("sensor", scene["sensor"])
    with SimBench(sensor, RADIUS, scene["bench"], scene["seed"]) as bench:
        cx, cy = plan_centre_printer_mm(sensor)
        x, y = cx + x_offset_mm, cy + y_offset_mm
        centre_px = bench.pose_px(x, y)
        z = bench._z_touch - float(bench.gel.sag_mm(*bench.gel.axis_mm(centre_px))) - depth_mm
        true_depth = bench.penetration_mm(centre_px, z)
        frame = bench.gel.render(bench.ball, centre_px, 0.0, true_depth, frame_index=7)
    return frame, np.array([x, y, z + RADIUS]), centre_px, true_depth, sensor


@pytest.mark.slow  # builds bench_model: a calibration on the bench and a lookup model (10-20 s)
def test_training_records_the_registration_and_the_dome(bench_model):
    folder, model = bench_model
    checkpoint = read_checkpoint(model)
    registration = json.loads((folder / "reg.json").read_text())
    assert checkpoint["registration"]["affine_px_per_mm"] == registration["affine_px_per_mm"]
    assert checkpoint["registration"]["contact_z_mm"] == registration["contact_z_mm"]
    assert checkpoint["dome"] == load_profile("sensor", "digit")["gel"]["dome"]


@pytest.mark.parametrize("offset", [(0.0, 0.0), (2.5, -3.0), (-3.3, 4.1)])
def test_exact_gradients_of_a_bench_press_come_back_on_the_sphere_where_the_printer_put_it(
    bench_model, offset
):
    """The geometry path: the press's exact gradients (labels at the true pose), integrated and
    placed through the model's checkpoint (the fitted registration and touch height): the sphere
    fitted to the contact points lies within 0.1 mm of the printer's ball in X, Y and 20 µm in Z,
    and every contact point within 20 µm of that sphere (measured: 6-17 µm, 4-5 µm, 3.3 µm at
    most; python -m diagnostics.point_frames)."""
    _, model = bench_model
    estimator = DepthEstimator.from_checkpoint(model, device="cpu")
    _, ball, centre_px, depth, sensor = bench_press(*offset, 1.0)
    px = float(sensor["px_per_mm"])  # the bench's true scale (the fitted one differs)
    dome = local_dome(sensor["gel"]["dome"], centre_px, estimator.image_shape, px)
    labels = sphere_gradients(estimator.image_shape, centre_px, RADIUS, depth, px, None, dome)
    depth_map = integrate(labels[..., 0], labels[..., 1], px_per_mm=estimator.px_per_mm)
    cloud = estimator.points_of_depth(depth_map, "printer")
    centre, residual = fit_sphere(cloud.points[cloud.contact])
    assert np.hypot(*(centre - ball)[:2]) < 0.1
    assert abs(centre[2] - ball[2]) < 0.02
    assert np.abs(residual).max() < 0.02


def test_a_trained_models_points_of_a_bench_press_come_back_at_the_printers_ball(bench_model):
    """The model path, the same press through `points` (the bench's `lookup` model): the fitted
    sphere's centre within 0.1 mm in X, Y and 30 µm in Z, the points within 30 µm RMS of it (looser
    than the geometry: the model's own error; measured 10-27 µm, 2-5 µm and 17-20 µm RMS; a third
    press, 5.3 mm from the centre, 34 µm, 29 µm and 24 µm)."""
    _, model = bench_model
    estimator = DepthEstimator.from_checkpoint(model, device="cpu")
    for offset in [(0.0, 0.0), (2.5, -3.0)]:
        frame, ball, *_ = bench_press(*offset, 1.0)
        cloud = estimator.points(frame, "printer")
        centre, residual = fit_sphere(cloud.points[cloud.contact])
        assert np.hypot(*(centre - ball)[:2]) < 0.1, offset
        assert abs(centre[2] - ball[2]) < 0.03, offset
        assert np.sqrt(np.mean(residual**2)) < 0.03, offset


def test_predict_writes_the_points_a_user_opens_in_trimesh(tmp_path, bench_model, capsys):
    folder, model = bench_model
    frame, ball, *_ = bench_press(0.0, 0.0, 1.0)

    cv2.imwrite(str(tmp_path / "press.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    args = ["predict", "--checkpoint", str(model), "--image", str(tmp_path / "press.png")]
    args += ["--out", str(tmp_path / "d.npy"), "--device", "cpu"]
    assert main([*args, "--points", str(tmp_path / "p.ply"), "--frame-of", "printer"]) == 0
    loaded = trimesh.load(tmp_path / "p.ply")
    assert len(loaded.vertices) == frame.shape[0] * frame.shape[1]
    contact = np.all(loaded.colors[:, :3] == CONTACT_RGB, axis=1)
    centre, _ = fit_sphere(np.asarray(loaded.vertices[contact], float))
    assert np.hypot(*(centre - ball)[:2]) < 0.1  # printer mm, as written (float32)
    assert "in contact" in capsys.readouterr().out
    # never replaced silently; a wrong suffix is refused before anything runs
    before = (tmp_path / "p.ply").read_bytes()
    for name in ("d.npy", "d.png"):
        (tmp_path / name).unlink()
    assert main([*args, "--points", str(tmp_path / "p.ply")]) == 1
    assert "p.ply: already exists" in capsys.readouterr().err
    assert (tmp_path / "p.ply").read_bytes() == before and not (tmp_path / "d.npy").exists()
    assert main([*args, "--points", str(tmp_path / "p.xyz")]) == 1
    assert "end it in .ply" in capsys.readouterr().err


def test_a_checkpoint_without_registration_names_what_to_pass(tmp_path, capsys, bench_model):
    """Checkpoints trained before the registration was recorded: the sensor frame works, the
    printer frame is a clear error before anything is written, and --registration fixes it."""
    folder, model = bench_model
    checkpoint = read_checkpoint(model)
    del checkpoint["registration"]
    save_checkpoint(tmp_path / "old.pt", checkpoint)
    estimator = DepthEstimator.from_checkpoint(tmp_path / "old.pt", device="cpu")
    frame = bench_press(0.0, 0.0, 1.0)[0]
    assert estimator.points(frame).points.shape == (frame.shape[0] * frame.shape[1], 3)
    with pytest.raises(ConfigError, match="registration"):
        estimator.points(frame, "printer")

    cv2.imwrite(str(tmp_path / "f.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    args = ["predict", "--checkpoint", str(tmp_path / "old.pt"), "--image", str(tmp_path / "f.png")]
    args += ["--out", str(tmp_path / "d.npy"), "--points", str(tmp_path / "p.ply")]
    assert main([*args, "--frame-of", "printer"]) == 1
    assert "carries none" in capsys.readouterr().err
    assert not (tmp_path / "d.npy").exists() and not (tmp_path / "p.ply").exists()
    assert main([*args, "--frame-of", "printer", "--registration", str(folder / "reg.json")]) == 0
    given = DepthEstimator.from_checkpoint(
        tmp_path / "old.pt", device="cpu", registration=folder / "reg.json"
    )
    np.testing.assert_allclose(
        given.points(frame, "printer").points,
        DepthEstimator.from_checkpoint(model, device="cpu").points(frame, "printer").points,
    )
    (tmp_path / "bad.json").write_text("[1, 2]")
    with pytest.raises(ConfigError, match="bad.json: a registration is a JSON object"):
        DepthEstimator.from_checkpoint(model, registration=tmp_path / "bad.json")


def test_a_damaged_registration_in_a_checkpoint_is_refused_on_load(tmp_path):
    damaged = {"affine_px_per_mm": [[1, 0]], "contact_z_mm": 3.0}
    blank = np.full((8, 8, 3), 100.0)
    write_untrained_model(tmp_path / "m.pt", "compact_tiny", blank, registration=damaged)
    with pytest.raises(
        CheckpointError, match="m.pt: 'registration': affine_px_per_mm must be a fin"
    ):
        read_checkpoint(tmp_path / "m.pt")
