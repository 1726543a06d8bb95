"""The quick plan's space-filling design: every round's prefix covers the gel the camera sees."""

import numpy as np
import pytest
from conftest import lens_free

from threedcal.collect.design import (
    covering_radius,
    discrepancy,
    halton_design,
    hexagonal_covering_radius,
)
from threedcal.collect.plan import dome_sag_mm, registration_plan, validate_plan, whole_contacts
from threedcal.collect.quick_plan import quick_area_mm, quick_rounds
from threedcal.collect.scene_plan import plan_from_config, registration_presses_of
from threedcal.errors import ConfigError
from threedcal.profiles import load_profile
from threedcal.study.config import validate_config

SENSOR = load_profile("sensor", "digit_fots")


def quick_plan_config(**plan) -> dict:
    """A quick plan checked as a scene's; its DIGIT lens-free, so that no registration presses
    are asked for (the design, not the registration, is under test: SENSOR builds the plans)."""
    scene = {
        "sensor": lens_free("digit_fots"),
        "printer": "ender3",
        "plan": {"pattern": "quick", "depth_mm": 1.0, "frames": 2, **plan},
        "dataset": {"downscale": 2},
    }
    return validate_config({"scenes": {"q": scene}})["scenes"]["q"]["plan"]


def test_covering_radius_and_hexagonal_yardstick_exact():
    # one press at the centre of a 2 x 2 mm square: the corners lie sqrt(2) mm away
    assert covering_radius([[1.0, 1.0]], (0, 0, 2, 2), resolution=201) == pytest.approx(np.sqrt(2))
    # a 2 x 2 lattice of 1 mm cells: every cell's corner lies sqrt(0.5) mm from its centre
    grid = [[0.5, 0.5], [1.5, 0.5], [0.5, 1.5], [1.5, 1.5]]
    assert covering_radius(grid, (0, 0, 2, 2), resolution=201) == pytest.approx(np.sqrt(0.5))
    # n hexagons of side s tile area A: A = n * 3 sqrt(3) / 2 * s^2, and the covering radius is s
    assert hexagonal_covering_radius(6, (0, 0, 3 * np.sqrt(3), 3)) == pytest.approx(1.0)


def test_every_round_prefix_covers_the_area_evenly():
    """Each round's prefix, for several seeds: centred discrepancy below the 5th percentile of
    uniformly random designs of its size, and no spot farther from a press than 3x the hexagonal
    lattice's covering radius (the least any design reaches)."""
    base = quick_plan_config(round_presses=10, max_presses=50)
    area = quick_area_mm(SENSOR, base)
    x0, y0, x1, y1 = area
    rng = np.random.default_rng(123)
    random_5th = {
        n: np.percentile(
            [
                discrepancy(np.column_stack([rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)]), area)
                for _ in range(200)
            ],
            5,
        )
        for n in (10, 20, 30, 40, 50)
    }
    for seed in range(4):
        plan = plan_from_config({**base, "seed": seed}, SENSOR)
        presses = plan.loc[plan["phase"] == "grid", ["x_mm", "y_mm"]].to_numpy()
        assert len(presses) == 50
        for n, bound in random_5th.items():
            assert discrepancy(presses[:n], area) < bound, (seed, n)
            assert covering_radius(presses[:n], area) <= 3 * hexagonal_covering_radius(n, area)


def test_quick_plan_rows_rounds_and_determinism():
    config = quick_plan_config(round_presses=10, max_presses=30, seed=4, touch_search={"points": 1})
    plan = plan_from_config(config, SENSOR)
    assert list(dict.fromkeys(plan["phase"])) == ["touch", "grid"]
    quick = plan[plan["phase"] == "grid"]
    first = int(quick.index[0])
    assert quick_rounds(config, first) == [first + 10, first + 20, first + 30]
    # one depth, dome compensated as the grid's; `frames` per press; inside the area
    np.testing.assert_allclose(
        quick["depth_mm"], 1.0 + dome_sag_mm(SENSOR, quick["x_mm"], quick["y_mm"]), atol=1e-4
    )
    assert (quick["frames"] == 2).all()
    x0, y0, x1, y1 = quick_area_mm(SENSOR, config)
    assert quick["x_mm"].between(x0, x1).all() and quick["y_mm"].between(y0, y1).all()
    validate_plan(plan, SENSOR, load_profile("printer", "ender3"))
    # the same seed, the same plan; another seed, another; a larger cap keeps the rounds before
    assert plan.equals(plan_from_config(config, SENSOR))
    other = plan_from_config({**config, "seed": 5}, SENSOR)
    assert not np.allclose(other["x_mm"].to_numpy()[first:], quick["x_mm"].to_numpy())
    longer = plan_from_config({**config, "max_presses": 50}, SENSOR)
    assert longer.iloc[: len(plan)].equals(plan)


