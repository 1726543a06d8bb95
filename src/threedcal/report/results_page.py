"""docs/results.md: the results page, written from a finished study's `results/` folder alone.

`threedcal report results-page` (and `make results-page`) call `write_results_page`. The scenes are
read from their own records (`results/{scene}/scene.json`, in the order of `environment.json`), so
the page needs no config and says only what that study ran. Every table says which protocol made
its figures and whether the simulator made both the training and the test frames.

A page section exists when some scene asks for it (its recorded config), whatever its files hold;
a missing file leaves a row that says so. So the page's layout (`page_layout`: headings and table
columns) depends on the scenes alone, and tests/report/test_results_page.py compares the committed
page's layout with the generator's.
"""

from __future__ import annotations

import datetime
import subprocess
from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from threedcal.config import convergence_fractions, training_fractions
from threedcal.config import is_imported as config_is_imported
from threedcal.report.stage_times import stage_time_lines, stage_times, study_span
from threedcal.report.summary import read_json, sim2real_rows
from threedcal.scenes import has_ablation, has_objects, has_sim2real

TITLE = "Results of the default study"
# The fraction whose test-object figures lead the page (the paper's Table II reports P = 20 %).
REPORTED_P = 20
SIMULATED = "yes"
# The column every table carries: did the simulator render both the frames trained on and those tested?
SIM_COLUMN = "simulator made training and test frames"
MISSING = "—"


# ---------------------------------------------------------------------------------------------
# The scenes, as the study recorded them


def load_scenes(results: str | Path) -> dict[str, dict]:
    """{scene: its record (scene.json: config, profiles, software)}, in the study's order."""
    results = Path(results)
    records = {path.parent.name: read_json(path) for path in sorted(results.glob("*/scene.json"))}
    environment = read_json(results / "environment.json") or {}
    order = [name for name in environment.get("scene_seeds", {}) if name in records]
    return {name: records[name] for name in order + sorted(set(records) - set(order))}


def _config(record: Mapping) -> dict:
    """The scene's config as the workflow's predicates read it (threedcal.scenes, .config); a
    record that wrote `import: null` for a scene that imports nothing counts as not imported."""
    config = dict(record.get("config") or {})
    if not config.get("import"):
        config.pop("import", None)
    return config


def _sensor_type(record: Mapping) -> str:
    """The recorded sensor profile's type (not looked up again: a profile given by path may not
    resolve where the page is written)."""
    sensor = (record.get("profiles") or {}).get("sensor") or {}
    return str(sensor.get("type", "vision"))


def is_magnetic(record: Mapping) -> bool:
    return _sensor_type(record) == "magnetic"


def is_imported(record: Mapping) -> bool:
    """Real images imported from a folder (no printer, no simulator)."""
    return config_is_imported(_config(record))


def is_simulated(record: Mapping) -> bool:
    """The simulated bench (`port: sim`) rendered both the frames trained on and those tested."""
    return not is_imported(record) and str(_config(record).get("port", "sim")) == "sim"


def frames_of(record: Mapping) -> str:
    """Where a scene's frames (a ReSkin's readings) came from, in words."""
    readings = "readings" if is_magnetic(record) else "frames"
    if is_imported(record):
        return f"real images ({_config(record)['import'].get('path', 'imported')})"
    if is_simulated(record):
        return f"simulated bench ({readings})"
    return f"real printer and sensor ({_config(record).get('port')})"


def simulated_cell(record: Mapping) -> str:
    """The SIM_COLUMN's cell of a scene's own figures."""
    if is_simulated(record):
        return SIMULATED
    return "no: real images" if is_imported(record) else "no: real sensor frames"


# ---------------------------------------------------------------------------------------------
# Formatting


def _table(header: list[str], rows: list[list[str]], align: str | None = None) -> list[str]:
    rule = align or "|" + "|".join("---" for _ in header) + "|"
    return ["| " + " | ".join(header) + " |", rule] + [
        "| " + " | ".join(str(cell) for cell in row) + " |" for row in rows
    ]


