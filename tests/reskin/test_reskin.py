"""ReSkin: serial parsing and robustness, the simulated skin and board, the cross plan, the readings
store, the localisation MLP and the scene's targets."""

import copy
import math

import numpy as np
import pandas as pd
import pytest
import serial

from threedcal.collect.plan import cross_plan, validate_plan
from threedcal.collect.scene_plan import plan_from_config
from threedcal.collect.store import PointRecord, RawStore, readings_layout
from threedcal.collect.store_read import open_raw
from threedcal.errors import ConfigError
from threedcal.hardware.printer import MarlinHost
from threedcal.hardware.reskin import (
    MalformedReading,
    ReSkinReader,
    ReSkinTimeout,
    field_indices,
    parse_line,
    value_names,
)
from threedcal.model.checkpoint import FORMAT, FORMAT_VERSION, save_checkpoint
from threedcal.profiles import load_profile
from threedcal.reskin.data import ReSkinSet, split_by_coordinate
from threedcal.reskin.evaluate import localisation_errors
from threedcal.reskin.model import ReSkinSettings, predict, read_reskin_model, train_mlp
from threedcal.sim.reskin import (
    MagneticSkin,
    ReSkinBench,
    dipole_field_ut,
    surface_deflection,
)
from threedcal.study.config import validate_config
from threedcal.study.paths import scene_targets

PROFILE = load_profile("sensor", "reskin")
PRINTER = load_profile("printer", "ender3")
N_VALUES = 20


def fast_profile(timeout_s=0.2):
    profile = copy.deepcopy(PROFILE)
    profile["serial"]["timeout_s"] = timeout_s
    return profile


def line(values, sep="\t", end="\r\n") -> bytes:
    return (sep.join(f"{v:.2f}" for v in values) + end).encode()


# ---- parsing and the serial reader -----------------------------------------------------------
def test_profile_names_twenty_values_fifteen_of_them_field():
    names = value_names(PROFILE)
    assert len(names) == N_VALUES and names[:5] == ["bx0", "by0", "bz0", "t0", "bx1"]
    assert len(field_indices(PROFILE)) == 15
    assert [names[i] for i in field_indices(PROFILE)][-3:] == ["bx4", "by4", "bz4"]


def test_parse_good_line():
    values = parse_line(b"1.5\t-2\t3e2\t0.25", 4, "\t")
    assert values.dtype == np.float32
    np.testing.assert_array_equal(values, [1.5, -2.0, 300.0, 0.25])
    np.testing.assert_array_equal(parse_line(b"  1\t2\r", 2, "\t"), [1.0, 2.0])


@pytest.mark.parametrize(
    "raw, message",
    [
        (b"1\t2\t3", "expected 4 numbers separated by '\\t', got 3 field(s)"),
        (b"1,2,3,4", "got 1 field(s)"),
        (b"1\t2\tabc\t4", "value 3 ('abc') is not a finite number"),
        (b"1\t2\tnan\t4", "value 3 ('nan') is not a finite number"),
        (b"1\t2\t\t4", "value 3 ('') is not a finite number"),
        (b"", "got 0 field(s)"),
        (b"\xff\xfe\t1", "not ASCII text"),
    ],
)
def test_malformed_lines_name_the_line(raw, message):
    with pytest.raises(MalformedReading) as exc:
        parse_line(raw, 4, "\t", where="/dev/ttyACM0")
    assert message in str(exc.value) and "/dev/ttyACM0" in str(exc.value)
    if raw.strip() and raw.isascii():
        assert repr(raw.decode().strip()) in str(exc.value)


def loop_reader(timeout_s=0.2):
    port = serial.serial_for_url("loop://", timeout=0.01)
    return port, ReSkinReader(fast_profile(timeout_s), port)


