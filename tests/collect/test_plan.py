import numpy as np
import pandas as pd
import pytest

from threedcal.collect.plan import (
    dome_sag_mm,
    grid_plan,
    plan_to_printer,
    read_plan_csv,
    serpentine,
    touch_search_plan,
    validate_plan,
)
from threedcal.collect.scene_plan import plan_from_config, plan_phases
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
        # Repro: frames nan / inf raised ValueError / OverflowError from int()
        ("1,2,3,nan", "frames='nan' must be a whole number >= 1"),
        ("1,2,3,inf", "frames='inf' must be a whole number >= 1"),
        ("1,2,3,-inf", "frames='-inf' must be a whole number >= 1"),
    ],
)
def test_plan_csv_errors_name_the_line(tmp_path, line, message):
    path = tmp_path / "plan.csv"
    path.write_text(f"x,y,depth,frames\n0,0,1,1\n{line}\n")
    with pytest.raises(ConfigError, match=f"plan.csv, line 3: {message}"):
        read_plan_csv(path)


def test_a_binary_plan_file_is_refused_naming_it(tmp_path):
    """Repro: a plan `csv` that is not text (a spreadsheet saved as .xlsx, say) raised
    UnicodeDecodeError out of `config check`."""
    path = tmp_path / "plan.csv"
    path.write_bytes(b"PK\x03\x04\x14\x00\x06\x00\x08\x00\x00\x00!\x00\xd0\xff")
    with pytest.raises(ConfigError, match=r"plan.csv: not a text file \(a plan CSV expected\)"):
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


MINI_LIKE = {**SENSOR, "type": "vision", "gel": {"max_penetration_mm": 3.5, "dome": None}}
SEARCH = {"points": 3, "spread_mm": 1.5, "step_mm": 0.02, "beyond_mm": 0.1, "frames": 1}


def test_touch_search_steps_through_the_nominal_touch_at_places_near_the_centre():
    sensor = {
        **SENSOR,
        "type": "vision",
        "probing": {**SENSOR["probing"], "touch_uncertainty_mm": 0.2},
    }
    rows = touch_search_plan(sensor, SEARCH)
    assert (rows["phase"] == "touch").all() and len(rows) == 3 * 26
    places = rows[["x_mm", "y_mm"]].drop_duplicates().to_numpy()
    np.testing.assert_allclose(np.hypot(places[:, 0] - 8.0, places[:, 1] - 9.0), 1.5)
    for x, y in places:  # each place: -0.2 .. +0.3 mm below the nominal touch, shallowest first
        one = rows[(rows["x_mm"] == x) & (rows["y_mm"] == y)]
        steps = one["depth_mm"].to_numpy() - dome_sag_mm(sensor, x, y)
        np.testing.assert_allclose(steps, -0.2 + 0.02 * np.arange(26), atol=1e-6)
    assert (
        len(touch_search_plan(sensor, {**SEARCH, "points": 1})[["x_mm", "y_mm"]].drop_duplicates())
        == 1
    )
    assert touch_search_plan(sensor, {**SEARCH, "points": 1})["x_mm"].iloc[0] == 8.0  # the centre


def test_plan_from_config_starts_with_the_search_for_vision_sensors_only():
    config = {"spacing_mm": 2.0, "depth_mm": 1.0, "frames": 2, "touch_search": SEARCH}
    plan = plan_from_config(config, MINI_LIKE)
    touch = plan["phase"] == "touch"
    assert touch.sum() == 78 and touch.iloc[:78].all() and not touch.iloc[78:].any()
    validate_plan(plan, MINI_LIKE, PRINTER)  # steps above the gel are allowed for the search
    magnetic = {**MINI_LIKE, "type": "magnetic"}
    assert (plan_from_config(config, magnetic)["phase"] == "grid").all()
    off = {**config, "touch_search": {**SEARCH, "points": 0}}
    assert (plan_from_config(off, MINI_LIKE)["phase"] == "grid").all()


def test_plan_phases_are_checked_against_the_collected_plan():
    config = {"spacing_mm": 2.0, "depth_mm": 1.0, "frames": 2, "touch_search": SEARCH}
    plan = plan_from_config(config, MINI_LIKE)
    stored = plan[["x_mm", "y_mm", "depth_mm", "frames"]].to_dict("list")
    np.testing.assert_array_equal(plan_phases(stored, config, MINI_LIKE), plan["phase"])
    other = {**config, "touch_search": {**SEARCH, "step_mm": 0.025}}
    with pytest.raises(ConfigError, match="rows its plan.touch_search describes"):
        plan_phases(stored, other, MINI_LIKE)
    # a store collected before registration presses were asked for is not read as having them
    asked = {**config, "registration": REGISTRATION}
    with pytest.raises(ConfigError, match="rows its plan.registration describes"):
        plan_phases(stored, asked, MINI_LIKE)


