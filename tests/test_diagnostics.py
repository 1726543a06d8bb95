"""The diagnostics package (diagnostics/, not shipped): each module's `--smoke` run writes what it
says, with finite and plausible figures, and no module reaches into threedcal's private names."""

import ast
import math
import sys
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from conftest import REPO

if str(REPO) not in sys.path:  # `python -m pytest` from the repository has it; a bare `pytest` not
    sys.path.insert(0, str(REPO))

MODULES = sorted((REPO / "diagnostics").glob("*.py"))


def finite(values) -> bool:
    return bool(np.all(np.isfinite(np.asarray(values, dtype=float))))


def test_every_module_uses_public_names_only():
    """No `_private` attribute or import, no setattr on the library: public functions only; and
    every module has main(argv) and --smoke, as the package docstring promises."""
    assert len(MODULES) > 1
    import diagnostics

    for path in MODULES:
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute):
                private = node.attr.startswith("_") and not node.attr.startswith("__")
                assert not private, f"{path.name}:{node.lineno}: .{node.attr}"
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("threedcal"):
                names = [a.name for a in node.names]
                assert not [n for n in names if n.startswith("_")], f"{path.name}: {names}"
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
                assert node.func.id != "setattr", f"{path.name}:{node.lineno}: setattr"
        if path.name != "__init__.py":
            source = path.read_text()
            assert "def main(argv" in source and "--smoke" in source, path.name
            assert path.stem in diagnostics.__doc__, f"{path.stem} missing from the package docs"


@pytest.mark.long  # about 5 s on 2 cores
@pytest.mark.slow
def test_elastic_gel_smoke(tmp_path):
    from diagnostics import elastic_gel

    found = elastic_gel.main(["--smoke", "--out", str(tmp_path), "checks", "contact", "locators"])
    assert (tmp_path / "elastic_checks.png").stat().st_size > 10_000
    assert (tmp_path / "elastic_contact.png").stat().st_size > 10_000
    checks = found["checks"]
    # the coarse grid still lands near Hertz and on the thin-layer limits' side of 1
    assert finite(checks["hertz_radius_error"]) and np.abs(checks["hertz_force_error"]).max() < 0.2
    assert all(r >= 1 for r in checks["bonded_force_ratio"])  # a bonded layer is stiffer
    for name in ("digit", "gelsight_mini"):
        contact = found["contact"][name]
        radii, geometric = np.array(contact["contact_radius_mm"]), np.array(contact["geometric_mm"])
        assert finite(radii) and np.all(radii > 0) and np.all(radii < geometric)
        assert np.all(np.diff(contact["force_n"]) > 0)  # deeper presses push harder
    locators = found["locators"]
    assert locators["geometric_rim_found"] == locators["geometric_symmetry_found"] == 6
    assert locators["geometric_symmetry_rms_px"] < 0.5 and locators["geometric_rim_rms_px"] < 1.0


@pytest.mark.long  # a calibration on the bench and a lookup model: about 10 s on 2 cores
@pytest.mark.slow
def test_point_frames_smoke(tmp_path):
    from diagnostics import point_frames

    (press,) = point_frames.main(["--smoke", "--out", str(tmp_path)])
    assert (tmp_path / "point_frames.png").stat().st_size > 10_000
    geometry, model = press["geometry"], press["model"]
    assert geometry["contact_points"] > 100 and model["contact_points"] > 100
    # the exact gradients come back on the printer's ball within tens of micrometres
    assert geometry["xy_um"] < 100 and abs(geometry["z_um"]) < 100 and geometry["rms_um"] < 20
    assert finite(list(model.values())) and model["xy_um"] < 1000


@pytest.mark.slow  # 1-6 s: two lookup folds on the real ball folder, its images pooled 4 x 4
def test_real_cv_methods_smoke(tmp_path):
    from diagnostics import real_cv_methods

    table = real_cv_methods.main(["--smoke", "--out", str(tmp_path), "--cache", str(tmp_path)])
    assert (tmp_path / "real_cv_drawn.png").is_file()
    assert (tmp_path / "gelsight_ball_fots" / "table.csv").is_file()
    (row,) = table.to_dict("records")
    assert row["method"] == "lookup" and row["labels"] == "drawn"
    assert 0 < row["gradient_lo"] <= row["gradient_rmse"] <= row["gradient_hi"] < 2
    assert 0 < row["depth_mae_um"] < 2000 and finite([row["ms_per_frame"]])