def test_each_round_is_a_set_of_the_halton_prefix():
    """Reordering a round into a short path changes no round's set of presses."""
    config = quick_plan_config(round_presses=10, max_presses=30, touch_search={"points": 0})
    quick = plan_from_config(config, SENSOR)[["x_mm", "y_mm"]].to_numpy()
    design = np.round(halton_design(30, quick_area_mm(SENSOR, config), 0, 10), 4)
    for start in (0, 10, 20):
        ours = {tuple(p) for p in quick[start : start + 10]}
        assert ours == {tuple(p) for p in design[start : start + 10]}


@pytest.mark.parametrize(("sensor", "depth"), [("digit_fots", 0.25), ("gelsight_mini", 0.4)])
def test_a_quick_plans_registration_presses_are_the_lattices_inside_its_area(sensor, depth):
    """Only the lattice's presses inside the quick area are kept, and none that would leave a whole
    contact is lost: the registration sees the same contacts for fewer presses."""
    profile = load_profile("sensor", sensor)
    presses = {"spacing_mm": 1.0, "depth_mm": depth, "frames": 1}
    lattice = registration_plan(profile, presses)
    quick = registration_presses_of({"pattern": "quick", "registration": presses}, profile)
    x0, y0, x1, y1 = quick_area_mm(profile, {})
    assert quick["x_mm"].between(x0, x1).all() and quick["y_mm"].between(y0, y1).all()
    assert 0 < len(quick) < len(lattice)
    kept = lattice.merge(quick, on=["x_mm", "y_mm", "depth_mm"])
    assert len(kept) == len(quick)  # lattice points, not new ones
    assert whole_contacts(profile, quick, 2.0) == whole_contacts(profile, lattice, 2.0) >= 30
    # a grid plan keeps its whole lattice
    grid = registration_presses_of({"pattern": "grid", "registration": presses}, profile)
    assert len(grid) == len(lattice)


def test_whole_contacts_counts_the_contacts_whose_rim_and_margin_lie_in_the_frame():
    """A press at the view's centre is whole; one whose contact reaches past the frame's edge is
    not: a flat gel (the Mini) at 0.4 mm under a 2 mm ball has a contact radius of
    sqrt(2 R d - d^2) = 1.2 mm."""
    import pandas as pd

    from threedcal.collect.plan import WHOLE_CONTACT_MARGIN_PX, camera_view_mm

    mini = load_profile("sensor", "gelsight_mini")
    vx0, vy0, vx1, vy1 = camera_view_mm(mini)
    scale = float(mini["px_per_mm"])
    reach_mm = (np.sqrt(2 * 2.0 * 0.4 - 0.4**2) * scale + WHOLE_CONTACT_MARGIN_PX) / scale
    rows = pd.DataFrame(
        {
            "x_mm": [(vx0 + vx1) / 2, vx0 + reach_mm + 0.01, vx0 + reach_mm - 0.05],
            "y_mm": [(vy0 + vy1) / 2] * 3,
            "depth_mm": [0.4] * 3,
        }
    )
    assert whole_contacts(mini, rows, 2.0) == 2
    assert whole_contacts(mini, rows.iloc[2:], 2.0) == 0
    assert whole_contacts(mini, rows.iloc[:0], 2.0) == 0