REGISTRATION = {"spacing_mm": 1.0, "depth_mm": 0.4, "frames": 1}


def test_registration_presses_follow_the_search_and_precede_the_grid():
    config = {
        "spacing_mm": 2.0,
        "depth_mm": 1.0,
        "frames": 2,
        "touch_search": SEARCH,
        "registration": REGISTRATION,
    }
    plan = plan_from_config(config, MINI_LIKE)
    order = plan["phase"].drop_duplicates().tolist()
    assert order == ["touch", "register", "grid"]
    register = plan[plan["phase"] == "register"]
    width, height = MINI_LIKE["probing"]["plan_area_mm"]
    # a 1 mm lattice over the whole probe area, corners included, each pressed 0.4 mm once
    assert len(register) == (int(width) + 1) * (int(height) + 1)
    assert register["x_mm"].min() == 0 and register["x_mm"].max() == width
    assert register["y_mm"].min() == 0 and register["y_mm"].max() == height
    np.testing.assert_allclose(register["depth_mm"], 0.4)
    assert (register["frames"] == 1).all()
    validate_plan(plan, MINI_LIKE, PRINTER)
    stored = plan[["x_mm", "y_mm", "depth_mm", "frames"]].to_dict("list")
    np.testing.assert_array_equal(plan_phases(stored, config, MINI_LIKE), plan["phase"])
    magnetic = {**MINI_LIKE, "type": "magnetic"}
    assert (plan_from_config(config, magnetic)["phase"] == "grid").all()
    off = {**config, "registration": {**REGISTRATION, "spacing_mm": 0}}
    assert not (plan_from_config(off, MINI_LIKE)["phase"] == "register").any()
    with pytest.raises(ConfigError, match="plan.registration spacing_mm=0.001 would have"):
        plan_from_config(
            {**config, "registration": {**REGISTRATION, "spacing_mm": 0.001}}, MINI_LIKE
        )


def test_only_search_steps_may_sit_above_the_gel_and_never_above_clearance():
    with pytest.raises(ConfigError, match="point 1: depth -0.1 mm is negative"):
        validate_plan(plan_of((1, 1, 1, 1), (1, 1, -0.1, 1)), SENSOR, PRINTER, source="p")
    high = {**SENSOR, "probing": {**SENSOR["probing"], "touch_uncertainty_mm": 2.5}}
    rows = touch_search_plan(high, SEARCH)
    with pytest.raises(ConfigError, match="touch search row 0: .* above the clearance height"):
        validate_plan(rows, high, PRINTER, source="p")


def test_cycled_depths_press_each_point_once_with_every_depth_over_the_area():
    depths = [1.0, 2.0, 3.0]
    every = grid_plan(MINI_LIKE, 1.0, depths, frames=3)
    cycled = grid_plan(MINI_LIKE, 1.0, depths, frames=3, depth_mode="cycle")
    one = grid_plan(MINI_LIKE, 1.0, 1.0, frames=3)
    assert len(cycled) == len(one) == len(every) // 3  # the frame count of one depth
    assert not cycled.duplicated(["x_mm", "y_mm"]).any()
    # point (column i, row j) at depths[(i + j) mod 3]: every depth forms a diagonal lattice
    expected = np.asarray(depths)[(cycled["x_mm"] + cycled["y_mm"]).round().astype(int) % 3]
    np.testing.assert_array_equal(cycled["depth_mm"], expected)
    counts = cycled["depth_mm"].value_counts()
    assert counts.max() - counts.min() <= 1
    # any half of the area (a training fraction) holds every depth in nearly equal shares
    half = cycled[cycled["x_mm"] < 8]
    assert half["depth_mm"].value_counts().max() / half["depth_mm"].value_counts().min() < 1.1
    with pytest.raises(ConfigError, match="depth_mode 'sometimes' is not allowed"):
        grid_plan(MINI_LIKE, 1.0, depths, frames=3, depth_mode="sometimes")


def test_a_cycled_cross_is_one_pass_with_every_depth():
    from threedcal.collect.plan import cross_plan

    one_pass = cross_plan(MINI_LIKE, 1.0, [1.0], 1, arm_width_mm=6.0)
    cycled = cross_plan(MINI_LIKE, 1.0, [1.0, 2.0, 3.0], 1, arm_width_mm=6.0, depth_mode="cycle")
    assert len(cycled) == len(one_pass) and not cycled.duplicated(["x_mm", "y_mm"]).any()
    assert set(cycled["depth_mm"]) == {1.0, 2.0, 3.0}
