import math

import pytest

from threedcal.hardware.motion import MotionModel, trapezoid
from threedcal.hardware.printer import printer_profile


@pytest.fixture(scope="module")
def model():
    return MotionModel(printer_profile("ender3"))


def test_long_move_is_trapezoid_with_exact_phases():
    tr = trapezoid(100.0, 100.0, 500.0)  # 0.2 s ramps of 10 mm each, 80 mm cruise
    assert tr.duration == pytest.approx(1.2)
    assert tr.distance_at(0.2) == pytest.approx(10.0)
    assert tr.distance_at(0.6) == pytest.approx(50.0)
    assert tr.distance_at(1.1) == pytest.approx(100.0 - 0.5 * 500 * 0.1**2)
    assert tr.distance_at(1.2) == pytest.approx(100.0)
    assert tr.distance_at(-1) == 0.0 and tr.distance_at(99) == 100.0


def test_short_move_is_a_triangle():
    tr = trapezoid(10.0, 100.0, 500.0)
    assert tr.duration == pytest.approx(2 * math.sqrt(10 / 500))
    assert tr.v_peak == pytest.approx(math.sqrt(10 * 500))
    assert tr.distance_at(tr.duration / 2) == pytest.approx(5.0)


def test_zero_and_invalid_moves():
    assert trapezoid(0.0, 10.0, 500.0).duration == 0.0
    for bad in [(-1, 10, 500), (1, 0, 500), (1, 10, 0)]:
        with pytest.raises(ValueError):
            trapezoid(*bad)


def test_z_move_is_capped_by_z_limits(model):
    # Ender 3: Z max 5 mm/s, 100 mm/s²: ramps of 0.05 s (0.125 mm), 9.75 mm at 5 mm/s.
    assert model.move_time((0, 0, 0), (0, 0, 10), 100.0) == pytest.approx(2.05)


def test_diagonal_move_caps_speed_by_the_slowest_axis_component(model):
    # Direction (0, 0.6, 0.8): speed <= 5/0.8 = 6.25 mm/s, accel <= 100/0.8 = 125 mm/s².
    assert model.move_time((0, 0, 0), (0, 3, 4), 100.0) == pytest.approx(5 / 6.25 + 6.25 / 125)
    # A pure XY diagonal is not capped below the requested feed.
    assert model.move_time((0, 0, 0), (60, 80, 0), 100.0) == pytest.approx(1.2)


def test_home_time_from_home_is_bumps_only(model):
    xy = (5 / 20 + 20 / 500) + (5 / 10 + 10 / 500)
    z = (2 / 4 + 4 / 100) + (2 / 1 + 1 / 100)
    assert model.home_time((0, 0, 0)) == pytest.approx(2 * xy + z)
    # From an unknown position the worst case (full travel) is assumed: Z alone is 250/4 s.
    assert model.home_time(None) > 250 / 4


def test_plan_time_sums_moves(model):
    targets = [(100, 0, 0), (100, 100, 0)]
    expected = model.move_time((0, 0, 0), (100, 0, 0), 100) + model.move_time(
        (100, 0, 0), (100, 100, 0), 100
    )
    assert model.plan_time(targets, 100.0, start=(0, 0, 0), home=False) == pytest.approx(expected)
    assert model.plan_time(targets, 100.0) == pytest.approx(expected + model.home_time(None))


def test_quantise_to_whole_steps(model):
    assert model.quantise((0.0124, 0.0, 0.0026)) == (0.0125, 0.0, 0.0025)
    assert model.steps((1.0, 2.0, 3.0)) == (80, 160, 1200)