def test_reader_returns_consecutive_lines_and_drops_stale_ones():
    port, reader = loop_reader()
    port.write(line(np.full(N_VALUES, 9.0)) * 3)  # stale: before the press
    reader.flush()
    # After a flush the first line may be a tail cut by the reset: it is dropped, never parsed.
    port.write(b"3.0\tgarbage tail\r\n" + line(np.arange(N_VALUES)) + line(-np.arange(N_VALUES)))
    readings, stamps = reader.capture(2)
    np.testing.assert_array_equal(readings[0], np.arange(N_VALUES))
    np.testing.assert_array_equal(readings[1], -np.arange(N_VALUES))
    assert readings.shape == (2, N_VALUES) and stamps.shape == (2,) and stamps[1] >= stamps[0]


def test_reader_reassembles_lines_split_across_reads_and_skips_blank_lines():
    port, reader = loop_reader()
    data = b"\r\n" + line(np.ones(N_VALUES))
    port.write(data[:7])
    first = port.read(7)  # the reader gets the rest only: as if it arrived in pieces
    port.write(first + data[7:])
    readings, _ = reader.capture(1)
    np.testing.assert_array_equal(readings[0], np.ones(N_VALUES))


def test_reader_raises_on_a_malformed_line():
    port, reader = loop_reader()
    port.write(line(np.ones(N_VALUES)) + b"1.0\t2.0\r\n")
    with pytest.raises(MalformedReading, match=r"malformed line '1.0\\t2.0': expected 20"):
        reader.capture(2)


def test_reader_times_out_naming_the_partial_line():
    port, reader = loop_reader(timeout_s=0.1)
    port.write(b"1.0\t2.0")
    with pytest.raises(
        ReSkinTimeout, match=r"within 0.1 s \(incomplete line so far: b'1.0\\t2.0'\)"
    ):
        reader.capture(1)


def test_reader_refuses_endless_lines(monkeypatch):
    import threedcal.hardware.reskin as reskin

    monkeypatch.setattr(reskin, "MAX_LINE_BYTES", 100)  # loop:// holds 4 kB at most
    port, reader = loop_reader()
    port.write(b"1" * 300)
    with pytest.raises(MalformedReading, match="without a line ending"):
        reader.capture(1)


def test_reader_needs_a_magnetic_profile():
    with pytest.raises(ConfigError, match="needs a magnetic sensor profile"):
        ReSkinReader(load_profile("sensor", "digit"), "loop://")


# ---- the simulated skin ------------------------------------------------------------------------
def test_dipole_field_on_and_beside_the_axis():
    up = np.array([[0.0, 0.0, 1.0]])
    sensors = np.array([[0.0, 0.0, -2.0], [3.0, 0.0, 0.0]])
    field = dipole_field_ut(sensors, np.zeros((1, 3)), up, scale=8.0)
    np.testing.assert_allclose(field[0], [0, 0, 2 * 8.0 / 2**3])  # on the axis: 2m/r³
    np.testing.assert_allclose(field[1], [0, 0, -8.0 / 3**3])  # in the equatorial plane: −m/r³


def test_surface_deflection_is_the_ball_inside_and_continuous_at_the_contact_edge():
    radius, depth = 2.0, 1.0
    a = math.sqrt(radius * depth)
    w, dw = surface_deflection(np.array([0.0, a - 1e-9, a + 1e-9]), depth, radius, decay_mm=1e9)
    assert w[0] == pytest.approx(depth)
    assert w[1] == pytest.approx(w[2], abs=1e-6) and w[1] == pytest.approx(depth / 2)
    assert dw[1] == pytest.approx(dw[2], abs=1e-4) and dw[1] == pytest.approx(-a / radius)
    # Far away, the Boussinesq fall-off 4d/(3πρ).
    far, _ = surface_deflection(np.array([1000 * a]), depth, radius, decay_mm=1e12)
    assert far[0] == pytest.approx(4 * depth / (3 * math.pi * 1000), rel=1e-3)
    none, slope = surface_deflection(np.array([0.0, 1.0]), 0.0, radius, 3.0)
    assert not none.any() and not slope.any()