def test_perfect_model_objects_smoke():
    """A perfect model on a registration as good as the bench's truth: a few micrometres under
    both protocols (the integrator's and the rasterisation's error alone)."""
    from diagnostics import perfect_model_objects

    errors = perfect_model_objects.main(["--smoke"])
    assert set(errors["protocol"]) == {"printer", "paper"} and set(errors["object"]) == {"pill"}
    assert finite(errors["type2_um"]) and (errors["type2_um"] < 50).all()
    assert errors["depth_ratio"].between(0.95, 1.05).all()


def test_label_integration_smoke(tmp_path):
    from diagnostics import label_integration

    table = label_integration.main(["--smoke", "--out", str(tmp_path)])
    assert (tmp_path / "label_integration.csv").is_file() and len(table) == 9
    exact = table[table["labels"] == "exact"]
    # exact labels integrate to the true depth at the centre; a 45° clamp loses most of a d = R cap
    assert (exact["centre_error_um"].abs() < 5).all()
    clamped = table[(table["labels"] == "45deg") & (table["depth_mm"] == 2.0)]
    assert math.isfinite(float(clamped["volume_error_pct"].iloc[0]))
    assert float(clamped["volume_error_pct"].iloc[0]) < -10


def test_unit_spread_smoke():
    from diagnostics import unit_spread

    spreads = unit_spread.main(["--smoke"])
    assert set(spreads) == {"DIGIT", "Mini"}
    for figures in spreads.values():
        assert finite([figures[k] for k in figures if k.startswith("spread_")])
        assert 1.0 < figures["spread_field_dn"] < 30.0  # two units' fields differ, by DN
        assert 0.0 < figures["spread_azimuth_deg"] < 60.0


def test_pretrained_edges_smoke():
    from diagnostics import pretrained_edges

    figures = pretrained_edges.main(["--smoke", "--sensor", "digit_fots"])["digit_fots"]
    assert finite(list(figures.values()))
    assert 0 <= figures["within_bound"] <= 1 and figures["gradient_mse"] > 0


@pytest.mark.long  # about 10 s on 2 cores: make test keeps its margin under 5 minutes
def test_quick_presses_smoke():
    from diagnostics import quick_presses

    row = quick_presses.main(["--smoke"])
    assert row["presses"] == 4 and finite([row["drawn_mse"], row["full_mse"], row["change"]])
    assert row["drawn_mse"] > 0 and row["full_mse"] > 0


def test_drawn_presses_are_the_full_sets_own_frames_and_labels():
    from diagnostics.quick_presses import drawn_presses, first
    from threedcal.dataset.trainset import TrainingSet

    samples = pd.DataFrame(
        {
            "frame": np.arange(6),
            "point": np.arange(6),
            "center_x_px": np.arange(6) * 10.0,
            "center_y_px": np.full(6, 5.0),
            "depth_mm": np.full(6, 1.0),
            "eval_radius_px": np.full(6, 3.0),
            "split": ["train", "val", "train", "train", "val", "train"],
            "min_p": [80, 0, 80, 80, 0, 80],
            "min_p_r1": [80, 0, 80, 80, 0, 80],
        }
    )
    frames = np.arange(6, dtype=np.uint8)[:, None, None, None] * np.ones((1, 4, 4, 3), np.uint8)
    full = TrainingSet(frames, np.zeros((4, 4, 3), np.float32), samples, 10.0, 2.0, None)
    drawn = drawn_presses(full, 3, seed=1)
    assert set(drawn.point) <= {0, 2, 3, 5} and len(set(drawn.point)) == 3  # training presses only
    for row, point in enumerate(drawn.point):  # each frame stays with its own label
        assert drawn.frames[row, 0, 0, 0] == point and drawn.center_px[row, 0] == point * 10.0
    assert list(drawn.samples["frame"]) == [0, 1, 2] and set(drawn.split) == {"train"}
    assert "min_p_r1" not in drawn.samples and len(first(drawn, 2).samples) == 2
    with pytest.raises(ValueError, match="4"):
        drawn_presses(full, 5, seed=0)