def _estimate(value, lo=None, hi=None, digits: int = 0) -> str:
    """'74 [70, 78]': a figure with its interval (the interval left out where it is unknown)."""
    if value is None or pd.isna(value):
        return MISSING
    text = f"{value:.{digits}f}"
    if lo is None or hi is None or pd.isna(lo) or pd.isna(hi):
        return text
    return f"{text} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _cross_validated(figures: Mapping, key: str, digits: int) -> str:
    """A figure of ball_eval.json with its interval95 bounds where it has them."""
    lo, hi = (figures.get("interval95", {}).get(key) or [None, None])[:2]
    return _estimate(figures.get(key), lo, hi, digits)


def _pct(value: float) -> str:
    return f"{value * 100:+.1f} %"


def _missing(path: Path, results: Path) -> str:
    return f"not in these results (`{path.relative_to(results.parent).as_posix()}`)"


# ---------------------------------------------------------------------------------------------
# Sections


def provenance_lines(results: Path, commit: str | None) -> list[str]:
    """Which commit, host and date produced the figures, from what the study recorded."""
    environment = read_json(results / "environment.json") or {}
    software = environment.get("software", {})
    host = ", ".join(
        str(part)
        for part in (
            environment.get("platform"),
            environment.get("processor"),
            environment.get("cpu"),
            f"{environment['cpu_count']} CPUs" if environment.get("cpu_count") else None,
            f"flags {environment['cpu_flags']}" if environment.get("cpu_flags") else None,
            f"limited by {environment['isa_limits']}"
            if environment.get("isa_limits", "none") != "none"
            else None,
            f"torch dispatches {environment['torch_cpu_capability']}"
            if environment.get("torch_cpu_capability")
            else None,
        )
        if part
    )
    span = study_span(results)
    when = (
        datetime.datetime.fromtimestamp(span[1], tz=datetime.timezone.utc).strftime(
            "%Y-%m-%d %H:%M UTC"
        )
        if span
        else None
    )
    facts = [
        f"commit {commit}" if commit else "commit not recorded",
        f"host {host}" if host else "host not recorded",
        f"last job ended {when}" if when else None,
        ", ".join(f"{k} {software[k]}" for k in ("threedcal", "torch") if k in software) or None,
    ]
    return [
        "Written by `threedcal report results-page` (`make results-page`) from the `results/` "
        f"folder of one finished study: {'; '.join(f for f in facts if f)}. Figures vary with the "
        "host (a CPU's floating-point kernels, its speed), so a study on another machine gives "
        "other digits; the tables' layout stays. Do not edit this page: regenerate it with "
        "`make results-page` (`RESULTS=path` for a study run elsewhere).",
        "",
    ]


def reading_lines() -> list[str]:
    return [
        f"Every table names its protocol, and its column *{SIM_COLUMN}* says whether the "
        "simulated bench rendered both the frames a model trained on and those it was tested on "
        f"(`{SIMULATED}`), or whether real images were involved. Intervals are 95 % unless a "
        "column says otherwise. The figures (PNG) that draw these tables sit beside their files "
        "in `results/` and in the study's report (`make report`); [outputs](outputs.md) lists "
        "every file.",
        "",
    ]


def scenes_section(scenes: Mapping[str, dict]) -> list[str]:
    rows = [
        [
            f"`{name}`",
            str(_config(record).get("sensor", MISSING)),
            frames_of(record),
            simulated_cell(record),
            str(_config(record).get("description", "")).replace("|", "/"),
        ]
        for name, record in scenes.items()
    ]
    return [
        "## Scenes",
        "",
        *_table(["scene", "sensor", "frames", SIM_COLUMN, "description"], rows),
        "",
    ]


def _objects_of(scenes: Mapping[str, dict]) -> list[str]:
    names: dict[str, None] = {}
    for record in scenes.values():
        if has_objects(_config(record)):
            names.update(dict.fromkeys(str(o) for o in _config(record)["objects"]))
    return list(names)


