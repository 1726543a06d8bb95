"""How many points to probe: each fraction P against P = 80 % (stats/tests.csv, error_vs_cost.csv),
the recommendation and the learning curve, for the page and for each scene of the summary."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from threedcal.evaluate.ablation_reading import curve_summary, family_comparison, placebo_summary
from threedcal.evaluate.power import needed_design
from threedcal.report.sections.convergence import convergence_lines
from threedcal.report.sections.markdown import (
    MISSING,
    SIM_COLUMN,
    estimate,
    markdown_table,
    missing_file,
    percent_interval,
)
from threedcal.report.sections.records import recorded_config, simulated_cell
from threedcal.study.paths import has_ablation

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


def _fraction_rows(
    scene: str, sim: str, costs: pd.DataFrame, tests: pd.DataFrame
) -> tuple[list[list[str]], list[str]]:
    """The page's rows of one scene, one a fraction, and the short equivalence forms they use."""
    paired = tests[tests["family"] == "paired"].set_index("P")
    equivalence = tests[tests["family"] == "equivalence"].set_index("P")
    paper = tests[tests["family"] == "paper"]
    rows, shorts = [], []
    for p in costs.index:
        cost = costs.loc[p]
        row = [scene, sim, f"{p} ({int(cost['points'])})", estimate(cost["mean_mse"], digits=5)]
        if p in paired.index:
            pair, eq = paired.loc[p], equivalence.loc[p] if p in equivalence.index else None
            verdict = pair["conclusion"]
            row.append(
                f"{pair['relative_change'] * 100:+.1f} "
                f"{percent_interval(pair['ci_low'], pair['ci_high'])}"
                + (f", *{verdict}*" if verdict != "no significant difference" else "")
            )
            if eq is None:
                row.append(MISSING)
            else:
                short = short_equivalence(eq["conclusion"])
                if short.endswith(")") and short.startswith("not equivalent ("):
                    shorts.append(short.removeprefix("not equivalent (")[:-1])
                row.append(f"{short} {percent_interval(eq['ci_low'], eq['ci_high'])}")
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
    return rows, shorts


def _advice(stats: Path, results: Path) -> tuple[str, str | None]:
    """A scene's recommendation in one line (the equivalence test's, then the learning curve's)
    and the whole of recommendation.txt (None without it)."""
    recommendation = stats / "recommendation.txt"
    text = None
    if recommendation.is_file():
        text = recommendation.read_text().strip()
        advice = text.split(":", 1)[0]
    else:
        advice = missing_file(recommendation, results)
    curve_path = stats / "learning_curve.csv"
    if curve_path.is_file():
        advice += f"; learning curve: {curve_summary(pd.read_csv(curve_path))}"
        differ = text is not None and "the readings differ" in text
        advice += " (the two differ: why in `stats/recommendation.txt`)" if differ else ""
    return advice, text


def _ablation_protocol(recommendations: list[str], shorts: list[str]) -> str:
    """The paragraph above the table: the tests, with the levels and margin the study recorded."""
    level = _recorded(r"(\d+(?:\.\d+)?) % interval, TOST", recommendations)
    eq_alpha = _recorded(r"TOST at alpha = ([0-9.eE+-]+)", recommendations)
    margin = _recorded(r"within a (\d+(?:\.\d+)?) % margin", recommendations)
    equivalence_level = (
        f"{level} % interval (1 − 2 × {eq_alpha}, as recorded)"
        if level and eq_alpha
        else "1 − 2·stats.equivalence_alpha interval (90 % by default)"
    )
    key = _equivalence_key(shorts)
    return (
        "Protocol: each fraction P (% of probe points) trained as replicate models, scored by "
        "gradient MSE at validation coordinates no P trains on, paired with P = 80 % there "
        "([statistics](explanation/statistics.md)); replicates' range and p-values in `stats/`. "
        "*Change* (%): paired test (blocks and replicates random, Holm over P), 1 − stats.alpha "
        "interval (99 % by default), *worse*/*better* if significant. *Equivalence*: TOST within "
        + (f"the {margin} % margin" if margin else "the recommendation's margin")
        + f", {equivalence_level}"
        + (f"; not equivalent: {key}" if key else "")
        + ". *t, U*: replicates where the paper's tests call P different."
    )