@pytest.mark.long  # about 3 s on 2 cores: make test keeps its margin under 5 minutes
def test_registration_cost_smoke():
    from diagnostics import registration_cost

    table = registration_cost.main(["--smoke"])
    moves = list(zip(table["dx_px"], table["dy_px"], strict=True))
    assert moves == [(0.0, 0.0), (0.25, 0.0), (0.0, 0.25)]
    assert finite(table["mse"]) and (table["mse"] > 0).all() and table["change"].iloc[0] == 0


def test_shifted_labels_move_by_the_shift_and_frames_stay():
    from diagnostics.registration_cost import downscale_of, shifted
    from threedcal.dataset.trainset import TrainingSet

    samples = pd.DataFrame(
        {
            "frame": [0],
            "point": [0],
            "center_x_px": [20.0],
            "center_y_px": [15.0],
            "depth_mm": [0.5],
            "eval_radius_px": [6.0],
            "split": ["val"],
            "min_p": [0],
        }
    )
    frames = np.random.default_rng(0).integers(0, 255, (1, 30, 40, 3), dtype=np.uint8)
    ts = TrainingSet(frames, np.zeros((30, 40, 3), np.float32), samples, 10.0, 2.0, None)
    moved = shifted(ts, 3, -2)
    assert moved.frames is ts.frames and list(moved.center_px[0]) == [23.0, 13.0]
    # a label moved by whole pixels is the same label, translated
    np.testing.assert_allclose(moved.labels(0)[:, 5:25, 8:33], ts.labels(0)[:, 7:27, 5:30])
    assert downscale_of(ts) == 1.0
    assert downscale_of(replace(ts, meta={"downscale": 2})) == 2.0


def test_registration_cost_recovers_an_exact_quadratic():
    from diagnostics.registration_cost import cost_per_px2, error_for

    e = np.array([0.0, 0.25, 0.25, 0.5, 0.5])
    rows = pd.DataFrame({"error_px": e, "change": 3.5 * e**2})
    assert cost_per_px2(rows) == pytest.approx(3.5, rel=1e-12)
    assert error_for(0.1, 3.5) == pytest.approx(math.sqrt(0.1 / 3.5))
    assert error_for(0.1, 0.0) == math.inf
    with pytest.raises(ValueError, match="no shifted rows"):
        cost_per_px2(rows.iloc[:1])


def test_against_ideal_divides_by_the_unshifted_model():
    from diagnostics.registration_cost import against_ideal

    table = pd.DataFrame(
        {"unit": ["u1", "u1", "u2"], "error_px": [0.0, 0.25, 0.0], "mse": [2.0, 3.0, 4.0]}
    )
    units = pd.DataFrame(
        {
            "full_scene": ["u1", "u2", "u3"],
            "truth_quick_mse": [3.0, 2.0, 1.0],
            "truth_full_mse": [2.5, 4.0, 1.0],
        }
    )
    out = against_ideal(table, units)
    assert list(out["full_scene"]) == ["u1", "u2"]  # u3 was not measured
    assert list(out["quick_vs_ideal"]) == [0.5, -0.5] and list(out["full_vs_ideal"]) == [0.25, 0.0]


def test_unit_costs_average_the_units_with_a_t_interval():
    from diagnostics.registration_cost import unit_costs

    e = np.array([0.0, 0.25, 0.5])
    rows = [
        {"sensor": "s", "unit": u, "error_px": x, "change": c * x**2}
        for u, c in (("a", 2.0), ("b", 4.0))
        for x in e
    ]
    out = unit_costs(pd.DataFrame(rows)).iloc[0]
    assert out["unit_costs"] == pytest.approx([2.0, 4.0]) and out["cost"] == pytest.approx(3.0)
    half = 12.706204736 * 1.0  # t(0.975, 1) x sem([2, 4]) = 12.706 x 1
    assert (out["cost_lo"], out["cost_hi"]) == pytest.approx((3.0 - half, 3.0 + half))
    one = unit_costs(pd.DataFrame(rows[:3])).iloc[0]
    assert one["units"] == 1 and math.isnan(one["cost_lo"])