def objects_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """Type 2 MAE per object at P = 20 %, both protocols; then the printer protocol over every P."""
    chosen = {name: r for name, r in scenes.items() if has_objects(_config(r))}
    if not chosen:
        return []
    objects = _objects_of(chosen)
    fractions = sorted({p for r in chosen.values() for p in training_fractions(_config(r))})
    reported = REPORTED_P if REPORTED_P in fractions else max(fractions)
    head_rows, by_p_rows, notes = [], [], []
    for name, record in chosen.items():
        path = results / name / "objects" / "errors.csv"
        sim = simulated_cell(record)
        sensor = str(_config(record).get("sensor", MISSING))
        if not path.is_file():
            head_rows.append(
                [f"`{name}`", sensor, sim, MISSING, _missing(path, results)]
                + [MISSING] * (len(objects) - 1)
            )
            continue
        table = pd.read_csv(path)
        notes.append(
            f"`{name}`: {int(table['presses'].min())} reporting presses per object, "
            f"{int(table['replicates'].min()) if 'replicates' in table else 1} replicate model(s) "
            "per P"
        )
        for protocol in dict.fromkeys(table["protocol"]):
            rows = table[table["protocol"] == protocol]
            at = {r.object: r for r in rows[rows["P"] == reported].itertuples()}
            head_rows.append(
                [f"`{name}`", sensor, sim, f"**{protocol}**" if protocol == "printer" else protocol]
                + [
                    _estimate(at[o].type2_um, at[o].type2_um_lo, at[o].type2_um_hi)
                    if o in at
                    else MISSING
                    for o in objects
                ]
            )
            if protocol != "printer":
                continue
            for obj in objects:
                part = rows[rows["object"] == obj].set_index("P")
                by_p_rows.append(
                    [f"`{name}`", sim, protocol, obj]
                    + [
                        f"{part.loc[p, 'type2_um']:.0f}" if p in part.index else MISSING
                        for p in fractions
                    ]
                )
    lines = [
        f"## Test objects: Type 2 MAE (µm), P = {reported} %",
        "",
        "Each object pressed into the gel by the printer, its depth predicted by the models of "
        f"P = {reported} % and compared with the CAD ground truth over the contact (Type 2: the "
        "error where the object touches; [objects](objects.md)). Protocol `printer`: the ground "
        "truth placed where the printer put the object (the scene's registration and touch "
        "height), nothing fitted. Protocol `paper`: the paper's, aligned by cross-correlation "
        "and its depth fitted to the prediction. Each figure is the mean over the reporting "
        "presses and the replicate models [95 % interval, presses and models both random]; "
        + "; ".join(notes)
        + ".",
        "",
        *_table(["scene", "sensor", SIM_COLUMN, "protocol", *objects], head_rows),
        "",
        "Across the ablation (protocol `printer`, Type 2 MAE µm, the mean over presses and "
        "replicates; `objects/errors.csv` holds Type 1, overall and the intervals):",
        "",
        *_table(
            ["scene", SIM_COLUMN, "protocol", "object", *(f"P = {p} %" for p in fractions)],
            by_p_rows,
        ),
        "",
    ]
    return lines