def test_skin_responds_to_a_press_symmetrically():
    skin = MagneticSkin(PROFILE, probe_radius_mm=2.0)
    rest = skin.field(0.0, 0.0, 0.0)
    np.testing.assert_array_equal(skin.field(3.0, 1.0, -0.5), rest)  # above the skin: nothing
    change = skin.field(0.0, 0.0, 1.0) - rest
    assert abs(change[0, 2]) > 50  # the centre chip, under the ball: tens of µT and more
    np.testing.assert_allclose(change[0, :2], 0, atol=1e-6)  # by symmetry
    np.testing.assert_allclose(change[1, 0], -change[2, 0], rtol=1e-9)  # chips at -x and +x
    deeper = skin.field(0.0, 0.0, 2.0) - rest
    assert abs(deeper[0, 2]) > abs(change[0, 2])


def pressed_readings(seed, xy=(8.0, 8.0), depth=1.5):
    """Home, press at plan (x, y), read 3 lines through the real host and reader code."""
    sensor = PROFILE
    with (
        ReSkinBench(sensor, 2.0, {}, seed) as bench,
        MarlinHost(bench.url, PRINTER) as host,
        ReSkinReader(sensor, bench.sensor_url) as reader,
    ):
        reader.flush()
        rest, _ = reader.capture(3)
        host.home()
        mount = sensor["mount"]
        host.move_to(z=mount["z_touch_mm"] + 1, feed_mm_s=5)
        host.move_to(x=mount["x_offset_mm"] + xy[0], y=mount["y_offset_mm"] + xy[1], feed_mm_s=50)
        host.move_to(z=mount["z_touch_mm"] - depth, feed_mm_s=5)
        host.wait_until_idle()
        reader.flush()
        pressed, stamps = reader.capture(3)
    return rest, pressed, stamps


def test_simulated_board_is_deterministic_and_feels_the_press():
    rest, pressed, stamps = pressed_readings(seed=4)
    rest2, pressed2, stamps2 = pressed_readings(seed=4)
    np.testing.assert_array_equal(pressed, pressed2)
    np.testing.assert_array_equal(stamps, stamps2)
    np.testing.assert_array_equal(rest, rest2)
    np.testing.assert_allclose(np.diff(stamps), 1 / PROFILE["serial"]["rate_hz"], rtol=1e-6)
    bz0 = value_names(PROFILE).index("bz0")
    assert pressed[:, bz0].mean() - rest[:, bz0].mean() > 50
    # Repeated readings differ by noise only (~1-2 µT), temperatures near the profile's 30 °C.
    assert 0 < np.abs(np.diff(rest[:, field_indices(PROFILE)], axis=0)).max() < 15
    t0 = value_names(PROFILE).index("t0")
    assert abs(rest[0, t0] - 30.0) < 1.0
    _, other, _ = pressed_readings(seed=5)
    assert not np.array_equal(other, pressed)


def test_simulated_board_drops_a_line_cut_by_the_flush():
    with (
        ReSkinBench(PROFILE, 2.0, {}, 0) as bench,
        ReSkinReader(PROFILE, bench.sensor_url) as reader,
    ):
        board = bench.board
        # Reset in the middle of a line's transmission: its tail still arrives, and is skipped.
        bench.firmware.clock.advance_to(board._time(5) + 20 * board.byte_s)
        reader.flush()
        assert board._offset == 20
        readings, stamps = reader.capture(2)
        assert stamps[0] == pytest.approx(board._time(6) + len(board.line(6)) * board.byte_s)
        np.testing.assert_array_equal(
            readings[0], parse_line(board.line(6).strip(), N_VALUES, "\t")
        )


