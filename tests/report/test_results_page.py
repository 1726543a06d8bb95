"""The results page (docs/results.md) written from a results folder: against synthetic results
trees in the formats the study writes, and the committed page's layout against the generator's."""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping
from pathlib import Path

import pandas as pd
import pytest

from threedcal.cli import main
from threedcal.depth.study import reading
from threedcal.errors import ConfigError
from threedcal.evaluate.ablation import TEST_COLUMNS
from threedcal.evaluate.real_check import FINETUNED, SHIPPED, TABLE_COLUMNS
from threedcal.evaluate.sim2real_settings import ERROR_COLUMNS
from threedcal.report.results_page import page_layout, results_page, write_results_page
from threedcal.report.sections.ablation import short_equivalence
from threedcal.report.sections.markdown import SIM_COLUMN, SIM_READINGS, markdown_table
from threedcal.report.stage_times import study_span
from threedcal.study.config import load_config, validate_config
from threedcal.study.paths import (
    has_ablation,
    has_objects,
    has_sim2real,
    is_magnetic_scene,
    write_scene_record,
)
from threedcal.study.quick_arms import arms_table, verdicts

REPO = Path(__file__).resolve().parents[2]
BENCH_HEADER = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
# One fixed end time for every benchmark file, so the page's date is known.
END = 1_800_000_000  # 2027-01-15 08:00 UTC


def bench(path: Path, wall: float, end: float = END) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(BENCH_HEADER + f"{wall}\t0:00:00\t500\t0\t0\t0\t0\t0\t0\t{wall / 2}\n")
    os.utime(path, (end, end))


def write_objects(root: Path, scene: Mapping) -> None:
    """objects/errors.csv: per object, P and protocol, each figure with its _lo/_hi."""
    rows = []
    for i, obj in enumerate(scene["objects"]):
        for p in scene["ablation"]["fractions"]:
            for protocol, shift in (("printer", 0.0), ("paper", -20.0)):
                row = {"object": obj, "P": p, "protocol": protocol, "presses": 10, "replicates": 3}
                for metric, value in (
                    ("overall_um", 20.0),
                    ("type1_um", 5.0),
                    ("type2_um", 60.0 + 10 * i + p / 10 + shift),
                ):
                    row |= {metric: value, f"{metric}_lo": value - 4, f"{metric}_hi": value + 4}
                rows.append(row | {"depth_ratio": 1.0})
    (root / "objects").mkdir(parents=True, exist_ok=True)
    pd.DataFrame(rows).to_csv(root / "objects/errors.csv", index=False)


def write_learning_curve(stats: Path, points: Mapping, answer, low, high) -> None:
    """stats/learning_curve.csv's rows the reports read: the answer, its level, each fraction."""
    rows = [
        {"quantity": "points_within_margin", "value": answer, "low": low, "high": high}
        | {"note": "fitted"},
        {"quantity": "level", "value": 0.9},
    ]
    rows += [{"quantity": "observed_mse", "P": p, "points": n} for p, n in points.items()]
    pd.DataFrame(rows).to_csv(stats / "learning_curve.csv", index=False)