def test_each_quick_press_pauses_to_register_on_its_way_down():
    """registration.each_press: every press is two rows at one place, its pause (phase register,
    the registration depth) then its own depth (grid), one press; the rounds count presses."""
    from threedcal.collect.quick_plan import continued_presses, rows_per_press
    from threedcal.collect.scene_plan import plan_phases

    config = quick_plan_config(
        round_presses=10,
        max_presses=30,
        registration={"depth_mm": 0.25, "each_press": True, "frames": 3},
        touch_search={"method": "bisect", "presses": 8, "points": 1},
    )
    plan = plan_from_config(config, SENSOR)
    assert rows_per_press(config) == 2
    assert plan["phase"].tolist() == ["touch"] * 8 + ["register", "grid"] * 30
    paused, pressed = plan.iloc[8::2], plan.iloc[9::2]
    np.testing.assert_array_equal(paused[["x_mm", "y_mm"]], pressed[["x_mm", "y_mm"]])
    sag = dome_sag_mm(SENSOR, pressed["x_mm"], pressed["y_mm"])
    np.testing.assert_allclose(paused["depth_mm"], 0.25 + sag, atol=1e-4)
    np.testing.assert_allclose(pressed["depth_mm"], 1.0 + sag, atol=1e-4)
    assert (paused["frames"] == 3).all() and (pressed["frames"] == 2).all()
    # the same presses, in the same order, as the plan without pauses
    plain = plan_from_config({**config, "registration": {}}, SENSOR)
    np.testing.assert_array_equal(pressed[["x_mm", "y_mm"]], plain.iloc[8:][["x_mm", "y_mm"]])
    assert quick_rounds(config, 8) == [28, 48, 68]  # 10 presses, 20 rows a round
    assert continued_presses(plan).tolist() == [False] * 8 + [False, True] * 30
    stored = plan[["x_mm", "y_mm", "depth_mm", "frames"]].to_dict("list")
    assert plan_phases(stored, config, SENSOR).tolist() == plan["phase"].tolist()
    validate_plan(plan, SENSOR, load_profile("printer", "ender3"))


def test_a_bisecting_touch_search_plans_its_presses_at_the_deepest_it_may_press():
    from threedcal.collect.plan import touch_search_range

    search = {"method": "bisect", "presses": 8, "points": 1, "frames": 4, "beyond_mm": 0.1}
    config = quick_plan_config(touch_search=search)
    plan = plan_from_config(config, SENSOR)
    touch = plan[plan["phase"] == "touch"]
    low, high = touch_search_range(SENSOR, config["touch_search"])
    assert (low, high) == pytest.approx((-0.2, 0.3))  # probing.touch_uncertainty_mm 0.2 each way
    assert len(touch) == 8 and (touch["frames"] == 4).all()
    np.testing.assert_allclose(touch["depth_mm"], high + dome_sag_mm(SENSOR, 8.0, 9.0))


def test_a_grid_plan_keeps_to_its_area_as_the_whole_areas_lattice():
    full = {"spacing_mm": 0.5, "depths_mm": [1.0, 2.0, 3.0], "depth_mode": "cycle", "frames": 1}
    full["registration"] = {"spacing_mm": 1.0, "depth_mm": 0.25, "frames": 1}
    whole = plan_from_config(full, SENSOR)
    area = [2.0, 1.0, 14.0, 17.0]
    kept = plan_from_config({**full, "area_mm": area}, SENSOR)
    inside = whole["x_mm"].between(2.0, 14.0) & whole["y_mm"].between(1.0, 17.0)
    for phase in ("grid", "register"):
        ours, theirs = kept[kept["phase"] == phase], whole[inside & (whole["phase"] == phase)]
        key = ["x_mm", "y_mm", "depth_mm"]
        assert 0 < len(ours) < (whole["phase"] == phase).sum()
        assert set(map(tuple, ours[key].to_numpy())) == set(map(tuple, theirs[key].to_numpy()))
    with pytest.raises(ConfigError, match=r"plan.area_mm: \[0.0, 0.0, 17.0, 18.0\] must be"):
        plan_from_config({**full, "area_mm": [0.0, 0.0, 17.0, 18.0]}, SENSOR)