# ---- the cross plan ------------------------------------------------------------------------------
def test_cross_plan_has_the_authors_reskin_shape():
    plan = plan_from_config(
        {"pattern": "cross", "spacing_mm": 1.0, "depths_mm": [1.0, 1.5, 2.0], "frames": 10},
        PROFILE,
    )
    assert len(plan) == 567 and (plan.frames == 10).all()
    assert list(plan.depth_mm.unique()) == [1.0, 1.5, 2.0]  # one whole pass per depth, in order
    for _, one in plan.groupby("depth_mm"):
        assert len(one) == 189  # 17 x 17 grid less four 5 x 5 corners
    on_arm = ((plan.x_mm - 8).abs() <= 3) | ((plan.y_mm - 8).abs() <= 3)
    assert on_arm.all()
    validate_plan(plan, PROFILE, PRINTER)


def test_cross_plan_with_zero_width_arms_is_two_lines():
    plan = cross_plan(PROFILE, 2.0, [1.0], 1, arm_width_mm=0.0)
    assert len(plan) == 9 + 9 - 1


# ---- the store with readings -------------------------------------------------------------------
def test_store_round_trip_with_readings(tmp_path):
    plan = pd.DataFrame(
        {"x_mm": [0.0, 1.0], "y_mm": [0.0, 2.0], "depth_mm": [1.0, 1.5], "frames": [4, 2]}
    )
    names = value_names(PROFILE)
    layout = readings_layout(names, plan)
    assert layout.chunk_frames == 2  # chunks never straddle two points
    store = RawStore.create(tmp_path / "raw.zarr", plan, (len(names),), 3, {"seed": 1}, layout)
    store.write_blank(np.full((3, len(names)), -1.5, np.float32))
    for point, count in enumerate(plan.frames):
        values = np.arange(count * len(names), dtype=np.float32).reshape(count, -1) + point / 4
        store.write_point(
            point,
            PointRecord(
                values, (1.0, 2.0, 3.0), (1.0, 2.0, 3.01), np.arange(count), np.ones(count)
            ),
        )
    store.finalize()
    resumed = RawStore.open_for_resume(tmp_path / "raw.zarr", plan)
    assert resumed.variable == "readings" and resumed.first_uncaptured() is None
    data = open_raw(tmp_path / "raw.zarr")
    assert data["readings"].dims == ("frame", "value") and data["readings"].dtype == np.float32
    assert [str(v) for v in data["value"].values] == names
    assert data["blank_readings"].shape == (3, 20) and float(data["blank_readings"][0, 0]) == -1.5
    np.testing.assert_array_equal(data["point"].values, [0, 0, 0, 0, 1, 1])
    np.testing.assert_array_equal(data["depth_mm"].values, [1.0] * 4 + [1.5] * 2)
    assert float(data["readings"][4, 1]) == 1.25
    assert "frames" not in data


# ---- the model ---------------------------------------------------------------------------------------
def synthetic_set(seed=0):
    """Readings that are a smooth invertible function of (x, y, depth), on a 1 mm grid."""
    xs, ys, ds = np.meshgrid(np.arange(6.0), np.arange(6.0), [1.0, 2.0], indexing="ij")
    targets = np.column_stack([xs.ravel(), ys.ravel(), ds.ravel()]).repeat(3, axis=0)
    rng = np.random.default_rng(seed)
    mixing = rng.normal(size=(3, 6)) * 30
    inputs = targets @ mixing + rng.normal(size=(len(targets), 6)) * 0.5
    point = np.arange(len(targets)) // 3
    return ReSkinSet(inputs.astype(np.float32), targets.astype(np.float32), point, [], np.zeros(6))