def write_stats(root: Path, scene: Mapping) -> None:
    """stats/: error_vs_cost.csv, tests.csv (four families), recommendation.txt, convergence.csv."""
    stats = root / "stats"
    stats.mkdir(parents=True, exist_ok=True)
    fractions = scene["ablation"]["fractions"]
    pd.DataFrame(
        [
            {
                "P": p,
                "points": 13 * p,
                "mean_mse": 0.008 + 0.001 / p,
                "mean_mse_low": 0.007,
                "mean_mse_high": 0.010,
                "replicates": 3,
                "probing_h": 0.0125 * p,
                "training_min": 1.5,
            }
            for p in fractions
        ]
    ).to_csv(stats / "error_vs_cost.csv", index=False)
    common = {"replicates": 3, "n": 267, "blocks": 6}
    rows = []
    for p in fractions[:-1]:
        for replicate in range(3):
            for test in ("t", "mannwhitney"):
                rows.append(
                    {"family": "paper", "test": test, "P": p, "replicate": replicate}
                    | {"against": replicate, "relative_change": 0.3, "significant": p == 1}
                    | {"conclusion": "worse" if p == 1 else "no significant difference"}
                )
        change = 0.30 if p == 1 else 0.05
        rows.append(
            {"family": "paired", "test": "block_mixed_t", "P": p, **common}
            | {"estimate": change / 100, "relative_change": change, "ci_low": -0.1}
            | {"ci_high": 0.2, "p_adjusted": 0.4, "significant": False}
            | {"conclusion": "no significant difference"}
        )
        rows.append(
            {"family": "equivalence", "test": "tost", "P": p, **common}
            | {"estimate": change / 100, "relative_change": change, "ci_low": -0.05}
            | {"ci_high": 0.15, "significant": False}
            | {"conclusion": "not equivalent: the interval is wider than the margin allows"}
        )
    rows += [
        {"family": "placebo", "test": test, "P": 80, "replicate": 1, "against": 0}
        | {"relative_change": -0.12, "significant": test == "mannwhitney"}
        for test in ("t", "mannwhitney")
    ]
    pd.DataFrame(rows, columns=TEST_COLUMNS).to_csv(stats / "tests.csv", index=False)
    (stats / "recommendation.txt").write_text(
        "probe at least 1040 points (P = 80 %): no smaller fraction is shown equivalent within a "
        "10 % margin of mean validation MSE; ... (90 % interval, TOST at alpha = 0.05; 3 "
        "replicate(s), 6 spatial blocks)\n"
        "learning curve: 400 points (90 % interval 300 to 520) bring ...\n"
        "the readings differ: the TOST says 1040 points (P = 80 %), the curve 400 ...\n"
    )
    write_learning_curve(stats, {p: 13 * p for p in fractions}, 400, 300, 520)
    if scene["ablation"].get("convergence"):
        pd.DataFrame(
            {
                "P": [fractions[0], 80],
                "replicates": [3, 3],
                "steps": [2000, 2000],
                "budget_mse": [0.0126, 0.0070],
                "twice_steps": [4000, 4000],
                "twice_mse": [0.0098, 0.0068],
                "change": [-0.2205, -0.0286],
                "ci_low": [-0.25, -0.04],
                "ci_high": [-0.19, -0.017],
            }
        ).to_csv(stats / "convergence.csv", index=False)
        (stats / "twice").mkdir()
        (stats / "twice/recommendation.txt").write_text("probe at least 150 points: P = 10 %\n")


def write_real(root: Path, scene: Mapping) -> None:
    """ball_eval.json and, with sim_to_real, sim2real/errors.csv."""
    model = {
        "gradient_rmse": 0.0896,
        "cap_depth_mae_um": 79.1,
        "interval95": {"gradient_rmse": [0.0842, 0.0954], "cap_depth_mae_um": [65.1, 94.4]},
        "n_test_images": 42,
    }
    lookup = model | {"gradient_rmse": 0.322, "cap_depth_mae_um": 155.9, "interval95": {}}
    root.mkdir(parents=True, exist_ok=True)
    (root / "ball_eval.json").write_text(
        json.dumps(model | {"preset": "multiscale", "lookup": lookup, "protocol": {"folds": 6}})
    )
    if not has_sim2real(scene):
        return
    rows = []
    for k, condition, mae in (
        ("8", "sim+real", 91.0),
        ("8", "real-only", 110.0),
        ("8", "shipped+real", 100.0),
    ):
        for fold in ("0", "1", "2", "all"):
            rows.append(
                {"k": k, "n_train": 8, "condition": condition, "fold": fold}
                | {"n_test_images": 7, "gradient_rmse": 0.1, "cap_depth_mae_um": mae}
                | {"gradient_rmse_lo": 0.09, "gradient_rmse_hi": 0.11}
                | {"cap_depth_mae_um_lo": mae - 10, "cap_depth_mae_um_hi": mae + 10}
            )
    (root / "sim2real").mkdir()
    pd.DataFrame(rows, columns=list(ERROR_COLUMNS)).to_csv(
        root / "sim2real/errors.csv", index=False
    )


