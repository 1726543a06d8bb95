"""The quick calibration's stop rule: did the last round's data lower the error on unseen presses?

Prequential, so it cannot flatter itself: round k's presses are scored before any model has
trained on them, by two models — the one before round k−1's data and the one after it. Each
press gives a paired log ratio d = log(mse_before / mse_after); pairing removes how hard a press
is (a spot near the rim is harder for both models), and the log makes a press's share
independent of its error's scale. The relative improvement is 1 − exp(−mean d) (the geometric
mean ratio), and its one-sided upper confidence bound comes from Student's t on the d's. The
calibration stops when that bound lies below the margin: at the stated confidence, one more
round of the same size would improve the error by less than the margin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats


@dataclass(frozen=True)
class Improvement:
    """What round k−1's data did to the error on round k's presses."""

    estimate: float  # relative improvement, 1 − geometric mean of after / before
    upper: float  # its one-sided upper confidence bound
    presses: int  # paired presses it rests on


def rule_problems(margin: float, confidence: float, where: str = "quick") -> list[str]:
    """What is wrong with a margin or confidence the rule cannot use, naming the key."""
    problems = []
    if not (math.isfinite(margin) and 0 < margin < 1):
        problems.append(
            f"{where}.margin: {margin!r} is not a relative improvement between 0 and 1 "
            "(e.g. 0.05: stop once a round is confidently worth less than 5 %)"
        )
    if not (math.isfinite(confidence) and 0.5 <= confidence < 1):
        problems.append(
            f"{where}.confidence: {confidence!r} must lie in [0.5, 1) (e.g. 0.9, one-sided)"
        )
    return problems


def paired_improvement(before, after, confidence: float) -> Improvement:
    """The relative improvement from `before` to `after` (per-press errors, paired, all > 0) and
    its one-sided upper bound at `confidence`. With one press the bound is infinite (no spread)."""
    before = np.asarray(before, dtype=float)
    after = np.asarray(after, dtype=float)
    if before.shape != after.shape or before.ndim != 1 or before.size == 0:
        raise ValueError(f"paired errors expected, got shapes {before.shape} and {after.shape}")
    if not (
        np.all(np.isfinite(before) & (before > 0)) and np.all(np.isfinite(after) & (after > 0))
    ):
        raise ValueError("per-press errors must be positive and finite")
    d = np.log(before) - np.log(after)
    mean = float(d.mean())
    if d.size < 2:
        upper_d = math.inf
    else:
        spread = float(d.std(ddof=1)) / math.sqrt(d.size)
        upper_d = mean + float(stats.t.ppf(confidence, d.size - 1)) * spread
    return Improvement(
        estimate=1 - math.exp(-mean),
        upper=1.0 if math.isinf(upper_d) else 1 - math.exp(-upper_d),
        presses=int(d.size),
    )


@dataclass(frozen=True)
class Decision:
    go_on: bool
    reason: str  # "continue", "improvement below margin" or "cap"


def decide(improvement: Improvement | None, margin: float, at_cap: bool) -> Decision:
    """Stop when the improvement's upper bound is below the margin, else at the cap; round 1
    (no improvement to measure yet) goes on unless it is the cap."""
    if improvement is not None and improvement.upper < margin:
        return Decision(False, "improvement below margin")
    if at_cap:
        return Decision(False, "cap")
    return Decision(True, "continue")
