"""docs/results.md: the results page, written from a finished study's `results/` folder alone.

`threedcal report results-page` (and `make results-page`) call `write_results_page`. The scenes are
read from their own records (`results/{scene}/scene.json`, in the order of `environment.json`), so
the page needs no config and says only what that study ran. Every table says which protocol made
its figures and whether the simulator made both the training and the test frames: in a column, or,
where every row has the same value, in one line above the table (`DESCRIPTIVE` columns only).

Provenance is the threedcal version, the host and the date of the last job, all from the study's
own files; no commit hash (the docs carry hashes only in the changelog).

A page section exists when some scene asks for it (its recorded config), whatever its files hold;
a missing file leaves a row that says so. So the page's layout (`page_layout`: headings and table
columns) depends on the scenes and on which descriptive columns are the same on every row, and
tests/report/test_results_page.py compares the committed page's layout with the generator's.
"""

from __future__ import annotations

import datetime
import re
from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from threedcal.evaluate.ablation_reading import curve_summary
from threedcal.report.stage_times import stage_time_lines, stage_times, study_span
from threedcal.report.summary import read_json, reading_line, sim2real_rows
from threedcal.study.config import has_arms, is_quick
from threedcal.study.config import is_imported as config_is_imported
from threedcal.study.fractions import convergence_fractions, training_fractions
from threedcal.study.paths import has_ablation, has_objects, has_sim2real

TITLE = "Results of the default study"
# The fraction whose test-object figures lead the page (the paper's Table II reports P = 20 %).
REPORTED_P = 20
SIMULATED = "yes"
# The column every table carries: did the simulator render both the frames trained on and those tested?
SIM_COLUMN = "simulator made training and test frames"
SIM_READINGS = SIM_COLUMN.replace("frames", "readings")
# Columns that describe a table's rows rather than measure them: one whose value is the same on
# every row becomes a line above the table instead of a repeated cell.
DESCRIPTIVE = ("scene", "sensor", SIM_COLUMN, SIM_READINGS, "protocol", "torch threads")
MISSING = "—"
# The stage-time table's longest stages; the rest share one row.
TOP_STAGES = 8


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
    """The scene's config as the workflow's predicates read it (threedcal.study.paths, .config); a
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
    """The scenes table's SIM_COLUMN cell: whether the simulator made a scene's frames (a ReSkin's
    readings), and where real ones came from."""
    if is_imported(record):
        return f"no (real images, `{_config(record)['import'].get('path', 'imported')}`)"
    readings = " (readings)" if is_magnetic(record) else ""
    if is_simulated(record):
        return f"{SIMULATED}{readings}"
    return f"no (real printer and sensor{readings}, port {_config(record).get('port')})"


def simulated_cell(record: Mapping) -> str:
    """The SIM_COLUMN's cell of a scene's own figures."""
    if is_simulated(record):
        return SIMULATED
    return "no (real images)" if is_imported(record) else "no (real sensor frames)"


# ---------------------------------------------------------------------------------------------
# Formatting


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    """A Markdown table; each DESCRIPTIVE column whose value is the same on every row leaves the
    table for one line above it (a study where the value varies keeps the column)."""
    keep, same = list(range(len(header))), []
    for i, name in enumerate(header):
        values = {str(row[i]) for row in rows}
        if name in DESCRIPTIVE and len(values) == 1 and len(keep) > 1:
            same.append(f"*{name}* {values.pop()}")
            keep.remove(i)
    lines = ["Every row: " + "; ".join(same) + ".", ""] if same else []
    return [
        *lines,
        "| " + " | ".join(header[i] for i in keep) + " |",
        "|" + "|".join("---" for _ in keep) + "|",
        *("| " + " | ".join(str(row[i]) for i in keep) + " |" for row in rows),
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


def _interval(low: float, high: float) -> str:
    """'[-2.9, +14.6]': an interval of relative changes, in percent."""
    return f"[{low * 100:+.1f}, {high * 100:+.1f}]"


def _missing(path: Path, results: Path) -> str:
    return f"not in these results (`{path.relative_to(results.parent).as_posix()}`)"


# The equivalence verdicts of tests.csv (threedcal.evaluate.ablation) in short: (words the verdict
# holds, its short form); the first match wins.
EQUIVALENCE_FORMS = (
    ("a larger P is not", "larger P"),
    ("worse by more than", "worse"),
    ("better by more than", "better"),
    ("power", "power"),
    ("wider than the margin", "power"),
    ("estimate lies past the margin on the worse", "estimate worse"),
    ("estimate lies past the margin on the better", "estimate better"),
)
# What each short form means, said once above the table (for the forms the table uses).
EQUIVALENCE_KEY = {
    "worse": "the interval lies past the margin",
    "better": "the interval lies past the margin",
    "estimate worse": "the estimate does",
    "estimate better": "the estimate does",
    "power": "the interval crosses it (too little power)",
    "larger P": "a larger P is not (fixed sequence)",
}


def short_equivalence(conclusion: str) -> str:
    """'not equivalent (power)' for 'not equivalent: the interval reaches past the margin on the
    worse side (too little power)'; a verdict it does not know stays as it is."""
    text = str(conclusion)
    for words, short in EQUIVALENCE_FORMS:
        if text.startswith("not equivalent") and words in text:
            return f"not equivalent ({short})"
    return text


