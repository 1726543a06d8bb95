import numpy as np
import pandas as pd
import pytest

from threedcal.collect.plan import (
    dome_sag_mm,
    grid_plan,
    plan_to_printer,
    read_plan_csv,
    serpentine,
    validate_plan,
)
from threedcal.errors import ConfigError

SENSOR = {
    "probing": {"plan_area_mm": [16.0, 18.0]},
    "gel": {"max_penetration_mm": 4.0, "dome": {"kx_per_mm": 0.013, "ky_per_mm": 0.0043}},
    "mount": {
        "x_offset_mm": 110.0,
        "y_offset_mm": 111.5,
        "z_touch_mm": 137.0,
        "z_clearance_mm": 2.0,
    },
}
PRINTER = {"travel_mm": {"x": 235, "y": 235, "z": 250}}


def test_py3dcal_plan_csv_reads_with_hash_header(tmp_path):
    path = tmp_path / "default.csv"
    path.write_text(
        "# X, Y, Penetration Depth, Frames to Capture\n0.00,0.00,3.15,30.00\n0.50,0.00,-3.04,30\n"
    )
    plan = read_plan_csv(path)
    assert plan[["x_mm", "y_mm", "depth_mm", "frames"]].values.tolist() == [
        [0, 0, 3.15, 30],
        [0.5, 0, 3.04, 30],
    ]
    assert plan["line"].tolist() == [2, 3]


@pytest.mark.parametrize(
    "line, message",
    [
        ("1,2,nan_x,3", "depth_mm='nan_x' is not a number"),
        ("1,2,3", "expected 4 values"),
        ("1,2,3,2.5", "frames='2.5' must be a whole number"),
        ("1,2,3,0", "frames='0' must be a whole number >= 1"),
    ],
)
def test_plan_csv_errors_name_the_line(tmp_path, line, message):
    path = tmp_path / "plan.csv"
    path.write_text(f"x,y,depth,frames\n0,0,1,1\n{line}\n")
    with pytest.raises(ConfigError, match=f"plan.csv, line 3: {message}"):
        read_plan_csv(path)


def test_empty_plan_is_refused(tmp_path):
    path = tmp_path / "plan.csv"
    path.write_text("# header only\n")
    with pytest.raises(ConfigError, match="no probe point"):
        read_plan_csv(path)


def test_grid_reproduces_the_authors_digit_plan_shape_and_dome_rule():
    plan = grid_plan(SENSOR, spacing_mm=0.5, depths_mm=2.0, frames=30)
    assert len(plan) == 33 * 37
    corner = plan[(plan.x_mm == 0) & (plan.y_mm == 0)].depth_mm.item()
    apex = plan[(plan.x_mm == 8) & (plan.y_mm == 9)].depth_mm.item()
    assert apex == pytest.approx(2.0)
    assert corner == pytest.approx(
        2.0 + 0.013 * 64 + 0.0043 * 81
    )  # 3.18 mm; the authors' file says 3.15
    assert dome_sag_mm({"gel": {}}, 3.0, 4.0) == 0


def test_serpentine_alternates_direction_per_row():
    plan = grid_plan(
        {**SENSOR, "probing": {"plan_area_mm": [2.0, 1.0]}}, spacing_mm=1.0, depths_mm=1.0, frames=1
    )
    assert list(zip(plan.x_mm, plan.y_mm, strict=True)) == [
        (0, 0),
        (1, 0),
        (2, 0),
        (2, 1),
        (1, 1),
        (0, 1),
    ]
    shuffled = plan.sample(frac=1, random_state=3)
    pd.testing.assert_frame_equal(serpentine(shuffled), plan)


def test_grid_presses_each_point_at_every_depth_before_moving_on():
    flat = {**SENSOR, "gel": {}, "probing": {"plan_area_mm": [1.0, 1.0]}}
    plan = grid_plan(flat, spacing_mm=1.0, depths_mm=[1.5, 0.5, 1.0], frames=1)
    assert list(zip(plan.x_mm, plan.y_mm, plan.depth_mm, strict=True)) == [
        (x, y, d) for x, y in [(0, 0), (1, 0), (1, 1), (0, 1)] for d in (1.5, 0.5, 1.0)
    ]
    domed = grid_plan(SENSOR, spacing_mm=0.5, depths_mm=[0.5, 1.0], frames=1)
    sag = domed.depth_mm.to_numpy()[1::2] - domed.depth_mm.to_numpy()[::2]
    np.testing.assert_allclose(sag, 0.5, atol=1e-4)  # the dome rule holds at every depth


@pytest.mark.parametrize("depths", [[], [1.0, float("nan")], [0.0], [1.0, -0.5]])
def test_grid_rejects_missing_or_non_positive_depths(depths):
    with pytest.raises(ConfigError, match="depth"):
        grid_plan(SENSOR, spacing_mm=1.0, depths_mm=depths, frames=1)


def plan_of(*rows):
    return pd.DataFrame(rows, columns=["x_mm", "y_mm", "depth_mm", "frames"])


def test_valid_plan_passes():
    validate_plan(grid_plan(SENSOR, 1.0, 2.0, 3), SENSOR, PRINTER)


@pytest.mark.parametrize(
    "row, message",
    [
        ((np.nan, 1, 1, 1), "point 1: x, y, depth and frames must be finite"),
        (
            (8, 9, 4.5, 1),
            "point 1: depth 4.5 mm gives 4.5 mm penetration, beyond the sensor's maximum of 4",
        ),
        ((17, 1, 1, 1), r"point 1: point \(17, 1\) mm lies outside the gel"),
        ((1, -0.5, 1, 1), "lies outside the gel"),
    ],
)
def test_plan_validation_names_the_row(row, message):
    with pytest.raises(ConfigError, match=message):
        validate_plan(plan_of((1, 1, 1, 1), row), SENSOR, PRINTER, source="p")


def test_dome_compensated_depth_is_not_counted_as_penetration():
    # At the corner the surface is 1.18 mm below the apex: 5 mm commanded is 3.82 mm of penetration.
    validate_plan(plan_of((0, 0, 5.0, 1)), SENSOR, PRINTER)


def test_target_outside_printer_travel_is_refused():
    sensor = {**SENSOR, "mount": {**SENSOR["mount"], "x_offset_mm": 230.0}}
    with pytest.raises(ConfigError, match="printer X=.* outside the printer's travel 0..235"):
        validate_plan(plan_of((10, 1, 1, 1)), sensor, PRINTER)


def test_plan_to_printer_uses_mount_offsets():
    assert plan_to_printer(SENSOR, 1.0, 2.0, 1.5) == (111.0, 113.5, 135.5)