def ablation_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """Validation MSE per fraction against P = 80 %, the recommendation, the placebo's spread."""
    from threedcal.evaluate.ablation_reading import placebo_summary

    chosen = {name: r for name, r in scenes.items() if has_ablation(_config(r))}
    if not chosen:
        return []
    rows, notes = [], []
    for name, record in chosen.items():
        stats = results / name / "stats"
        sim = simulated_cell(record)
        costs_path, tests_path = stats / "error_vs_cost.csv", stats / "tests.csv"
        if not costs_path.is_file() or not tests_path.is_file():
            missing = costs_path if not costs_path.is_file() else tests_path
            rows.append([f"`{name}`", sim, MISSING, MISSING, _missing(missing, results)])
            rows[-1] += [MISSING] * 3
            continue
        costs = pd.read_csv(costs_path).set_index("P")
        tests = pd.read_csv(tests_path)
        paired = tests[tests["family"] == "paired"].set_index("P")
        equivalence = tests[tests["family"] == "equivalence"].set_index("P")
        paper = tests[tests["family"] == "paper"]
        for p in costs.index:
            cost = costs.loc[p]
            row = [
                f"`{name}`",
                sim,
                str(p),
                str(int(cost["points"])),
                _estimate(cost["mean_mse"], cost["mean_mse_low"], cost["mean_mse_high"], 5),
            ]
            if p in paired.index:
                pair, eq = paired.loc[p], equivalence.loc[p] if p in equivalence.index else None
                row.append(
                    f"{_pct(pair['relative_change'])} [{_pct(pair['ci_low'])}, "
                    f"{_pct(pair['ci_high'])}], {pair['conclusion']} "
                    f"(p = {pair['p_adjusted']:.3g})"
                )
                row.append(
                    MISSING
                    if eq is None
                    else f"{eq['conclusion']} [{_pct(eq['ci_low'])}, {_pct(eq['ci_high'])}]"
                )
                part = paper[paper["P"] == p]
                significant = part["significant"].astype(bool)
                row.append(
                    " / ".join(
                        f"{int(significant[part['test'] == t].sum())}/"
                        f"{part.loc[part['test'] == t, 'replicate'].nunique()}"
                        for t in ("t", "mannwhitney")
                    )
                )
            else:
                row += ["(the reference)", MISSING, MISSING]
            rows.append(row)
        recommendation = stats / "recommendation.txt"
        notes.append(
            f"- `{name}` ({'simulated' if sim == SIMULATED else 'real'} frames): "
            + (
                recommendation.read_text().strip()
                if recommendation.is_file()
                else _missing(recommendation, results)
            )
            + "."
        )
        placebo = placebo_summary(tests)
        if placebo:
            notes.append(f"  Placebo: {placebo}.")
    return [
        "## How many points to probe: validation MSE against P = 80 %",
        "",
        "Protocol: each training fraction P (percent of the probe points) trained as several "
        "replicate models, each scored by its gradient MSE at the validation probe coordinates, "
        "which no P trains on, and paired with P = 80 % on the same coordinates "
        "([statistics](statistics.md)). *Change*: the paired test's estimate of the "
        "change of mean MSE, spatial blocks and replicates as random effects (95 % interval, "
        "Holm over the fractions). *Equivalence*: the TOST behind the recommendation, within the "
        "margin the recommendation names (90 % interval). *Paper's tests*: replicates in which the paper's t-test / Mann-Whitney U call P different.",
        "",
        *_table(
            [
                "scene",
                SIM_COLUMN,
                "P %",
                "points",
                "mean validation MSE [lowest, highest replicate]",
                "change against P = 80 % [95 %]",
                "equivalence [90 %]",
                "paper's tests t / U",
            ],
            rows,
        ),
        "",
        "The recommendation (`stats/recommendation.txt`) and the placebo (two trainings of "
        "P = 80 %: how far apart training noise alone puts them):",
        "",
        *notes,
        "",
    ]