def ablation_section(scenes: Mapping[str, dict], results: Path) -> list[str]:
    """Validation MSE per fraction against P = 80 %, the recommendation, the placebo's spread."""
    chosen = {name: r for name, r in scenes.items() if has_ablation(recorded_config(r))}
    if not chosen:
        return []
    rows, notes, shorts, recommendations = [], [], [], []
    for name, record in chosen.items():
        stats = results / name / "stats"
        sim = simulated_cell(record)
        costs_path, tests_path = stats / "error_vs_cost.csv", stats / "tests.csv"
        if not costs_path.is_file() or not tests_path.is_file():
            missing = costs_path if not costs_path.is_file() else tests_path
            rows.append([f"`{name}`", sim, MISSING, missing_file(missing, results)] + [MISSING] * 3)
            continue
        costs = pd.read_csv(costs_path).set_index("P")
        tests = pd.read_csv(tests_path)
        scene_rows, scene_shorts = _fraction_rows(f"`{name}`", sim, costs, tests)
        rows += scene_rows
        shorts += scene_shorts
        advice, text = _advice(stats, results)
        if text is not None:
            recommendations.append(text)
        placebo = _placebo(tests)
        notes.append(f"- `{name}`: {advice}" + (f"; placebo {placebo}." if placebo else "."))
    header = [
        "scene",
        SIM_COLUMN,
        "P % (points)",
        "mean validation MSE",
        "change against P = 80 %",
        "equivalence",
        "t, U",
    ]
    return [
        "## How many points to probe: validation MSE against P = 80 %",
        "",
        _ablation_protocol(recommendations, shorts),
        "",
        *markdown_table(header, rows),
        "",
        "Recommendation: the equivalence test's (reasons: `stats/recommendation.txt`) and the "
        "learning curve's, fitted on every fraction: the fewest points whose predicted MSE is "
        "within the margin of P = 80 %'s (`stats/learning_curve.csv`, `.png`); placebo (the "
        "paper's tests between two P = 80 % trainings):",
        "",
        *notes,
        "",
    ]


def recommendation_facts(stats_dir: Path) -> list[tuple[str, str]]:
    """The summary's recommendation rows: the TOST's answer, the learning curve's (with its
    interval) and where the two differ, why (stats/recommendation.txt, one reading a line)."""
    path = stats_dir / "recommendation.txt"
    if not path.is_file():
        return []
    lines = path.read_text().strip().splitlines()
    facts = [("recommendation (equivalence test)", lines[0])]
    curve = stats_dir / "learning_curve.csv"
    if curve.is_file():
        facts.append(
            ("learning curve (stats/learning_curve.csv)", curve_summary(pd.read_csv(curve)))
        )
    compared = [line for line in lines[1:] if "readings" in line.split(":", 1)[0]]
    facts += [("equivalence test against the curve", line) for line in compared]
    return facts


def ablation_lines(stats_dir: Path) -> list[str]:
    """One scene's three test families side by side, disagreements spelled out, and the design
    the power simulation says each P needs (docs/explanation/statistics.md)."""
    tests_path = stats_dir / "tests.csv"
    if not tests_path.is_file():
        return []
    tests = pd.read_csv(tests_path)
    if not {"paper", "paired", "equivalence"} <= set(tests["family"]):
        return []
    comparison = family_comparison(tests)
    power = pd.read_csv(stats_dir / "power.csv") if (stats_dir / "power.csv").is_file() else None
    lines = [
        "Each P against P = 80 % (tests.csv): the paper's tests (replicates significant, t / U), "
        "the paired spatial-block test and the equivalence test (TOST):",
        "",
        "| P | change of mean MSE | paper t / U | paired | equivalence | families | "
        "80 % power to show equivalence |",
        "|---:|---:|---|---|---|---|---|",
    ]
    for row in comparison.itertuples():
        design = needed_design(power, row.P) if power is not None else "—"
        lines.append(
            f"| {row.P} | {row.change} | {row.paper_t} / {row.paper_u} | {row.paired} | "
            f"{row.equivalence} | {row.agreement} | {design} |"
        )
    placebo = placebo_summary(tests)
    if placebo:
        lines += ["", f"Placebo (`family = placebo`): {placebo}."]
    lines += convergence_lines(stats_dir / "convergence.csv")
    return lines + [""]
