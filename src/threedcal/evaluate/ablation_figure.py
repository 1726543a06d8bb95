"""The ablation's tests as one figure (stats/tests.png): each P against P = 80 %."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import ticker

from threedcal.evaluate.ablation import MARGIN
from threedcal.evaluate.ablation_reading import family_comparison, placebo_summary
from threedcal.plotting import pyplot

# The tests figure's ratio axis: an interval reaching past it (a paired interval with few degrees
# of freedom can span -150 % to +5,000 %) is cut at the edge and its bound written beside it, so
# that the intervals that matter are not squeezed into a sliver.
AXIS_RATIO = (0.2, 20.0)


def interval_on_axis(ci_low, ci_high, limits=AXIS_RATIO) -> dict:
    """Ratio bounds (1 + relative bound) cut to `limits`, and for each cut bound its true value as
    text ("" where it lies on the axis). NaN bounds stay NaN."""
    ci_low, ci_high = np.asarray(ci_low, dtype=float), np.asarray(ci_high, dtype=float)
    low, high = 1 + ci_low, 1 + ci_high
    below = [f"{v * 100:+.0f} %" if v + 1 < limits[0] else "" for v in ci_low]
    above = [f"{v * 100:+,.0f} %" if v + 1 > limits[1] else "" for v in ci_high]
    return {
        "low": np.where(np.isnan(low), low, np.clip(low, limits[0], limits[1])),
        "high": np.where(np.isnan(high), high, np.clip(high, limits[0], limits[1])),
        "below": below,
        "above": above,
    }


def tests_figure(tests: pd.DataFrame, path: str | Path, title: str, margin: float = MARGIN) -> None:
    """Each P against P = 80: ratio of mean validation MSE with the paired (1 - alpha) and TOST
    (1 - 2 alpha) intervals, the margin shaded, each replicate's paper-family ratio as a dot
    (filled where both of the paper's tests are significant)."""
    plt = pyplot()
    paired = tests[tests["family"] == "paired"].set_index("P").sort_index()
    equivalence = tests[tests["family"] == "equivalence"].set_index("P")
    fractions = list(paired.index)
    x = np.arange(len(fractions))
    fig, ax = plt.subplots(figsize=(7, 4.6), dpi=120)
    ax.axhspan(
        1 - margin,
        1 + margin,
        color="tab:green",
        alpha=0.15,
        lw=0,
        label=f"margin ±{margin * 100:.0f} %",
    )
    ax.axhline(1.0, c="k", lw=0.6)
    drawn = [
        _interval_bars(ax, paired, x - 0.08, "tab:blue", "paired test, 1 - alpha interval", 1.2),
        _interval_bars(
            ax, equivalence.loc[fractions], x + 0.08, "tab:green", "TOST, 1 - 2 alpha interval", 2.4
        ),
    ]
    _paper_dots(ax, tests[tests["family"] == "paper"], fractions)
    ax.set_yscale("log")
    low, high = ax.get_ylim()
    low, high = max(low, AXIS_RATIO[0]), min(high, AXIS_RATIO[1])
    # room above and below for the verdicts written at the panel's edges
    low, high = min(low, 1 - 2 * margin) / 1.8, max(high, 1 + 2 * margin) * 1.8
    ax.set_ylim(low, high)
    for xs, colour, bounds in drawn:
        _cut_bounds(ax, xs, colour, bounds)
    _ratio_ticks(ax, low, high)
    ax.set_xticks(x, [f"P = {p} %" for p in fractions])
    ax.set(ylabel="change of mean validation MSE against P = 80 %", title=title)
    _verdicts(ax, family_comparison(tests).set_index("P"), fractions)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=4, frameon=False)
    placebo = placebo_summary(tests, short=True)
    if placebo:
        fig.text(0.5, 0.01, placebo, ha="center", fontsize=7, color="tab:red")
    fig.tight_layout(rect=(0, 0.04 if placebo else 0, 1, 1))
    fig.savefig(path)
    plt.close(fig)


def _interval_bars(ax, frame: pd.DataFrame, xs, colour: str, label: str, width: float):
    """One family's ratios with their intervals cut to the axis; (xs, colour, bounds) to mark."""
    ratio = 1 + frame["relative_change"].to_numpy(float)
    bounds = interval_on_axis(frame["ci_low"].to_numpy(float), frame["ci_high"].to_numpy(float))
    ax.errorbar(
        xs,
        ratio,
        yerr=[ratio - bounds["low"], bounds["high"] - ratio],
        fmt="o",
        c=colour,
        lw=width,
        capsize=3,
        label=label,
    )
    return xs, colour, bounds


def _paper_dots(ax, paper: pd.DataFrame, fractions) -> None:
    """Each replicate's ratio under the paper's t-test, filled where both its tests reject."""
    for i, p in enumerate(fractions):
        part = paper[(paper["P"] == p) & (paper["test"] == "t")]
        both = paper[paper["P"] == p].groupby("replicate")["significant"].all()
        for _, row in part.iterrows():
            filled = bool(both.get(row["replicate"], False))
            ax.plot(
                i + 0.25,
                np.clip(1 + row["relative_change"], *AXIS_RATIO),
                "s",
                ms=4,
                mec="tab:red",
                mfc="tab:red" if filled else "none",
            )
    ax.plot([], [], "s", ms=4, mec="tab:red", mfc="tab:red", label="paper's tests, a replicate")


def _cut_bounds(ax, xs, colour: str, bounds: dict) -> None:
    """An interval past the axis: an arrow at the edge and its true bound beside it."""
    edges = (("below", 0, "v", -2, "top"), ("above", 1, "^", 2, "bottom"))
    for side, end, marker, dy, va in edges:
        for xi, text in zip(xs, bounds[side], strict=True):
            if text:
                ax.plot(xi, AXIS_RATIO[end], marker, c=colour, ms=5)
                ax.annotate(
                    text,
                    (xi, AXIS_RATIO[end]),
                    xytext=(-4, dy),
                    textcoords="offset points",
                    ha="right",
                    va=va,
                    fontsize=6,
                    color=colour,
                )


def _ratio_ticks(ax, low: float, high: float) -> None:
    """Ticks at round ratios, labelled as the change in per cent."""
    nice = [0.2, 0.25, 0.5, 0.75, 0.9, 1.0, 1.1, 1.25, 1.5, 2, 3, 5, 10, 20]
    if high / low > 3:  # on a wide axis the small steps crowd the 0 %; the shaded band shows them
        nice = [v for v in nice if v not in (0.25, 0.75, 0.9, 1.1, 1.25)]
    ax.yaxis.set_major_locator(ticker.FixedLocator([v for v in nice if low <= v <= high]))
    ax.yaxis.set_major_formatter(
        ticker.FuncFormatter(lambda v, _: f"{(v - 1) * 100:+,.0f} %" if v != 1 else "0 %")
    )
    ax.yaxis.set_minor_locator(ticker.NullLocator())


def _verdicts(ax, comparison: pd.DataFrame, fractions) -> None:
    """Under each P the paper's rejections; above it where the families disagree."""
    for i, p in enumerate(fractions):
        row = comparison.loc[p]
        ax.annotate(
            f"t {row['paper_t']}, U {row['paper_u']}",
            (i, 0.02),
            xycoords=("data", "axes fraction"),
            ha="center",
            fontsize=7,
            color="tab:red",
        )
        if row["agreement"].startswith(("disagree", "mixed")):
            ax.annotate(
                "families disagree",
                (i, 0.95),
                xycoords=("data", "axes fraction"),
                ha="center",
                fontsize=7,
                color="tab:orange",
            )