def _equivalence_key(shorts: list[str]) -> str:
    """The meaning of each short form used, once: '(worse) the interval lies past the margin,
    (power) ...'."""
    meanings: dict[str, list[str]] = {}
    for short in sorted(dict.fromkeys(shorts), key=list(EQUIVALENCE_KEY).index):
        meanings.setdefault(EQUIVALENCE_KEY[short], []).append(short)
    return ", ".join(f"({'/'.join(names)}) {meaning}" for meaning, names in meanings.items())


def _placebo(tests: pd.DataFrame) -> str | None:
    """'t 0/3, U 0/3, means 0.4-1.4 % apart': the placebo family (two trainings of the reference
    fraction) in short; None without it."""
    rows = tests[tests["family"] == "placebo"]
    if rows.empty:
        return None
    pairs = len(rows.drop_duplicates(["against", "replicate"]))
    called = [
        f"{name} {int(rows.loc[rows['test'] == test, 'significant'].astype(bool).sum())}/{pairs}"
        for name, test in (("t", "t"), ("U", "mannwhitney"))
    ]
    change = rows["relative_change"].abs().to_numpy(float) * 100
    low, high = f"{change.min():.1f}", f"{change.max():.1f}"
    return f"{', '.join(called)}, means {low if low == high else f'{low}-{high}'} % apart"


def _recorded(pattern: str, texts: list[str]) -> str | None:
    """The one value `pattern` (one group) finds in every text, or None where a text lacks it or
    the texts disagree."""
    found = {m.group(1) if (m := re.search(pattern, text)) else None for text in texts}
    return found.pop() if len(found) == 1 else None


# ---------------------------------------------------------------------------------------------
# Sections


