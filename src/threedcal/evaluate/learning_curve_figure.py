"""The learning curve as one figure (stats/learning_curve.png): error against points probed, the
fitted curve with its bootstrap band, the margin, and the answer with its interval."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
from matplotlib import ticker

from threedcal.evaluate.ablation_reading import answer_interval
from threedcal.evaluate.learning_curve import FLAT, NOT_FITTED, LearningCurve
from threedcal.plotting import pyplot

ANSWER_COLOUR = "tab:orange"
CURVE_COLOUR = "tab:blue"


def learning_curve_figure(curve: LearningCurve, path: str | Path, title: str) -> None:
    """Mean validation MSE against points probed (log x; log y unless the errors lie within a
    factor 3): each replicate's mean (dots), each
    fraction's mean with the replicates' range, the fitted curve and its pointwise bootstrap band,
    P = 80 %'s predicted MSE and the margin above it, the answer and its interval."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=120)
    frame = curve.fractions.sort_values("points")
    for row in frame.itertuples():
        replicates = curve.replicate_means[int(row.P)]
        ax.plot(np.full(replicates.shape, row.points), replicates, ".", c="0.55", ms=4, zorder=2)
    used = frame["in_fit"].astype(bool) | (curve.status == NOT_FITTED)
    for part, face, label in (
        (
            frame[used],
            "k",
            f"mean of {curve.replicates} replicate(s) (bar: their range; dots: each)",
        ),
        (frame[~used], "white", "left out of the fit: before the power law holds"),
    ):
        if part.empty:
            continue
        ax.errorbar(
            part["points"],
            part["mean_mse"],
            yerr=[
                part["mean_mse"] - part["replicate_low"],
                part["replicate_high"] - part["mean_mse"],
            ],
            fmt="o",
            c="k",
            mfc=face,
            ms=5,
            capsize=3,
            zorder=3,
            label=label,
        )
    for row in frame.itertuples():
        ax.annotate(
            f"P = {int(row.P)} %",
            (row.points, row.replicate_high),
            xytext=(0, 4),
            textcoords="offset points",
            ha="center",
            fontsize=7,
        )
    if curve.status == NOT_FITTED:
        ax.text(
            0.5,
            0.03,
            textwrap.fill(f"curve not fitted: {curve.reason}", 70),
            transform=ax.transAxes,
            ha="center",
            va="bottom",
            fontsize=7,
            bbox={"facecolor": "white", "edgecolor": "0.7", "alpha": 0.9},
        )
    else:
        _curve(ax, curve)
    ax.set(xscale="log", yscale="log", xlabel="points probed (log)", title=title)
    ax.margins(x=0.08, y=0.12)
    low, high = ax.get_ylim()
    narrow = high / low < 3  # close fractions' errors read better on a linear axis
    if narrow:
        ax.set_yscale("linear")
    ax.set_ylabel("mean validation gradient MSE" + ("" if narrow else " (log)"))
    ax.xaxis.set_major_locator(ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(ticker.NullFormatter())
    if not narrow:
        ax.yaxis.set_major_locator(ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:.3g}"))
        ax.yaxis.set_minor_formatter(ticker.NullFormatter())
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _curve(ax, curve: LearningCurve) -> None:
    level = f"{curve.level * 100:g} %"
    grid = np.geomspace(curve.smallest_points, curve.reference_points, 200)
    low, high = curve.band(grid)
    ax.fill_between(grid, low, high, color=CURVE_COLOUR, alpha=0.18, lw=0, zorder=1)
    ax.plot(
        grid,
        curve.predict(grid),
        c=CURVE_COLOUR,
        lw=1.6,
        zorder=2,
        label=f"fitted a + b·(n / {curve.reference_points})^-c, {level} bootstrap band",
    )
    reference = float(curve.predict(curve.reference_points))
    ax.axhline(reference, c="0.3", ls=":", lw=0.9, label=f"P = {curve.reference} % predicted")
    ax.axhline(
        reference * (1 + curve.margin),
        c="tab:green",
        ls="--",
        lw=1.1,
        label=f"P = {curve.reference} % predicted + {curve.margin * 100:g} % margin",
    )
    low_end = curve.smallest_points if curve.low_censored else curve.answer_low
    ax.axvspan(low_end, curve.answer_high, color=ANSWER_COLOUR, alpha=0.15, lw=0)
    ax.axvline(curve.answer, c=ANSWER_COLOUR, lw=1.8)
    below = "≤ " if curve.status == FLAT else ""
    interval = answer_interval(
        curve.answer_low, curve.answer_high, curve.smallest_points, curve.level
    ).replace("at or below", "≤")
    ax.plot(
        [],
        [],
        c=ANSWER_COLOUR,
        lw=6,
        alpha=0.5,
        label=f"answer {below}{int(curve.answer)} points ({interval})",
    )
    ax.annotate(
        f"{below}{int(curve.answer)} points",
        (curve.answer, reference * (1 + curve.margin)),
        xytext=(4, 6),
        textcoords="offset points",
        color=ANSWER_COLOUR,
        fontsize=8,
        fontweight="bold",
    )