def write_reskin(root: Path) -> None:
    figures = {"median_error_mm": 0.256, "p90_error_mm": 0.670, "depth_mae_mm": 0.0772}
    per_depth = {
        "1": {"median_error_mm": 0.276, "p90_error_mm": 0.764, "depth_mae_mm": 0.0466},
        "2": {"median_error_mm": 0.279, "p90_error_mm": 1.001, "depth_mae_mm": 0.0982},
    }
    root.mkdir(parents=True, exist_ok=True)
    (root / "reskin_eval.json").write_text(
        json.dumps(
            figures
            | {"n_test_coordinates": 38, "n_test_readings": 1140, "per_depth": per_depth}
            | {"mean_error_mm": 0.34, "seed": 0}
        )
    )


def write_real_check(results: Path, config: Mapping) -> None:
    """real_check/table.csv: the shipped weights on every set, fine-tuned where it has labels."""
    rows = []
    for i, entry in enumerate(config["real_check"]["sets"]):
        reads = [(SHIPPED, "held-out half", 21), (SHIPPED, "all", 42)]
        reads += [(FINETUNED, "held-out half", 21)] if "ball" in entry["real"] else []
        for weights, which, frames in reads:
            rows.append(
                {"set": entry["real"], "sensor": entry["sensor"], "weights": weights}
                | {"frames_read": which, "located": "labels", "frames": frames}
                | {"within_bound": 0.9 + i / 100, "area_ratio_median": 0.71, "area_ratio_p90": 0.93}
                | {"centroid_error_mm_median": 0.12, "centroid_error_mm_p90": 0.3}
                | {"centroid_within_0p2mm": 0.8, "peak_mm_median": 1.1, "allowed_mm_median": 1.9}
                | {"peak_within": 1.0}
            )
    (results / "real_check").mkdir()
    pd.DataFrame(rows, columns=list(TABLE_COLUMNS)).to_csv(results / "real_check/table.csv")


def build_results(results: Path, config: Mapping, skip: tuple[str, ...] = ()) -> Path:
    """A finished study's results folder for `config` (validated), every file the page reads in
    the study's format; `skip`: leaves (relative to results/) not to write."""
    for name, scene in config["scenes"].items():
        root = results / name
        write_scene_record(name, scene, root / "scene.json")
        if is_magnetic_scene(scene):
            write_reskin(root)
        else:
            (root / "models").mkdir(parents=True, exist_ok=True)
            (root / "models/inference.json").write_text(
                json.dumps(
                    {"preset": scene["model"]["preset"], "frames_per_s": 15.59}
                    | {"ms_per_frame": 64.12, "image_shape": [320, 240], "torch_threads": 1}
                )
            )
        if scene.get("import"):
            write_real(root, scene)
        if has_objects(scene):
            write_objects(root, scene)
        if has_ablation(scene):
            write_stats(root, scene)
            for p in scene["ablation"]["fractions"]:
                bench(root / f"benchmarks/train_P{p}_r0.tsv", 60.0)
        bench(root / "benchmarks/scene.tsv", 1.0, END - 600)
    environment = {"platform": "Linux-test", "processor": "x86_64", "cpu_count": 2, "seed": 0}
    environment |= {"scene_seeds": {name: 0 for name in config["scenes"]}}
    environment |= {"software": {"python": "3.11.7", "threedcal": "0.1.0", "torch": "2.13.0"}}
    (results / "environment.json").write_text(json.dumps(environment))
    if config.get("integration_study", {}).get("enabled"):
        table = pd.DataFrame(
            {
                "method": ["poisson_dst", "poisson_dct"],
                "scenario": ["hemisphere", "hemisphere"],
                "H": [240, 240],
                "W": [320, 320],
                "dtype": ["float32", "float32"],
                "ms_per_frame": [1.75, 1.05],
                "rmse": [0.0623, 0.0620],
            }
        )
        (results / "integration").mkdir()
        (results / "integration/reading.md").write_text(reading(table))
    if config.get("real_check"):
        write_real_check(results, config)
    bench(results / "benchmarks/summary.tsv", 2.0)
    for leaf in skip:
        (results / leaf).unlink()
    return results