def convergence_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    chosen = {name: r for name, r in scenes.items() if convergence_fractions(_config(r))}
    if not chosen:
        return []
    rows = []
    for name, record in chosen.items():
        path = results / name / "stats" / "convergence.csv"
        sim = simulated_cell(record)
        if not path.is_file():
            rows.append([f"`{name}`", sim, MISSING, _missing(path, results)] + [MISSING] * 4)
            continue
        for row in pd.read_csv(path).itertuples():
            rows.append(
                [
                    f"`{name}`",
                    sim,
                    str(row.P),
                    str(row.study_steps),
                    f"{row.study_mse:.5f}",
                    str(row.twice_steps),
                    f"{row.twice_mse:.5f}",
                    _pct(row.change),
                ]
            )
    return [
        "## Has the training converged? Twice the budget",
        "",
        "Protocol: replicate 0 of P = 80 % and of the smallest P trained again with twice the "
        "stopping rule's budget, both scored on the validation coordinates (mean validation "
        "MSE; `stats/convergence.csv`, [statistics](statistics.md)). A large drop at twice the "
        "budget means the study's models stopped short.",
        "",
        *_table(
            [
                "scene",
                SIM_COLUMN,
                "P %",
                "steps",
                "validation MSE",
                "steps at 2x",
                "validation MSE at 2x",
                "change",
            ],
            rows,
        ),
        "",
    ]


def real_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """Imported scenes: the cross-validated figures, then sim-to-real."""
    chosen = {name: r for name, r in scenes.items() if is_imported(r)}
    if not chosen:
        return []
    rows = []
    for name, record in chosen.items():
        path = results / name / "ball_eval.json"
        sim = simulated_cell(record)
        ball = read_json(path)
        if ball is None:
            rows.append([f"`{name}`", sim, MISSING, MISSING, _missing(path, results), MISSING])
            rows[-1].append(MISSING)
            continue
        folds = (ball.get("protocol") or {}).get("folds")
        protocol = f"{folds}-fold grouped cross-validation" if folds else "held-out images"
        for method, figures in (
            (f"model ({ball.get('preset', 'model')})", ball.get("model", ball)),
            ("colour lookup", ball.get("lookup")),
        ):
            if not figures:
                continue
            rows.append(
                [
                    f"`{name}`",
                    sim,
                    protocol,
                    method,
                    _cross_validated(figures, "gradient_rmse", 3),
                    _cross_validated(figures, "cap_depth_mae_um", 0),
                    str(figures.get("n_test_images", ball.get("n_test_images", MISSING))),
                ]
            )
    lines = [
        "## Real frames: cross-validated accuracy",
        "",
        "Protocol: the imported images split into folds that keep each press's images together; "
        "every image is tested once, by the model trained without its fold. Error inside each "
        "contact's evaluation circle, 95 % interval from a bootstrap over press groups "
        "([real data](real_data.md)). No simulator: real images for training and test.",
        "",
        *_table(
            [
                "scene",
                SIM_COLUMN,
                "protocol",
                "method",
                "gradient RMSE [95 %]",
                "cap depth MAE µm [95 %]",
                "test images",
            ],
            rows,
        ),
        "",
    ]
    lines += sim2real_section(
        {n: r for n, r in chosen.items() if has_sim2real(_config(r))}, results
    )
    return lines


def sim2real_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    if not scenes:
        return []
    cells = {
        "sim+real": "no: pretrained on simulated presses, fine-tuned and tested on real images",
        "real-only": "no: real images",
        "scene model": "no: real images",
    }
    rows = []
    for name in scenes:
        path = results / name / "sim2real" / "errors.csv"
        if not path.is_file():
            rows.append([f"`{name}`", MISSING, MISSING, _missing(path, results), MISSING, MISSING])
            continue
        errors = pd.read_csv(path, dtype={"k": str, "fold": str})
        folds = sorted(set(errors["fold"]) - {"all"}, key=int)
        protocol = f"held-out real images of folds {', '.join(folds)}"
        for k, condition, rmse, mae in sim2real_rows(errors[errors["fold"] == "all"]):
            rows.append(
                [
                    f"`{name}`",
                    protocol,
                    cells.get(condition, MISSING),
                    f"{condition}, k = {k}",
                    rmse,
                    mae,
                ]
            )
    return [
        "### Sim-to-real: k real images, with and without simulated pretraining",
        "",
        "Protocol: for each of the listed folds, the simulator's optics fitted to that fold's "
        "training images (never its test images); `sim+real` pretrains on simulated presses and "
        "fine-tunes on k real training images, `real-only` trains on the same k alone, "
        "`scene model` is the scene's own cross-validated model. All are tested on the fold's "
        "held-out real images (95 % interval over press groups).",
        "",
        *_table(
            [
                "scene",
                "protocol",
                SIM_COLUMN,
                "condition",
                "gradient RMSE [95 %]",
                "cap depth MAE µm [95 %]",
            ],
            rows,
        ),
        "",
    ]