def test_split_is_by_coordinate_and_seeded():
    data = synthetic_set()
    test = split_by_coordinate(data.targets[:, 0], data.targets[:, 1], 0.25, seed=3)
    keys = [tuple(k) for k in data.targets[:, :2]]
    held = {k for k, t in zip(keys, test, strict=True) if t}
    kept = {k for k, t in zip(keys, test, strict=True) if not t}
    assert not held & kept and len(held) == 9 and len(kept) == 27
    again = split_by_coordinate(data.targets[:, 0], data.targets[:, 1], 0.25, seed=3)
    np.testing.assert_array_equal(test, again)
    other = split_by_coordinate(data.targets[:, 0], data.targets[:, 1], 0.25, seed=4)
    assert not np.array_equal(test, other)
    with pytest.raises(ConfigError, match="test_fraction"):
        split_by_coordinate(data.targets[:, 0], data.targets[:, 1], 1.0, seed=3)


def test_mlp_learns_a_tiny_set_deterministically(tmp_path):
    data = synthetic_set()
    settings = ReSkinSettings(hidden=(32,), epochs=150, batch_size=32, lr=1e-2)
    first, rows = train_mlp(data.inputs, data.targets, settings, seed=2, torch_threads=1)
    second, _ = train_mlp(data.inputs, data.targets, settings, seed=2, torch_threads=1)
    for key, value in first["state_dict"].items():
        assert np.array_equal(value.numpy(), second["state_dict"][key].numpy())
    assert rows[-1]["train_loss"] < rows[0]["train_loss"] / 20
    errors = localisation_errors(predict(first, data.inputs), data.targets)
    assert errors["median_error_mm"] < 0.3 and errors["depth_mae_mm"] < 0.15
    save_checkpoint(tmp_path / "model.pt", first)
    loaded = read_reskin_model(tmp_path / "model.pt")
    np.testing.assert_array_equal(predict(loaded, data.inputs), predict(first, data.inputs))
    with pytest.raises(ConfigError, match="expects \\(N, 6\\) readings"):
        predict(loaded, data.inputs[:, :5])


def test_checkpoint_of_another_kind_is_refused(tmp_path):
    """One checkpoint format for every model: a vision model is no ReSkin model, a ReSkin model
    no vision model, and a foreign file neither."""
    import torch

    from threedcal.model.checkpoint import CheckpointError
    from threedcal.model.inference import DepthEstimator

    torch.save({"kind": "something"}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="neither a threedcal checkpoint"):
        read_reskin_model(tmp_path / "other.pt")
    vision = {"format": FORMAT, "format_version": FORMAT_VERSION, "preset": "compact_tiny"}
    normalisation = {"gradient_sign": 1}
    save_checkpoint(
        tmp_path / "vision.pt", {**vision, "state_dict": {}, "normalisation": normalisation}
    )
    with pytest.raises(ConfigError, match="vision.pt: not a threedcal ReSkin model"):
        read_reskin_model(tmp_path / "vision.pt")
    data = synthetic_set()
    settings = ReSkinSettings(hidden=(8,), epochs=1)
    checkpoint, _ = train_mlp(data.inputs, data.targets, settings, seed=0)
    save_checkpoint(tmp_path / "reskin.pt", checkpoint)
    with pytest.raises(CheckpointError, match="ReSkin model .* takes no images"):
        DepthEstimator.from_checkpoint(
            tmp_path / "reskin.pt", blank=np.zeros((4, 4, 3)), px_per_mm=9
        )
    del checkpoint["normalisation"]["in_std"]
    save_checkpoint(tmp_path / "broken.pt", checkpoint)
    with pytest.raises(
        CheckpointError, match="broken.pt: ReSkin model without normalisation in_std"
    ):
        read_reskin_model(tmp_path / "broken.pt")


def test_localisation_errors_exact():
    truth = np.zeros((4, 3))
    predicted = np.array([[3, 4, 0.5], [0, 1, -0.5], [0, 0, 0], [6, 8, 1.0]], dtype=float)
    errors = localisation_errors(predicted, truth)
    assert errors["median_error_mm"] == pytest.approx(3.0)  # errors 5, 1, 0, 10
    assert errors["p90_error_mm"] == pytest.approx(5 + 0.7 * 5)
    assert errors["depth_mae_mm"] == pytest.approx(0.5)