def provenance_lines(results: Path) -> list[str]:
    """Which threedcal, host and date produced the figures, from what the study recorded."""
    environment = read_json(results / "environment.json") or {}
    software = environment.get("software", {})

    def words(value) -> str:
        if isinstance(value, Mapping):
            return ", ".join(f"{k}={v}" for k, v in value.items())
        return " ".join(map(str, value)) if isinstance(value, list | tuple) else str(value)

    limits = environment.get("isa_limits")
    host = ", ".join(
        str(part)
        for part in (
            environment.get("platform"),
            environment.get("processor"),
            environment.get("cpu"),
            f"{environment['cpu_count']} CPUs" if environment.get("cpu_count") else None,
            f"with {words(_widest(environment['cpu_flags']))}"
            if environment.get("cpu_flags")
            else None,
            f"capped by {words(limits)}" if limits and limits != "none" else None,
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
        f"threedcal {software['threedcal']}" if "threedcal" in software else None,
        f"torch {software['torch']}" if "torch" in software else None,
        f"host {host}" if host else "host not recorded",
        f"last job ended {when}" if when else None,
    ]
    return [
        "Written by `make results-page` from one finished study's `results/` (regenerate, do "
        f"not edit): {'; '.join(f for f in facts if f)} (every version: `environment.json`). "
        "Other hosts give other digits.",
        "",
    ]


def reading_lines() -> list[str]:
    return [
        "Each table names its protocol and says, in a column or (where every row agrees) in a "
        f"line above it, whether the *{SIM_COLUMN}*. Brackets: 95 % intervals unless said "
        "otherwise. Files: [outputs](reference/outputs.md).",
        "",
    ]


def scenes_section(scenes: Mapping[str, dict]) -> list[str]:
    """One row a scene."""
    rows = [
        [
            f"`{name}`",
            str(_config(record).get("sensor", MISSING)),
            str(_config(record).get("printer") or MISSING),
            frames_of(record),
        ]
        for name, record in scenes.items()
    ]
    return [
        "## Scenes",
        "",
        *_table(["scene", "sensor", "printer", SIM_COLUMN], rows),
        "",
    ]


def _objects_of(scenes: Mapping[str, dict]) -> list[str]:
    names: dict[str, None] = {}
    for record in scenes.values():
        if has_objects(_config(record)):
            names.update(dict.fromkeys(str(o) for o in _config(record)["objects"]))
    return list(names)


def quick_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """Each compared quick calibration's stopped model against its unit's full calibration
    (arms.json), and its presses from scratch."""
    chosen = [n for n, r in scenes.items() if has_arms(_config(r))]
    if not chosen:
        return []
    rows = []
    for name in chosen:
        path = results / name / "quick" / "arms.json"
        if not path.is_file():
            rows.append([f"`{name}`", _missing(path, results)] + [MISSING] * 4)
            continue
        arms = read_json(path)
        targets = arms["targets"]
        mse, scratch = targets["validation_mse"], arms.get("scratch_same_round")
        worst = max(
            targets["objects"]["per_object"].items(), key=lambda o: o[1]["interval95_um"][1]
        )
        rows.append(
            [
                f"`{name}` vs `{arms['compare_with']}`",
                f"{arms.get('presses_in_all', arms['presses'])}, {arms['printer_minutes']:.1f}",
                f"{_pct(mse['change'])} {_interval(*mse['interval95'])} ({mse['verdict']})",
                MISSING
                if scratch is None
                else f"{_pct(scratch['change'])} {_interval(*scratch['interval95'])}",
                f"{worst[0]} {_estimate(worst[1]['difference_um'], *worst[1]['interval95_um'])} "
                f"({targets['objects']['verdict']})",
                f"{targets['presses']['verdict']}, {targets['printer_minutes']['verdict']}",
            ]
        )
    return [
        "## Quick calibration",
        "",
        "The stopped model against the unit's P = 80 models; targets: "
        "+10 %, +10 µm (printer protocol), 50 presses (touch search included), 5 minutes. "
        "One unit a sensor; over units: `make quick-study` "
        "([statistics](explanation/statistics.md#a-quick-calibration-against-a-full-one)).",
        "",
        *_table(
            ["scene", "presses, min", "MSE vs full", "scratch", "worst Δ Type 2 µm", "budget"],
            rows,
        ),
        "",
    ]


def objects_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """Type 2 MAE per object at P = 20 %, both protocols; then the printer protocol over every P."""
    chosen = {name: r for name, r in scenes.items() if has_objects(_config(r))}
    if not chosen:
        return []
    objects = _objects_of(chosen)
    fractions = sorted({p for r in chosen.values() for p in training_fractions(_config(r))})
    reported = REPORTED_P if REPORTED_P in fractions else max(fractions)
    head_rows, by_p_rows, designs = [], [], {}
    for name, record in chosen.items():
        path = results / name / "objects" / "errors.csv"
        sim = simulated_cell(record)
        if not path.is_file():
            head_rows.append(
                [f"`{name}`", sim, MISSING, _missing(path, results)]
                + [MISSING] * (len(objects) - 1)
            )
            continue
        table = pd.read_csv(path)
        replicates = int(table["replicates"].min()) if "replicates" in table else 1
        design = (
            f"{int(table['presses'].min())} presses per object and {replicates} "
            f"model{'s' if replicates != 1 else ''} per P"
        )
        designs.setdefault(design, []).append(f"`{name}`")
        for protocol in dict.fromkeys(table["protocol"]):
            rows = table[table["protocol"] == protocol]
            at = {r.object: r for r in rows[rows["P"] == reported].itertuples()}
            head_rows.append(
                [f"`{name}`", sim, f"**{protocol}**" if protocol == "printer" else protocol]
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
                part = rows[rows["object"] == obj].set_index("P")["type2_um"]
                ends = (
                    [f"{part[p]:.0f} ({p})" for p in (part.idxmin(), part.idxmax())]
                    if len(part)
                    else [MISSING, MISSING]
                )
                by_p_rows.append([f"`{name}`", sim, protocol, obj, *ends])
    design = "; ".join(f"{d} ({', '.join(names)})" for d, names in designs.items())
    return [
        f"## Test objects: Type 2 MAE (µm), P = {reported} %",
        "",
        f"Protocol: objects pressed by the printer; the P = {reported} % models' depth against "
        "the CAD truth where it touches ([objects](explanation/objects.md)); `printer`: truth "
        "placed where the printer put it, `paper`: aligned by cross-correlation, depth fitted. "
        "Mean over presses and models, both random" + (f": {design}" if design else "") + ".",
        "",
        *_table(["scene", SIM_COLUMN, "protocol", *objects], head_rows),
        "",
        f"Over P = {', '.join(map(str, fractions))} %, the lowest and highest mean (all: "
        "`objects/errors.csv`):",
        "",
        *_table(
            ["scene", SIM_COLUMN, "protocol", "object", "lowest (P %)", "highest (P %)"], by_p_rows
        ),
        "",
    ]


def ablation_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """Validation MSE per fraction against P = 80 %, the recommendation, the placebo's spread."""
    chosen = {name: r for name, r in scenes.items() if has_ablation(_config(r))}
    if not chosen:
        return []
    rows, notes, shorts, recommendations = [], [], [], []
    for name, record in chosen.items():
        stats = results / name / "stats"
        sim = simulated_cell(record)
        costs_path, tests_path = stats / "error_vs_cost.csv", stats / "tests.csv"
        if not costs_path.is_file() or not tests_path.is_file():
            missing = costs_path if not costs_path.is_file() else tests_path
            rows.append([f"`{name}`", sim, MISSING, _missing(missing, results)] + [MISSING] * 3)
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
                f"{p} ({int(cost['points'])})",
                _estimate(cost["mean_mse"], digits=5),
            ]
            if p in paired.index:
                pair, eq = paired.loc[p], equivalence.loc[p] if p in equivalence.index else None
                verdict = pair["conclusion"]
                row.append(
                    f"{pair['relative_change'] * 100:+.1f} "
                    f"{_interval(pair['ci_low'], pair['ci_high'])}"
                    + (f", *{verdict}*" if verdict != "no significant difference" else "")
                )
                if eq is None:
                    row.append(MISSING)
                else:
                    short = short_equivalence(eq["conclusion"])
                    if short.endswith(")") and short.startswith("not equivalent ("):
                        shorts.append(short.removeprefix("not equivalent (")[:-1])
                    row.append(f"{short} {_interval(eq['ci_low'], eq['ci_high'])}")
                part = paper[paper["P"] == p]
                significant = part["significant"].astype(bool)
                row.append(
                    ", ".join(
                        f"{int(significant[part['test'] == t].sum())}/"
                        f"{part.loc[part['test'] == t, 'replicate'].nunique()}"
                        for t in ("t", "mannwhitney")
                    )
                )
            else:
                row += ["reference", MISSING, MISSING]
            rows.append(row)
        recommendation = stats / "recommendation.txt"
        if recommendation.is_file():
            text = recommendation.read_text().strip()
            recommendations.append(text)
            advice = text.split(":", 1)[0]
        else:
            advice = _missing(recommendation, results)
        curve_path = stats / "learning_curve.csv"
        if curve_path.is_file():
            advice += f"; learning curve: {curve_summary(pd.read_csv(curve_path))}"
            differ = recommendation.is_file() and "the readings differ" in text
            advice += " (the two differ: why in `stats/recommendation.txt`)" if differ else ""
        placebo = _placebo(tests)
        notes.append(f"- `{name}`: {advice}" + (f"; placebo {placebo}." if placebo else "."))
    level = _recorded(r"(\d+(?:\.\d+)?) % interval, TOST", recommendations)
    eq_alpha = _recorded(r"TOST at alpha = ([0-9.eE+-]+)", recommendations)
    margin = _recorded(r"within a (\d+(?:\.\d+)?) % margin", recommendations)
    equivalence_level = (
        f"{level} % interval (1 − 2 × {eq_alpha}, as recorded)"
        if level and eq_alpha
        else "1 − 2·stats.equivalence_alpha interval (90 % by default)"
    )
    key = _equivalence_key(shorts)
    return [
        "## How many points to probe: validation MSE against P = 80 %",
        "",
        "Protocol: each fraction P (% of probe points) trained as replicate models, scored by "
        "gradient MSE at validation coordinates no P trains on, paired with P = 80 % there "
        "([statistics](explanation/statistics.md)); replicates' range and p-values in `stats/`. "
        "*Change* (%): paired test (blocks and replicates random, Holm over P), 1 − stats.alpha "
        "interval (99 % by default), *worse*/*better* if significant. *Equivalence*: TOST within "
        + (f"the {margin} % margin" if margin else "the recommendation's margin")
        + f", {equivalence_level}"
        + (f"; not equivalent: {key}" if key else "")
        + ". *t, U*: replicates where the paper's tests call P different.",
        "",
        *_table(
            [
                "scene",
                SIM_COLUMN,
                "P % (points)",
                "mean validation MSE",
                "change against P = 80 %",
                "equivalence",
                "t, U",
            ],
            rows,
        ),
        "",
        "Recommendation: the equivalence test's (reasons: `stats/recommendation.txt`) and the "
        "learning curve's, fitted on every fraction: the fewest points whose predicted MSE is "
        "within the margin of P = 80 %'s (`stats/learning_curve.csv`, `.png`); placebo (the "
        "paper's tests between two P = 80 % trainings):",
        "",
        *notes,
        "",
    ]


def convergence_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    chosen = {name: r for name, r in scenes.items() if convergence_fractions(_config(r))}
    if not chosen:
        return []
    rows, readings = [], []
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
                    f"{row.steps} / {row.twice_steps}",
                    f"{row.budget_mse:.5f}",
                    f"{row.twice_mse:.5f}",
                    f"{_pct(row.change)} [{_pct(row.ci_low)}, {_pct(row.ci_high)}]",
                    str(row.replicates),
                ]
            )
        for label, leaf in (
            ("the budget", "recommendation.txt"),
            ("twice", "twice/recommendation.txt"),
        ):
            line = reading_line((results / name / "stats" / leaf).parent)
            if line:
                readings.append(f"- `{name}` at {label}: {line}")
    return [
        "## Has the training converged? Twice the budget",
        "",
        "Protocol: every model trains the same steps (the budget) in cycles ending at a quarter, "
        "a half, all and twice the budget, scored by mean validation MSE "
        "(`stats/error_vs_time.csv`); the change at twice pairs models by replicate and "
        "block, 95 % interval (`stats/convergence.csv`); `stats/twice/` reads the "
        "ablation there.",
        "",
        *_table(
            [
                "scene",
                SIM_COLUMN,
                "P %",
                "steps",
                "validation MSE",
                "at twice the steps",
                "change [95 % interval]",
                "replicates",
            ],
            rows,
        ),
        "",
        *(
            ["How many points to probe, read at the budget and at twice it:", "", *readings, ""]
            if readings
            else []
        ),
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
        "Protocol: each press's images in one fold, each image tested by the model trained "
        "without its fold; error inside each contact's evaluation circle, bootstrap over press "
        "groups ([real data](explanation/real-data.md)).",
        "",
        *_table(
            [
                "scene",
                SIM_COLUMN,
                "protocol",
                "method",
                "gradient RMSE",
                "cap depth MAE µm",
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


# Sim-to-real conditions, in the table's column order, with whether the simulator made their
# training and test frames.
SIM2REAL_CONDITIONS = {
    "sim+real": "pretraining",
    "real-only": "no",
    "scene model": "no",
}
# Shown only where a scene ran it (sim_to_real.shipped).
SHIPPED_CONDITION = "shipped+real"


def sim2real_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """One row per scene and k, one column per condition: gradient RMSE; cap depth MAE."""
    if not scenes:
        return []
    conditions = dict(SIM2REAL_CONDITIONS)
    rows = []
    for name in scenes:
        path = results / name / "sim2real" / "errors.csv"
        if not path.is_file():
            rows.append({"scene": f"`{name}`", "protocol": MISSING, "k": MISSING})
            rows[-1][next(iter(conditions))] = _missing(path, results)
            continue
        errors = pd.read_csv(path, dtype={"k": str, "fold": str})
        folds = sorted(set(errors["fold"]) - {"all"}, key=int)
        protocol = f"held-out folds {', '.join(folds)}"
        by_k: dict[str, dict] = {}
        for k, condition, rmse, mae in sim2real_rows(errors[errors["fold"] == "all"]):
            conditions.setdefault(
                condition, "pretraining" if condition == SHIPPED_CONDITION else MISSING
            )
            row = by_k.setdefault(k, {"scene": f"`{name}`", "protocol": protocol, "k": k})
            row[condition] = f"{rmse}; {mae}"
        rows += by_k.values()
    # the simulator made no test frame here: only some conditions' pretraining frames
    simulated = "only to pretrain " + ", ".join(
        f"`{c}`" for c in conditions if conditions[c] == "pretraining"
    )
    unknown = [f"`{c}`" for c in conditions if conditions[c] == MISSING]
    simulated += f"; {MISSING} for {', '.join(unknown)}" if unknown else ""
    header = ["scene", "protocol", "k", *conditions]
    return [
        "### Sim-to-real: k real images, with and without simulated pretraining",
        "",
        "Protocol: `sim+real`: simulated presses, then k real; `real-only`: k alone; "
        + (
            f"`{SHIPPED_CONDITION}`: shipped weights, then k at their frame size; "
            if SHIPPED_CONDITION in conditions
            else ""
        )
        + "`scene model`: cross-validated"
        + f". *{SIM_COLUMN}*: {simulated}. Cells: gradient RMSE; cap depth MAE µm.",
        "",
        *_table(header, [[row.get(column, MISSING) for column in header] for row in rows]),
        "",
    ]


def real_check_section(results: Path) -> list[str]:
    """The shipped weights on real frames (results/real_check/table.csv), when the study ran it."""
    path = results / "real_check" / "table.csv"
    if not path.is_file():
        return []
    table = pd.read_csv(path)
    rows = [
        [
            f"`{Path(str(r['set'])).name}`",
            "pretraining only (real test frames)",
            str(r["weights"]),
            str(r["frames_read"]),
            str(int(r["frames"])),
            f"{100 * r['within_bound']:.0f} %",
            f"{r['area_ratio_median']:.2f} ({r['area_ratio_p90']:.2f})",
            f"{r['centroid_error_mm_median']:.2f} ({100 * r['centroid_within_0p2mm']:.0f} %)",
            f"{r['peak_mm_median']:.2f} / {r['allowed_mm_median']:.2f}",
        ]
        for _, r in table.iterrows()
    ]
    header = [
        "set",
        SIM_COLUMN,
        "weights",
        "frames read",
        "frames",
        "contact within the ball",
        "contact / ball's disc, median (p90)",
        "centroid error mm, median (within 0.2 mm)",
        "peak / allowed depth mm",
    ]
    return [
        "### The shipped weights on real frames: depth only where the ball is?",
        "",
        "Protocol: each real folder read with its own blank at the weights' frame size; contact = "
        "depth above 0.05 mm, against the ball's disc πR²; centroid against the located contact; "
        "peak against the located contact's cap depth. Fine-tuned: on the folder's fitting half "
        "(the realism split), read on the other ([real data](explanation/real-data.md)).",
        "",
        *_table(header, rows),
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
        "Protocol: magnetic readings of probe presses on the authors' cross plan; an MLP "
        "predicts contact position and depth at probe coordinates it never trained on (x, y "
        "error; [ReSkin](explanation/reskin.md)).",
        "",
        *_table(
            [
                "scene",
                SIM_READINGS,
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


def _widest(flags) -> list[str]:
    """The vector extensions that decide torch's kernels (AVX2, AVX-512, native bfloat16), of a
    CPU's flags: the page names the host, not every flag."""
    flags = flags.split() if isinstance(flags, str) else list(flags)
    return [f for f in ("avx2", "avx512f", "avx512_bf16") if f in flags] or ["no AVX2"]


def inference_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    # a quick scene's model is timed by no stage (its rounds are its figures)
    chosen = {
        name: r for name, r in scenes.items() if not is_magnetic(r) and not is_quick(_config(r))
    }
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
                "×".join(str(s) for s in shape) if shape else MISSING,
                str(fps.get("torch_threads", MISSING)),
            ]
        )
    return [
        "## Inference speed",
        "",
        "Protocol: replicate 0 of the largest P turns its scene's frames into depth maps on "
        "this host's CPU, one at a time after a warm-up (`models/inference.json`).",
        "",
        *_table(
            [
                "scene",
                SIM_COLUMN,
                "model preset",
                "frames/s",
                "ms per frame",
                "image H×W px",
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
    # the study's reading up to its advice, which explanation/depth.md gives
    advice = [i for i, line in enumerate(body) if line.startswith("Which method when")]
    body = "\n".join(body[: advice[0]] if advice else body).strip().splitlines()
    return [
        "## Depth integrators",
        "",
        "Protocol: gradient fields of analytic surfaces (exact, or with the scenario's noise, "
        "outliers or border contact), no simulator and no model, integrated and compared with "
        "the surface (`integration/`; which method when: [depth](explanation/depth.md)).",
        "",
        *[f"#{line}" if line.startswith("## ") else line for line in body],
        "",
    ]


def time_section(results: Path) -> list[str]:
    span = study_span(results)
    table = stage_times(results)
    duration = (
        f"{(span[1] - span[0]) / 60:.1f} min from the first job's start to the last one's end; "
        if span
        else ""
    )
    work = (
        f"{table['wall_s'].sum() / 60:.1f} job-minutes (jobs run side by side). "
        if not table.empty
        else ""
    )
    return [
        "## Where the time goes",
        "",
        f"{duration}{work}Per stage from the `benchmark:` files (CPU time and memory: "
        "`threedcal report stage-times`).",
        "",
        *stage_time_lines(table, limit=TOP_STAGES, brief=True),
        "",
    ]


# ---------------------------------------------------------------------------------------------
# The page


def results_page(results: str | Path, *, title: str = TITLE) -> str:
    """The page's Markdown."""
    results = Path(results)
    scenes = load_scenes(results)
    lines = [
        f"# {title}",
        "",
        *provenance_lines(results),
        *reading_lines(),
        *scenes_section(scenes),
        *objects_section(scenes, results),
        *quick_section(scenes, results),
        *ablation_section(scenes, results),
        *convergence_section(scenes, results),
        *real_section(scenes, results),
        *real_check_section(results),
        *reskin_section(scenes, results),
        *inference_section(scenes, results),
        *integrators_section(results),
        *time_section(results),
    ]
    return "\n".join(lines).rstrip("\n") + "\n"


def write_results_page(results: str | Path, out: str | Path, *, title: str = TITLE) -> str:
    from threedcal.errors import ConfigError

    results = Path(results)
    if not load_scenes(results):
        raise ConfigError(
            f"{results}: no scene records (*/scene.json): not the results folder of a study"
        )
    text = results_page(results, title=title)
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