def reskin_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    chosen = {name: r for name, r in scenes.items() if is_magnetic(r)}
    if not chosen:
        return []
    rows = []
    for name, record in chosen.items():
        path = results / name / "reskin_eval.json"
        sim = simulated_cell(record).replace("frames", "readings")
        figures = read_json(path)
        if figures is None:
            rows.append([f"`{name}`", sim, _missing(path, results)] + [MISSING] * 4)
            continue
        protocol = (
            f"{figures.get('n_test_coordinates', '?')} held-out probe coordinates "
            f"({figures.get('n_test_readings', '?')} readings)"
        )
        per_depth = figures.get("per_depth") or {}
        for depth, part in [
            *sorted(per_depth.items(), key=lambda kv: float(kv[0])),
            ("all", figures),
        ]:
            rows.append(
                [
                    f"`{name}`",
                    sim,
                    protocol,
                    depth,
                    f"{part['median_error_mm']:.2f}",
                    f"{part['p90_error_mm']:.2f}",
                    f"{part['depth_mae_mm']:.3f}",
                ]
            )
    return [
        "## ReSkin: where the probe touched",
        "",
        "Protocol: the magnetic readings of probe presses along the authors' cross plan; an MLP "
        "learns contact position and depth, scored on probe coordinates it never trained on "
        "(the error of x, y in mm; [ReSkin](reskin.md)).",
        "",
        *_table(
            [
                "scene",
                SIM_COLUMN.replace("frames", "readings"),
                "protocol",
                "press depth mm",
                "median error mm",
                "p90 error mm",
                "depth MAE mm",
            ],
            rows,
        ),
        "",
    ]


def inference_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    chosen = {name: r for name, r in scenes.items() if not is_magnetic(r)}
    if not chosen:
        return []
    rows = []
    for name, record in chosen.items():
        path = results / name / "models" / "inference.json"
        fps = read_json(path)
        sim = simulated_cell(record)
        if fps is None:
            rows.append([f"`{name}`", sim, _missing(path, results)] + [MISSING] * 4)
            continue
        shape = fps.get("image_shape") or []
        rows.append(
            [
                f"`{name}`",
                sim,
                str(fps.get("preset", MISSING)),
                f"{fps['frames_per_s']:.1f}",
                f"{fps['ms_per_frame']:.1f}",
                " × ".join(str(s) for s in shape) if shape else MISSING,
                str(fps.get("torch_threads", MISSING)),
            ]
        )
    return [
        "## Inference speed",
        "",
        "Protocol: replicate 0 of the scene's largest training fraction turns frames of its own "
        "dataset into depth maps (gradients, then integration) on this host's CPU, one frame at "
        "a time after a warm-up (`models/inference.json`).",
        "",
        *_table(
            [
                "scene",
                SIM_COLUMN,
                "model preset",
                "frames/s",
                "ms per frame",
                "image px (H × W)",
                "torch threads",
            ],
            rows,
        ),
        "",
    ]


def integrators_section(results: Path) -> list[str]:
    reading = results / "integration" / "reading.md"
    if not reading.is_file():
        return []
    body = [line for line in reading.read_text().splitlines() if not line.startswith("# ")]
    body = "\n".join(body).strip().splitlines()
    return [
        "## Depth integrators",
        "",
        "Protocol: gradient fields of analytic surfaces (exact, or with the noise, outliers or "
        "border contact that the scenario names), no simulator and no model; each integrator's "
        "depth against the analytic truth ([depth](depth.md), `integration/error_vs_time.csv`).",
        "",
        *[f"#{line}" if line.startswith("## ") else line for line in body],
        "",
    ]


