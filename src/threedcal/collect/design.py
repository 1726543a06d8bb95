"""Space-filling press designs: where a few presses go so that any prefix of rounds covers the gel.

A quick calibration stops after an unknown number of rounds, so the presses of every round prefix
must already spread evenly over the area, not just the whole plan. A regular grid does not have
that property (its first rows fill one edge); a scrambled Halton sequence does: each prefix has
low discrepancy whatever its length, and the seed makes it reproducible. Within a round the presses
are reordered into a short nearest-neighbour path, which changes no round's set.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import qmc

# Scrambles drawn for a design; the one whose worst round prefix spreads most evenly is kept.
SCRAMBLES = 16


def halton_design(count: int, area_mm, seed: int, round_size: int | None = None) -> np.ndarray:
    """(count, 2) press centres (x, y mm) over `area_mm` = (x0, y0, x1, y1): a scrambled Halton
    sequence, so every prefix is itself evenly spread. Of SCRAMBLES scrambles drawn from `seed`,
    the one whose worst prefix of whole rounds (`round_size`; default every prefix) has the lowest
    discrepancy relative to its size is kept: a single scramble's first round of ten can be
    as uneven as a random design's."""
    x0, y0, x1, y1 = (float(v) for v in area_mm)
    count = int(count)
    sizes = range(int(round_size or 1), count + 1, int(round_size or 1))
    best, best_score = None, np.inf
    for scramble in np.random.SeedSequence([int(seed), 0x0A17]).spawn(SCRAMBLES):
        unit = qmc.Halton(d=2, scramble=True, seed=np.random.default_rng(scramble)).random(count)
        # a uniformly random design's discrepancy falls as 1/n: n * D compares prefixes fairly
        score = max(n * qmc.discrepancy(unit[:n], method="CD") for n in sizes)
        if score < best_score:
            best, best_score = unit, score
    return np.column_stack([x0 + best[:, 0] * (x1 - x0), y0 + best[:, 1] * (y1 - y0)])


def round_order(points: np.ndarray, round_size: int, start=None) -> np.ndarray:
    """Indices that visit each round's points (consecutive blocks of `round_size`) along a greedy
    nearest-neighbour path, each round starting next to where the last one ended."""
    points = np.asarray(points, dtype=float)
    order: list[int] = []
    here = np.asarray(points[0] if start is None else start, dtype=float)
    for first in range(0, len(points), round_size):
        left = list(range(first, min(first + round_size, len(points))))
        while left:
            distances = np.linalg.norm(points[left] - here, axis=1)
            nearest = left.pop(int(np.argmin(distances)))
            order.append(nearest)
            here = points[nearest]
    return np.asarray(order, dtype=int)


def covering_radius(points, area_mm, resolution: int = 200) -> float:
    """The largest empty circle's radius (mm): how far a spot of the area can lie from its nearest
    press, over a `resolution`² grid of the area (the exact value is the grid's as it refines)."""
    x0, y0, x1, y1 = (float(v) for v in area_mm)
    gx, gy = np.meshgrid(np.linspace(x0, x1, resolution), np.linspace(y0, y1, resolution))
    distance, _ = cKDTree(np.asarray(points, dtype=float)).query(
        np.column_stack([gx.ravel(), gy.ravel()])
    )
    return float(distance.max())


def hexagonal_covering_radius(count: int, area_mm) -> float:
    """The covering radius of `count` presses on a hexagonal lattice filling the area: the least
    any design of that many can reach (edges aside), the yardstick of `covering_radius`."""
    x0, y0, x1, y1 = (float(v) for v in area_mm)
    return float(np.sqrt(2 * (x1 - x0) * (y1 - y0) / (3 * np.sqrt(3) * count)))


def discrepancy(points, area_mm) -> float:
    """The centred L2 discrepancy of the presses mapped to the unit square (0: perfectly even)."""
    x0, y0, x1, y1 = (float(v) for v in area_mm)
    points = np.asarray(points, dtype=float)
    unit = (points - [x0, y0]) / [x1 - x0, y1 - y0]
    return float(qmc.discrepancy(np.clip(unit, 0.0, 1.0), method="CD"))