# ---- scenes ----------------------------------------------------------------------------------------------
def test_reskin_scene_targets_have_no_image_stages():
    config = validate_config({"scenes": {"rs": {"sensor": "reskin", "printer": "ender3"}}})
    targets = scene_targets("rs", config["scenes"]["rs"])
    assert "results/rs/reskin_eval.json" in targets and "results/rs/collect/summary.json" in targets
    assert "results/rs/collect/frames.png" in targets
    assert not any("registration" in t or "models/" in t or "stats/" in t for t in targets)


def test_reskin_scene_refuses_image_analyses():
    bad = {"scenes": {"rs": {"sensor": "reskin", "printer": "ender3", "ablation": [5, 80]}}}
    with pytest.raises(
        ConfigError, match="scenes.rs.ablation: not available for a magnetic sensor"
    ):
        validate_config(bad)


def test_cli_reads_the_simulated_board(capsys):
    from threedcal.cli import main

    assert main(["reskin", "read", "--port", "sim", "--count", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split("\t")[:3] == ["t_s", "bx0", "by0"] and len(lines) == 3
    assert lines[2].split("\t")[0] == "0.020"  # one reading per 1/50 s


def test_real_printer_with_the_simulated_board_is_refused_before_anything_opens(tmp_path):
    from threedcal.study.session import collect_scene

    real = {"scenes": {"rs": {"sensor": "reskin", "printer": "ender3", "port": "/dev/ttyUSB9"}}}
    with pytest.raises(ConfigError, match="set the scene's `reader` to the ReSkin board"):
        validate_config(real)  # the config check names it first
    # and collect refuses it too, for a scene that never went through the check
    scene = {**validate_config({"scenes": {"rs": {**real["scenes"]["rs"], "port": "sim"}}})}
    scene = {**scene["scenes"]["rs"], "port": "/dev/ttyUSB9"}
    with pytest.raises(ConfigError, match="set the scene's `reader` to the ReSkin board"):
        collect_scene("rs", scene, tmp_path / "raw.zarr", progress=False)
    assert not any(tmp_path.iterdir())


def test_hardware_collection_reads_the_board_through_the_real_host_and_reader(
    tmp_path, monkeypatch
):
    # The hardware path (serial printer + ReSkin reader), with both serial ends simulated.
    from conftest import _profile_variant

    from threedcal.collect.store_read import open_raw
    from threedcal.study.session import collect_scene

    # A real rig waits probing.settle_s (0.3 s) at every press, on the wall clock; the simulated
    # printer's time is virtual (instant moves) and the board reads on it, so the wait only took
    # time (14 s of sleep): the profile with a 10 ms settle, its readings the same.
    sensor = _profile_variant("reskin", "settle-10ms", lambda p: p["probing"].update(settle_s=0.01))
    asked = []  # the rig asks its user through the callback, never on the terminal itself
    with ReSkinBench(PROFILE, 2.0, {}, 0) as bench:
        scene = {
            "sensor": sensor,
            "printer": "ender3",
            "port": bench.url,
            "reader": bench.sensor_url,
            "plan": {"pattern": "cross", "spacing_mm": 2.0, "depths_mm": [1.0], "frames": 2},
        }
        scene = validate_config({"scenes": {"rs": scene}})["scenes"]["rs"]
        collect_scene("rs", scene, tmp_path / "raw.zarr", progress=False, ask=asked.append)
    assert asked == ["Attach the probe to the print head"]
    raw = open_raw(tmp_path / "raw.zarr")
    readings = raw["readings"].values
    assert readings.shape[1] == N_VALUES and len(readings) == 2 * (raw["point"].values.max() + 1)
    bz0 = value_names(PROFILE).index("bz0")
    rest = raw["blank_readings"].values[:, bz0].mean()
    assert np.abs(readings[:, bz0] - rest).max() > 20  # the presses show in the field