SMALL = {
    "seed": 0,
    "integration_study": {"enabled": True},
    "scenes": {
        "sim": {
            "sensor": "digit",
            "printer": "ender3",
            "objects": ["pill", "pawn"],
            "ablation": {"fractions": [1, 20, 80], "replicates": 3, "convergence": True},
        },
        "real": {
            "sensor": "gelsight_mini",
            "import": {"format": "ball_folder", "path": "data/gelsight_ball_fots"},
            "sim_to_real": {"enabled": True, "folds": [0, 1, 2]},
        },
        "mag": {"sensor": "reskin", "printer": "ender3", "plan": {"pattern": "cross"}},
    },
    "real_check": {
        "sets": [
            {"real": "data/digit_frames_fots", "sensor": "digit_fots"},
            {"real": "data/gelsight_ball_fots", "sensor": "gelsight_mini"},
        ]
    },
}


@pytest.fixture
def small(tmp_path):
    config = validate_config(SMALL)
    return build_results(tmp_path / "results", config), config


def section(text: str, heading: str) -> str:
    start = text.index(f"\n{heading}\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end > 0 else None]


def test_committed_page_has_the_generators_layout(tmp_path):
    """docs/results.md and the generator agree on every heading and table column (not on the
    figures, which vary by host): regenerate the page (`make results-page`) after changing
    either."""
    results = build_results(tmp_path / "results", load_config(REPO / "config.yaml"))
    generated = page_layout(results_page(results))
    committed = page_layout((REPO / "docs/results.md").read_text())
    assert committed == generated


def test_the_committed_page_is_short_and_carries_no_commit():
    """The docs carry commit hashes only in the changelog; the page stays within its share of
    the docs' word budget."""
    text = (REPO / "docs/results.md").read_text()
    assert len(text.split()) <= 2200  # 1,800 before the quick calibration and real-check tables
    assert "commit" not in text.lower()
    assert not re.search(r"\b[0-9a-f]{7,40}\b", text)


def table_blocks(part: str) -> list[tuple[str, str]]:
    """(the lines above a table since the previous table or heading, its header row) per table."""
    lines, blocks, above = part.splitlines(), [], []
    for i, line in enumerate(lines):
        if line.startswith("#"):
            above = []
        elif line.startswith("|") and i + 1 < len(lines) and lines[i + 1].startswith("|---"):
            blocks.append(("\n".join(above), line))
            above = []
        elif not line.startswith("|"):
            above.append(line)
    return blocks


def test_every_table_names_its_protocol_and_whether_the_simulator_made_its_frames(small):
    text = results_page(small[0])
    figures = [
        "## Test objects: Type 2 MAE (µm), P = 20 %",
        "## How many points to probe: validation MSE against P = 80 %",
        "## Has the training converged? Twice the budget",
        "## Real frames: cross-validated accuracy",
        "## ReSkin: where the probe touched",
        "## Inference speed",
        "## Depth integrators",
    ]
    for heading in figures:
        part = section(text, heading)
        assert "Protocol:" in part, heading
        if heading == "## Depth integrators":  # analytic fields, said in its protocol line
            assert "no simulator and no model" in part
            continue
        for above, header in table_blocks(part):
            said = f"{header}\n{above}"
            assert SIM_COLUMN in said or SIM_READINGS in said, (heading, header)


def test_a_column_the_same_on_every_row_becomes_a_line_and_one_that_varies_stays():
    header = ["scene", SIM_COLUMN, "protocol", "figure"]
    same = markdown_table(header, [["`a`", "yes", "printer", "1"], ["`b`", "yes", "printer", "2"]])
    assert same[0] == f"Every row: *{SIM_COLUMN}* yes; *protocol* printer."
    assert same[2] == "| scene | figure |"
    varies = markdown_table(
        header, [["`a`", "yes", "printer", "1"], ["`b`", "no (real images)", "x", "2"]]
    )
    assert varies[0] == f"| scene | {SIM_COLUMN} | protocol | figure |"
    # a measured column the same on every row stays a column
    assert markdown_table(["P %", "figure"], [["1", "5"], ["2", "5"]])[0] == "| P % | figure |"


def test_equivalence_verdicts_in_short():
    assert short_equivalence("equivalent") == "equivalent"
    assert (
        short_equivalence("not equivalent: worse by more than the margin")
        == "not equivalent (worse)"
    )
    assert (
        short_equivalence(
            "not equivalent: the interval reaches past the margin on the worse side (too little "
            "power)"
        )
        == "not equivalent (power)"
    )
    assert (
        short_equivalence("not equivalent: the estimate lies past the margin on the worse side")
        == "not equivalent (estimate worse)"
    )
    assert short_equivalence("not equivalent: a larger P is not") == "not equivalent (larger P)"
    assert short_equivalence("something new") == "something new"


def test_the_page_reads_each_figure_from_the_results(small):
    results, _ = small
    text = results_page(results)
    # provenance: threedcal, host, the last job's end (benchmark files); no commit
    assert "threedcal 0.1.0; torch 2.13.0; host Linux-test, x86_64, 2 CPUs" in text
    assert "last job ended 2027-01-15 08:00 UTC" in text
    assert "commit" not in text
    # scenes in the study's order, each with whether the simulator made its frames
    assert "| `sim` | digit | ender3 | yes |" in text
    assert "| `real` | gelsight_mini | — | no (real images, `data/gelsight_ball_fots`) |" in text
    assert "| `mag` | reskin | ender3 | yes (readings) |" in text
    assert text.index("| `sim` |") < text.index("| `real` |") < text.index("| `mag` |")
    # objects at P = 20 %: Type 2 with intervals, printer first, then paper; one scene, one line
    objects = section(text, "## Test objects: Type 2 MAE (µm), P = 20 %")
    assert f"Every row: *scene* `sim`; *{SIM_COLUMN}* yes." in objects
    assert "| protocol | pill | pawn |" in objects
    assert "| **printer** | 62 [58, 66] | 72 [68, 76] |" in objects
    assert "| paper | 42 [38, 46] | 52 [48, 56] |" in objects
    assert "| pill | 60 (1) | 68 (80) |" in objects  # lowest and highest over P = 1, 20, 80
    assert "10 presses per object and 3 models per P (`sim`)" in objects
    # the ablation: MSE per P, the paired test's 1 - alpha interval, equivalence in short
    ablation = section(text, "## How many points to probe: validation MSE against P = 80 %")
    assert "| 1 (13) | 0.00900 | +30.0 [-10.0, +20.0] | not equivalent (power) [-5.0, +15.0] |" in (
        ablation
    )
    assert "| 80 (1040) | 0.00801 | reference |" in ablation
    assert "1 − stats.alpha interval (99 % by default)" in ablation
    # the equivalence level and margin as the recommendation recorded them
    assert "TOST within the 10 % margin, 90 % interval (1 − 2 × 0.05, as recorded)" in ablation
    assert "(power) the interval crosses it" in ablation
    assert (
        "- `sim`: probe at least 1040 points (P = 80 %); learning curve: 400 points (90 % "
        "interval 300 to 520) (the two differ: why in `stats/recommendation.txt`); placebo t "
        "0/1, U 1/1, means 12.0 %"
    ) in ablation
    # convergence
    assert "| 80 | 2000 / 4000 | 0.00700 | 0.00680 | -2.9 % [-4.0 %, -1.7 %] | 3 |" in text
    assert "- `sim` at twice: probe at least 150 points: P = 10 %" in text
    # real frames and sim-to-real: no simulator, or a simulator that pretrained only
    real = section(text, "## Real frames: cross-validated accuracy")
    assert f"*{SIM_COLUMN}* no (real images); *protocol* 6-fold grouped cross-validation." in real
    assert "| model (multiscale) | 0.090 [0.084, 0.095] | 79 [65, 94] | 42 |" in real
    assert "| colour lookup | 0.322 | 156 | 42 |" in real
    assert f"*{SIM_COLUMN}*: only to pretrain `sim+real`, `shipped+real`. Cells" in real
    assert "`shipped+real`: shipped weights, then k at their frame size" in real
    assert "*protocol* held-out folds 0, 1, 2." in real
    assert (
        "| 8 | 0.100 [0.090, 0.110]; 91 [81, 101] | 0.100 [0.090, 0.110]; 110 [100, 120] | — | "
        "0.100 [0.090, 0.110]; 100 [90, 110] |" in real
    )
    # ReSkin per depth, then all
    reskin = section(text, "## ReSkin: where the probe touched")
    assert f"*{SIM_READINGS}* yes; *protocol* 38 held-out probe coordinates (1140 readings)" in (
        reskin
    )
    assert "| 2 | 0.28 | 1.00 | 0.098 |" in reskin
    assert "| all | 0.26 | 0.67 | 0.077 |" in reskin
    # inference: vision scenes only; the threads, the same on every row, in one line
    speed = section(text, "## Inference speed")
    assert "Every row: *torch threads* 1." in speed
    assert "| `sim` | yes | compact | 15.6 | 64.1 | 320×240 |" in speed
    assert "`mag`" not in speed
    # where the time went: the span of the jobs and the stage table
    time = section(text, "## Where the time goes")
    assert "10.0 min from the first job's start to the last one's end" in time
    assert "| train (sim) | 3 | 3.0 |" in time
    assert (
        "threedcal 0.1.0; torch 2.13.0; host" in text
        and "(every version: `environment.json`)" in text
    )


def test_the_top_stages_then_the_others_and_the_total(tmp_path):
    results = tmp_path / "results"
    for i in range(10):
        bench(results / f"s/benchmarks/stage{i}.tsv", 60.0 * (i + 1))
    time = section(results_page(results), "## Where the time goes")
    rows = [line for line in time.splitlines() if line.startswith("| ")][1:]
    assert len(rows) == 8 + 2
    assert rows[0].startswith("| stage9 (s) | 1 | 10.0 |")
    assert rows[-2].startswith("| 2 other stages | 2 | 3.0 |")
    assert rows[-1] == "| **all** | 10 | 55.0 | 100 % |"


def test_the_equivalence_level_without_a_recorded_one_is_the_configs_default(small):
    results, _ = small
    (results / "sim/stats/recommendation.txt").write_text("probe at least 1040 points\n")
    ablation = section(
        results_page(results), "## How many points to probe: validation MSE against P = 80 %"
    )
    assert "1 − 2·stats.equivalence_alpha interval (90 % by default)" in ablation
    assert "within the recommendation's margin" in ablation


def test_the_links_are_to_the_moved_pages(small):
    links = set(re.findall(r"\]\(([^)]+)\)", results_page(small[0])))
    assert links == {
        "reference/outputs.md",
        "explanation/objects.md",
        "explanation/statistics.md",
        "explanation/real-data.md",
        "explanation/reskin.md",
        "explanation/depth.md",
    }


def test_a_missing_file_leaves_a_row_that_says_so_and_the_layout_stays(tmp_path):
    config = validate_config(SMALL)
    full = results_page(build_results(tmp_path / "a/results", config))
    missing = ("sim/stats/convergence.csv", "real/ball_eval.json", "mag/reskin_eval.json")
    partial = results_page(build_results(tmp_path / "b/results", config, missing))
    assert page_layout(partial) == page_layout(full)
    assert "| — | not in these results (`results/sim/stats/convergence.csv`) |" in partial
    assert "not in these results (`results/real/ball_eval.json`)" in partial
    assert "not in these results (`results/mag/reskin_eval.json`)" in partial


def test_sections_follow_what_the_scenes_ran(tmp_path):
    """A study of one simulated scene without an ablation: no objects, ablation, real-data or
    ReSkin section."""
    config = validate_config({"scenes": {"one": {"sensor": "digit", "printer": "ender3"}}})
    text = results_page(build_results(tmp_path / "results", config))
    headings = [line for line in page_layout(text) if line.startswith("#")]
    assert headings == [
        "# Results of the default study",
        "## Scenes",
        "## Inference speed",
        "## Where the time goes",
    ]
    assert "commit" not in text


def test_write_refuses_a_folder_without_scene_records_and_the_cli_writes_the_page(
    small, tmp_path, capsys
):

    with pytest.raises(ConfigError, match="no scene records"):
        write_results_page(tmp_path / "empty", tmp_path / "page.md")
    results, _ = small
    out = tmp_path / "page.md"
    assert main(["report", "results-page", str(results), "--out", str(out)]) == 0
    assert re.search(r"threedcal 0\.1\.0; (torch \S+; )?host Linux-test", out.read_text())
    assert main(["report", "stage-times", str(results)]) == 0
    assert "| train | sim | 3 |" in capsys.readouterr().out


def test_the_study_span_runs_from_the_first_jobs_start_to_the_last_jobs_end(tmp_path):
    assert study_span(tmp_path) is None
    bench(tmp_path / "a/benchmarks/collect.tsv", 100.0, END - 1000)
    bench(tmp_path / "benchmarks/summary.tsv", 2.0, END)
    assert study_span(tmp_path) == pytest.approx((END - 1100, END))


def write_arms(root: Path, full: str, mse_change: tuple, pawn: tuple) -> None:
    """quick/arms.json as the quick_arms stage writes it (threedcal.study.quick_arms.verdicts)."""
    rows = []
    points = (("quick", 5, 50), ("stopped", None, 50), ("scratch", 5, 50), ("full", None, 2956))
    for arm, round_, presses in points:
        base = {"arm": arm, "round": round_, "presses": presses, "printer_min": 3.2, "steps": 1500}
        base |= {"replicates": 1, "value": 1.0, "value_lo": 0.9, "value_hi": 1.1}
        change = (float("nan"),) * 3 if arm == "full" else mse_change
        change = tuple(c + (arm == "scratch") for c in change)
        rows.append(
            base
            | {"metric": "validation_mse", "object": ""}
            | dict(zip(("change", "change_lo", "change_hi"), change, strict=True))
        )
        for name, diff in (("pill", (1.0, -3.0, 5.0)), ("pawn", pawn)):
            rows.append(
                base
                | {"metric": "type2_um", "object": name}
                | dict(zip(("change", "change_lo", "change_hi"), diff, strict=True))
            )
    record = verdicts(arms_table(rows), root.name, full)
    (root / "quick").mkdir(parents=True, exist_ok=True)
    (root / "quick/arms.json").write_text(json.dumps(record))


def test_the_quick_table_reads_each_compared_scenes_verdicts(small, tmp_path):
    quick = {
        "sensor": "digit",
        "printer": "ender3",
        "plan": {"pattern": "quick", "depth_mm": 1.0, "registration": {"spacing_mm": 1.0}},
        "quick": {"compare_with": "sim"},
    }
    config = validate_config({**SMALL, "scenes": {**SMALL["scenes"], "q": quick}})
    results = build_results(tmp_path / "with_quick/results", config)
    part = section(results_page(results), "## Quick calibration")
    assert "not in these results (`results/q/quick/arms.json`)" in part
    write_arms(results / "q", "sim", (0.04, -0.02, 0.12), (12.0, 6.0, 18.0))
    part = section(results_page(results), "## Quick calibration")
    assert "Every row: *scene* `q` vs `sim`." in part  # one scene: its column becomes a line
    assert (
        "| 50, 3.2 | +4.0 % [-2.0, +12.0] (undecided) | +104.0 % [+98.0, +112.0] "
        "| pawn 12 [6, 18] (undecided) | met, met |"
    ) in part
    assert "## Quick calibration" not in results_page(small[0])  # no compared quick scene


def test_the_shipped_weights_on_real_frames_sit_under_real_frames(small):
    text = results_page(small[0])
    part = section(text, "## Real frames: cross-validated accuracy")
    assert "### The shipped weights on real frames: depth only where the ball is?" in part
    assert f"Every row: *{SIM_COLUMN}* pretraining only (real test frames)." in part
    assert "| `digit_frames_fots` | shipped | all | 42 | 90 % | 0.71 (0.93) | 0.12 (80 %) |" in part
    tuned = (
        "| `gelsight_ball_fots` | shipped, fine-tuned on the fitting half | held-out half | 21 |"
    )
    assert tuned in part and "| 91 % |" in part
    assert "fine-tuned" not in part.split("digit_frames_fots")[1].split("\n")[0]
    results = small[0]
    (results / "real_check/table.csv").unlink()
    assert "### The shipped weights on real frames" not in results_page(results)