def time_section(results: Path) -> list[str]:
    span = study_span(results)
    table = stage_times(results)
    duration = (
        f"From the first job's start to the last job's end {(span[1] - span[0]) / 60:.1f} min "
        "(from the benchmark files' times: a study resumed over several sessions spans them "
        "all); "
        if span
        else ""
    )
    work = f"{table['wall_s'].sum() / 60:.1f} job-minutes in all. " if not table.empty else ""
    return [
        "## Where the time goes",
        "",
        f"{duration}{work}Each stage's jobs summed from their `benchmark:` files; jobs run side "
        "by side, so the summed wall time is work, not duration. The CPU column undercounts: "
        "Snakemake samples a job's CPU time now and then and misses what it used after the last "
        "sample.",
        "",
        *stage_time_lines(table),
        "",
    ]


def environment_section(results: Path) -> list[str]:
    environment = read_json(results / "environment.json")
    if not environment:
        return []
    rows = [[k, str(v)] for k, v in environment.items() if not isinstance(v, dict)]
    rows += [[k, str(v)] for k, v in environment.get("software", {}).items()]
    return ["## Run environment", "", *_table(["", ""], rows), ""]


# ---------------------------------------------------------------------------------------------
# The page


def study_commit(results: str | Path) -> str | None:
    """The commit of the git checkout that holds `results/`, in words (its short hash, whether
    tracked files differ from it), or None outside a checkout."""
    folder = Path(results).resolve().parent

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(
                ["git", "-C", str(folder), *args],
                capture_output=True,
                text=True,
                timeout=30,
                check=False,
            )
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    commit = git("rev-parse", "--short", "HEAD")
    if not commit:
        return None
    changed = git("status", "--porcelain", "--untracked-files=no")
    return f"`{commit}`{' with local changes' if changed else ''} (the HEAD of the checkout holding them when this page was written)"


def results_page(results: str | Path, *, commit: str | None = None, title: str = TITLE) -> str:
    """The page's Markdown. `commit`: which commit produced `results`, in words."""
    results = Path(results)
    scenes = load_scenes(results)
    lines = [
        "<!-- Generated by `make results-page` from a finished study's results/ "
        "(threedcal.report.results_page): regenerate it, do not edit it. -->",
        f"# {title}",
        "",
        *provenance_lines(results, commit),
        *reading_lines(),
        *scenes_section(scenes),
        *objects_section(scenes, results),
        *ablation_section(scenes, results),
        *convergence_section(scenes, results),
        *real_section(scenes, results),
        *reskin_section(scenes, results),
        *inference_section(scenes, results),
        *integrators_section(results),
        *time_section(results),
        *environment_section(results),
    ]
    return "\n".join(lines).rstrip("\n") + "\n"


def write_results_page(
    results: str | Path,
    out: str | Path,
    *,
    commit: str | None = None,
    title: str = TITLE,
) -> str:
    from threedcal.errors import ConfigError

    results = Path(results)
    if not load_scenes(results):
        raise ConfigError(
            f"{results}: no scene records (*/scene.json): not the results folder of a study"
        )
    text = results_page(
        results, commit=f"`{commit}`" if commit else study_commit(results), title=title
    )
    Path(out).write_text(text)
    return text


def page_layout(text: str) -> list[str]:
    """The page's shape, without its figures: every heading and every table's header row."""
    lines = text.splitlines()
    layout = []
    for i, line in enumerate(lines):
        if line.startswith("#"):
            layout.append(line.strip())
        elif (
            line.startswith("|")
            and i + 1 < len(lines)
            and lines[i + 1].startswith("|")
            and "-" in lines[i + 1]
            and set(lines[i + 1].replace("|", "").strip()) <= set("-: ")
        ):
            layout.append(line.strip())
    return layout
