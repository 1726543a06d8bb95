"""Elastic contact of a rigid indenter with a soft gel layer bonded to a rigid backing (the acrylic).

The gel is a linear-elastic layer of thickness h, Young's modulus E and Poisson ratio nu, bonded to a
rigid base, its free surface pressed by a rigid, frictionless indenter; the half-space is the limit
h -> inf. Only normal pressure acts on the surface (frictionless contact), so the surface's normal
displacement is the pressure convolved with the layer's surface Green's function (threedcal.sim.layer_kernel).

Contact (Polonsky & Keer, Wear 231, 206, 1999). With the indenter's interference w (how far its surface
lies below the undeformed gel surface, mm; -inf where it has no surface) the pressure p >= 0 and the
gap g = u - w satisfy g >= 0, p g = 0. Conjugate gradients on the pressure over the active set,
projected onto p >= 0, with points that penetrate added back into the active set; the rigid approach
is prescribed (displacement control), so the load-balance step of the original algorithm is not used.
The convolution is linear (not periodic): the pressure is zero-padded to twice the domain before the
FFT, so no image contacts leak in.

Units: mm, MPa (N/mm^2), N.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from threedcal.errors import ConfigError
from threedcal.sim.layer_kernel import RHO_MAX, GelMaterial, LayerKernel

_SPARSE_UPDATES = 24  # up to this many nodes set apart from a CG step: direct sums, not an FFT


def _mirrored(table: np.ndarray) -> np.ndarray:
    """The lag table K[|dy|, |dx|] as K[dy + ny - 1, dx + nx - 1] for every signed lag."""
    rows = np.concatenate([table[:0:-1], table], axis=0)
    return np.concatenate([rows[:, :0:-1], rows], axis=1)


@dataclass
class ContactResult:
    """The solution on the solver grid: pressure (MPa), surface displacement (mm, into the gel)."""

    pressure: np.ndarray
    displacement: np.ndarray
    force_n: float
    iterations: int
    converged: bool
    gap_tolerance_mm: float = 0.0  # the largest gap error left in contact

    @property
    def contact(self) -> np.ndarray:
        return self.pressure > 0


def solve_contact(
    kernel: LayerKernel,
    interference: np.ndarray,
    *,
    initial: np.ndarray | None = None,
    tol: float = 1e-6,
    max_iter: int = 2000,
    single: bool | None = None,
) -> ContactResult:
    """Pressure and displacement of a rigid indenter pressed into the gel (Polonsky & Keer, CG).

    `interference[i, j]`: how far the indenter's surface lies below the undeformed gel surface (mm)
    at element (i, j); -inf or NaN where the indenter has no surface there (it never touches).
    Converged when the largest gap error in contact is below `tol` times the largest interference.
    `initial` (a previous pressure on the same grid) warm-starts the iteration. `single`: FFTs in
    float32 (default when tol >= 1e-4, where their ~1e-7 relative error is far below the tolerance).
    """
    w = np.asarray(interference, dtype=np.float64)
    if w.ndim != 2:
        raise ConfigError(f"interference must be a 2-D grid, got shape {w.shape}")
    if np.isposinf(w).any():
        raise ConfigError("interference holds +inf (an indenter infinitely deep into the gel)")
    admissible = np.isfinite(w)
    w = np.where(admissible, w, -np.inf)
    top = float(w.max()) if admissible.any() else -np.inf
    zero = np.zeros(w.shape)
    if not top > 0:
        return ContactResult(zero, zero.copy(), 0.0, 0, True, 0.0)
    single = tol >= 1e-4 if single is None else single

    def conv(q: np.ndarray) -> np.ndarray:
        return kernel.convolve(q, single).astype(np.float64)

    p = _start_pressure(w, admissible, top, initial, conv)
    u = conv(p)
    scale = tol * top
    t = zero.copy()
    g_old, delta, converged, iterations = 1.0, 0.0, False, 0
    self_influence = float(kernel.influence(1, 1)[0, 0])
    influence = _Influence(kernel, w.shape)
    while iterations < max_iter:
        iterations += 1
        gap = u - w
        active = p > 0
        g_act = gap[active]
        err = float(np.abs(g_act).max()) if g_act.size else 0.0
        if err <= scale and not np.any(gap[~active & admissible] < -scale):
            converged = True
            break
        g_sum = float(g_act @ g_act)
        t = np.where(active, gap + (delta * g_sum / g_old) * t, 0.0)
        g_old = max(g_sum, 1e-300)
        r = conv(t)
        denom = float(r[active] @ t[active])
        tau = float(g_act @ t[active]) / denom if denom > 0 else 0.0
        step = p - tau * t  # t = 0 off the active set
        p = np.maximum(step, 0.0)
        overlap = (p == 0) & (gap < 0) & admissible
        if overlap.any():
            # penetrating points join the contact (PK's step; an element's own stiffness if tau <= 0)
            delta = 0.0
            p[overlap] = -gap[overlap] * (tau if tau > 0 else 1.0 / self_influence)
        else:
            delta = 1.0
        u = influence.moved(u, p, step, tau, r, conv)
    force = float(p.sum()) * kernel.spacing_mm**2
    return ContactResult(p, u, force, iterations, converged, scale)


def _start_pressure(w, admissible, top: float, initial, conv) -> np.ndarray:
    """A warm start (`initial`, a previous pressure on the same grid), else a first guess:
    sqrt(w - top/2), scaled to fit u = w in least squares. For a paraboloid on a half-space this is
    Hertz's solution (contact a^2 = R d where w > d/2, p ~ sqrt(a^2 - r^2))."""
    if initial is not None and initial.shape == w.shape:
        p = np.where(admissible, np.maximum(initial, 0.0), 0.0)
    else:
        p = np.zeros(w.shape)
    if not p.any():
        q = np.sqrt(np.maximum(w - 0.5 * top, 0.0))
        kq = conv(q)
        fit = w > 0
        p = q * (float(kq[fit] @ w[fit]) / max(float(kq[fit] @ kq[fit]), 1e-300))
    return p


