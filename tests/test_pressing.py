import numpy as np
import pytest

from threedcal.errors import ConfigError
from threedcal.evaluate.groundtruth import surface_height
from threedcal.evaluate.objects import load_object
from threedcal.evaluate.pressing import Press, plan_presses, relief_indenter, render_press
from threedcal.profiles import load_profile
from threedcal.sim.optics import GelSimulator

PRESSING = {
    "presses": 1,
    "depth_mm": 1.0,
    "depth_jitter": 0.1,
    "offset_fraction": 0.12,
    "rotation_deg": 20,
}


@pytest.fixture(scope="module")
def simulator():
    return GelSimulator(load_profile("sensor", "gelsight_mini"), seed=0)


def test_presses_are_seeded_off_centre_turned_and_jittered():
    a = plan_presses(["pill", "pawn"], (240, 320), PRESSING, seed=3)
    assert a == plan_presses(["pill", "pawn"], (240, 320), PRESSING, seed=3)
    assert a != plan_presses(["pill", "pawn"], (240, 320), PRESSING, seed=4)
    for press in a:
        assert (
            abs(press.center_px[0] - 159.5) <= 0.12 * 320
            and abs(press.center_px[1] - 119.5) <= 0.12 * 240
        )
        assert abs(press.rotation_deg) <= 20 and 0.9 <= press.depth_mm <= 1.1


def test_more_presses_come_in_rounds_and_keep_the_earlier_ones():
    one = plan_presses(["pill", "pawn"], (240, 320), PRESSING, seed=3)
    three = plan_presses(["pill", "pawn"], (240, 320), {**PRESSING, "presses": 3}, seed=3)
    assert three[:2] == one
    assert [(p.name, p.number) for p in three] == [
        (name, n) for n in range(3) for name in ("pill", "pawn")
    ]
    assert len({p.center_px for p in three}) == 6  # each press its own pose


def test_relief_indenter_is_the_gel_facing_surface():
    mesh = load_object("pill")
    indenter = relief_indenter(mesh, 15.77, 0.0)
    # The tip (lowest point of the pill) is where the gap is zero; 1.5 mm off-axis along the
    # capsule's width (radius 2 mm) the surface has risen by 2 - sqrt(4 - 1.5^2).
    assert indenter.gap(np.array([0.0]), np.array([0.0]))[0] == pytest.approx(0.0, abs=0.02)
    assert indenter.gap(np.array([0.0]), np.array([1.5]))[0] == pytest.approx(
        2 - np.sqrt(4 - 1.5**2), abs=0.03
    )


def test_rendered_press_changes_the_frame_where_the_ground_truth_touches(simulator):
    press = Press("pill", (160.0, 120.0), 15.0, 1.0, 1.0)
    frame = render_press(simulator, press)
    blank = simulator.blank(0)
    change = np.abs(frame.astype(int) - blank.astype(int)).sum(axis=-1)
    gt = surface_height(
        load_object("pill"), frame.shape[:2], simulator.px_per_mm, press.center_px, 15.0
    ).depth(1.0)
    assert change[gt > 0.2].mean() > 5 * change[gt == 0].mean()


def test_press_deeper_than_the_gel_allows_is_refused(simulator):
    with pytest.raises(ConfigError, match="maximum penetration"):
        render_press(simulator, Press("pawn", (160.0, 120.0), 0.0, 5.0, 5.0))


def test_object_partly_outside_the_gel_and_vertical_walls_render_finite(simulator):
    for name, centre in (("pawn", (5.0, 120.0)), ("hemispheres", (310.0, 230.0))):
        frame = render_press(simulator, Press(name, centre, 30.0, 2.0, 2.0))
        assert frame.dtype == np.uint8 and frame.shape == (240, 320, 3)
