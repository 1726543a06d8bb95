"""The integration study: table columns, Pareto front, figure, reading, and its DAG target."""

import pandas as pd
import pytest

from threedcal.depth.scenarios import SCENARIOS, make_scene
from threedcal.depth.study import COLUMNS, pareto_front, run_study, write_study
from threedcal.errors import ConfigError
from threedcal.study.config import validate_config
from threedcal.study.paths import INTEGRATION_STUDY_TARGETS, study_targets


def test_study_table_figure_and_reading(tmp_path):
    table = run_study(
        [[20, 30], [30, 20]],
        ["cap", "border_contact"],
        ["poisson_dst", "poisson_dct", "py3dcal"],
        dtypes=["float32", "float64"],
        repeats=2,
    )
    assert list(table.columns) == COLUMNS
    assert len(table) == 2 * 2 * 2 * 3
    assert (table["ms_per_frame"] > 0).all() and (table["rmse"] <= table["peak_error"]).all()
    border = table[(table["scenario"] == "border_contact") & (table["dtype"] == "float64")]
    by_method = border.groupby("method")["rmse"].max()
    assert by_method["poisson_dct"] < by_method["poisson_dst"]
    write_study(table, tmp_path / "t.csv", tmp_path / "t.png", tmp_path / "r.md")
    assert pd.read_csv(tmp_path / "t.csv").shape == table.shape
    assert (tmp_path / "t.png").stat().st_size > 10_000
    assert "border_contact | poisson_dct" in (tmp_path / "r.md").read_text()


def test_pareto_front_keeps_only_undominated_points():
    points = pd.DataFrame({"ms_per_frame": [1, 2, 3, 4], "rmse": [5, 1, 2, 0.5]})
    assert pareto_front(points).index.tolist() == [0, 1, 3]


def test_unknown_names_are_refused():
    with pytest.raises(ConfigError, match="scenario 'moon'"):
        run_study([[10, 10]], ["moon"], ["poisson_dst"])
    with pytest.raises(ConfigError, match="method 'magic'"):
        run_study([[10, 10]], ["cap"], ["magic"])


def test_every_scenario_is_finite_and_reproducible():
    for name in SCENARIOS:
        a, b = make_scene(name, 24, 32, seed=3), make_scene(name, 24, 32, seed=3)
        assert (a.depth_mm >= 0).all()
        assert (a.gx[~pd.isna(a.gx)] == b.gx[~pd.isna(b.gx)]).all()


def test_study_target_only_when_enabled():
    scenes = {"s": {"sensor": "digit", "printer": "ender3"}}
    off = validate_config({"scenes": scenes})
    on = validate_config({"scenes": scenes, "integration_study": {"enabled": True}})
    assert not set(INTEGRATION_STUDY_TARGETS) & set(study_targets(off))
    assert set(INTEGRATION_STUDY_TARGETS) <= set(study_targets(on))
    assert on["integration_study"]["sizes"] == [[240, 320]]
    with pytest.raises(ConfigError, match="integration_study: unknown key 'size'"):
        validate_config({"scenes": scenes, "integration_study": {"size": [[1, 2]]}})


def test_method_pixel_limit_skips_large_grids_for_that_method_only():
    table = run_study(
        sizes=[(8, 10), (16, 20)],
        scenarios=["cap"],
        methods=["poisson_dct", "lstsq_sparse"],
        dtypes=["float64"],
        repeats=1,
        method_max_pixels={"lstsq_sparse": 100},
    )
    cells = set(zip(table["method"], table["H"], strict=True))
    assert cells == {("poisson_dct", 8), ("poisson_dct", 16), ("lstsq_sparse", 8)}