class _Influence:
    """u = K p kept up to date by linearity within one solve."""

    def __init__(self, kernel: LayerKernel, shape: tuple[int, int]):
        self.kernel, self.shape, self.lags = kernel, shape, None

    def moved(self, u, p, step, tau: float, r, conv) -> np.ndarray:
        """The CG step moved u by -tau r; the few nodes the projection or the new contact points
        set apart (p != step) add their own influence (a full convolution if many)."""
        changed = np.flatnonzero(p != step)
        if changed.size > _SPARSE_UPDATES:
            return conv(p)
        u = u - tau * r
        if changed.size:
            if self.lags is None:
                self.lags = _mirrored(self.kernel.influence(*self.shape))
            ny, nx = self.shape
            for i, j in zip(*np.unravel_index(changed, self.shape), strict=True):
                u += (p[i, j] - step[i, j]) * self.lags[
                    ny - 1 - i : 2 * ny - 1 - i, nx - 1 - j : 2 * nx - 1 - j
                ]
        return u


@dataclass
class ElasticPress:
    """One solved press. Its node lattice is centred on the indenter: node (i, j) sits at
    (x0 + j s, y0 + i s) mm with (x0, y0) = `origin_mm`, so the discretisation is symmetric about
    the axis wherever the press sits. `domain` = (row0, col0) of the pressure grid's first node."""

    gel: ElasticGel
    origin_mm: tuple[float, float]
    domain: tuple[int, int]
    result: ContactResult
    interference: Callable[[np.ndarray, np.ndarray], np.ndarray]

    def interference_at(self, X, Y) -> np.ndarray:
        """The indenter's interference (mm) at points (X, Y) mm; -inf where it has no surface."""
        w = np.asarray(self.interference(X, Y), dtype=np.float64)
        return np.where(np.isnan(w), -np.inf, w)

    @property
    def force_n(self) -> float:
        return self.result.force_n

    @property
    def pressure(self) -> np.ndarray:
        return self.result.pressure

    @property
    def spacing_mm(self) -> float:
        return self.gel.spacing_mm

    def node_coords(self, box: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
        """(X, Y) mm of the lattice nodes in `box` (row0, row1, col0, col1)."""
        return _node_coords(self.origin_mm, self.spacing_mm, box)

    def nodes_covering(self, x0: float, x1: float, y0: float, y1: float):
        """Smallest lattice box (row0, row1, col0, col1) whose nodes cover [x0, x1] x [y0, y1] mm."""
        return _nodes_covering(self.origin_mm, self.spacing_mm, x0, x1, y0, y1)

    def node_box(self) -> tuple[int, int, int, int]:
        """(row0, row1, col0, col1) lattice indices of the pressure grid (end exclusive)."""
        r0, c0 = self.domain
        ny, nx = self.result.pressure.shape
        return r0, r0 + ny, c0, c0 + nx

    def displacement_on(self, box: tuple[int, int, int, int]) -> np.ndarray:
        """Surface displacement (mm, into the gel) on the lattice nodes of `box` (row0, row1, col0, col1)."""
        r0, r1, c0, c1 = box
        d0, d1, e0, e1 = self.node_box()
        if (r0, r1, c0, c1) == (d0, d1, e0, e1):
            return self.result.displacement
        u0, u1, v0, v1 = min(r0, d0), max(r1, d1), min(c0, e0), max(c1, e1)
        # round the union up so that few FFT shapes (and cached spectra) occur
        ny = -(-(u1 - u0) // 8) * 8
        nx = -(-(v1 - v0) // 8) * 8
        p = np.zeros((ny, nx))
        p[d0 - u0 : d1 - u0, e0 - v0 : e1 - v0] = self.result.pressure
        u = self.gel.kernel.convolve(p, single=True)
        return u[r0 - u0 : r1 - u0, c0 - v0 : c1 - v0]

    def reach_mm(self, slope: float, height_mm: float) -> float:
        """Distance from the pressure grid's edge beyond which the force's far field has a slope below
        `slope` and a displacement below `height_mm` (the limit of what the optics can see)."""
        return self.gel.reach_mm(self.force_n, slope, height_mm)


def _node_coords(origin, s, box):
    r0, r1, c0, c1 = box
    return np.meshgrid(origin[0] + np.arange(c0, c1) * s, origin[1] + np.arange(r0, r1) * s)


def _nodes_covering(origin, s, x0, x1, y0, y1):
    ox, oy = origin
    return (
        math.floor((y0 - oy) / s),
        math.ceil((y1 - oy) / s) + 1,
        math.floor((x0 - ox) / s),
        math.ceil((x1 - ox) / s) + 1,
    )


class ElasticGel:
    """Presses rigid indenters into a gel layer on node lattices of spacing `spacing_mm`.

    The caller supplies the indenter as a function interference(X, Y) -> w (mm below the undeformed
    surface, -inf where it has no surface), a bounding box it cannot reach beyond, and the lattice
    origin (its axis: the solution is then the same, relative to the axis, wherever it presses a flat
    gel, and mirror-symmetric for a symmetric indenter).
    """

    def __init__(
        self, material: GelMaterial, spacing_mm: float, *, tol: float = 1e-4, max_iter: int = 2000
    ):
        self.material = material
        self.kernel = LayerKernel(material, spacing_mm)
        self.spacing_mm = float(spacing_mm)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self._tail: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def press(self, interference, bounds_mm, origin_mm=(0.0, 0.0)) -> ElasticPress | None:
        """Solve the contact of the indenter `interference` confined to `bounds_mm` (x0, x1, y0, y1)
        on the lattice through `origin_mm`.

        None when it does not touch the gel. The result depends on these arguments alone (no state
        carried from earlier presses), so a frame renders to the same bytes in any order or after a
        resumed run.
        """
        origin = (float(origin_mm[0]), float(origin_mm[1]))
        box = _nodes_covering(origin, self.spacing_mm, *bounds_mm)
        X, Y = _node_coords(origin, self.spacing_mm, box)
        w_all = np.asarray(interference(X, Y), dtype=np.float64)
        if np.isposinf(w_all).any():
            raise ConfigError("indenter interference holds +inf")
        w_all = np.where(np.isnan(w_all), -np.inf, w_all)
        top = float(w_all.max()) if w_all.size else -np.inf
        if not top > 0:
            return None
        # A near-incompressible layer bulges up around the contact, so it may touch the indenter where
        # the indenter stays above the undeformed surface. No point can rise more than F |G_min|
        # (p >= 0 everywhere, G_min the most negative point response), so solving over every node with
        # w > -margin, margin > F |G_min|, misses no contact; widen and re-solve until that holds.
        rise = self.max_rise_per_newton
        margin = 0.05 * top if rise > 0 else 0.0
        warm = None
        while True:
            rows, cols = np.nonzero(w_all > -margin)
            sub = (
                max(rows.min() - 2, 0),
                min(rows.max() + 3, w_all.shape[0]),
                max(cols.min() - 2, 0),
                min(cols.max() + 3, w_all.shape[1]),
            )
            w = w_all[sub[0] : sub[1], sub[2] : sub[3]]
            domain = (box[0] + sub[0], box[2] + sub[2])
            initial = _placed(warm, domain, w.shape) if warm is not None else None
            result = solve_contact(
                self.kernel, w, initial=initial, tol=self.tol, max_iter=self.max_iter
            )
            solved = ElasticPress(self, origin, domain, result, interference)
            needed = rise * result.force_n
            if margin >= needed or sub == (0, w_all.shape[0], 0, w_all.shape[1]):
                break
            margin = 1.5 * needed
            warm = solved  # the narrower solve starts the wider one
        return solved

    @cached_property
    def max_rise_per_newton(self) -> float:
        """-min_r G(r) (mm/N, >= 0): the most a unit force can lift any surface point (0 for a
        half-space, which only sinks)."""
        m = self.material
        if math.isinf(m.thickness_mm):
            return 0.0
        r = np.linspace(0.02, RHO_MAX, 6000) * m.thickness_mm
        return max(-float(self.kernel.point(r).min()), 0.0)

    def reach_mm(self, force_n: float, slope: float, height_mm: float) -> float:
        """Radius beyond which a point force `force_n` raises or lowers the surface by less than
        `height_mm` with a slope below `slope` (finite for a layer; for a half-space the 1/r tail
        gives force/(pi E* height) and the slope's force/(pi E* r^2))."""
        if force_n <= 0:
            return 0.0
        m = self.material
        if math.isinf(m.thickness_mm):
            es = m.plane_strain_modulus
            return max(
                force_n / (math.pi * es * height_mm), math.sqrt(force_n / (math.pi * es * slope))
            )
        if self._tail is None:
            r = np.linspace(0.02, RHO_MAX, 6000) * m.thickness_mm
            g = self.kernel.point(r)
            self._tail = (r, np.abs(g), np.abs(np.gradient(g, r)))
        r, height, tilt = self._tail
        above = np.nonzero((force_n * height > height_mm) | (force_n * tilt > slope))[0]
        return float(r[above[-1]]) if above.size else 0.0


def _placed(previous: ElasticPress, domain: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """The previous pressure moved onto a new domain of the same lattice (zero where it had none)."""
    out = np.zeros(shape)
    r0, c0 = previous.domain
    p = previous.result.pressure
    dr, dc = r0 - domain[0], c0 - domain[1]
    a0, a1 = max(dr, 0), min(dr + p.shape[0], shape[0])
    b0, b1 = max(dc, 0), min(dc + p.shape[1], shape[1])
    if a0 < a1 and b0 < b1:
        out[a0:a1, b0:b1] = p[a0 - dr : a1 - dr, b0 - dc : b1 - dc]
    return out
