"""Contact centres from the mirror symmetry of each LED's image.

The rim's centre (threedcal.dataset.contacts) drifts with the LED geometry: the shading's
nonlinearity moves the rim's edge peak by an amount that changes across the frame, which an affine
absorbs as a wrong scale. `refine_by_symmetry` uses the one property that holds for any shading
response: a point LED lights a pressed sphere mirror-symmetrically about the line from the LED
through the sphere's centre. Each LED's image (the colour channels unmixed by a matrix fitted to the
same frames) fixes the centre across its axis; two or more LEDs at different azimuths fix it in 2D.
Saturated pixels take no part.

The fit is a small Levenberg–Marquardt on normal equations summed LED by LED (`_SymmetryResiduals`),
never forming the full Jacobian: scipy's least_squares needs the residual vector and its Jacobian
(K·Q × 2+K), several times the work per step, and stops on criteria that do not match the bilinear
samples' noise floor (`STEP_TOLERANCE_PX`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from tqdm import tqdm

from threedcal.dataset.contacts import SATURATED_DN, Contact
from threedcal.errors import RegistrationError


@dataclass(frozen=True)
class _Window:
    """One contact's neighbourhood: colour change per channel (smoothed once) and usability.

    Only a box around the contact is kept (everything a fit can sample, plus the filters' reach,
    so its values equal the whole frame's); points outside the box count as unusable. What is
    kept is each pixel's bilinear cell coefficients (`_bilinear_table`), which is all sampling
    needs.
    """

    # (4P, h*w) float64, P planes: frame − blank per channel, then 1 where usable. Float64, not
    # float32: rounding in the samples makes the fit's steps noise near its minimum.
    table: np.ndarray
    shape: tuple[int, int, int]  # (h, w, P)
    origin: tuple[int, int]  # (row, column) of the box's first pixel in the frame

    @classmethod
    def of(cls, frame: np.ndarray, blank: np.ndarray, smooth_px: float, box=None) -> _Window:
        if frame.shape != blank.shape:
            raise RegistrationError(
                f"frame shape {frame.shape} differs from blank shape {blank.shape}"
            )
        if box is None:
            box = (0, frame.shape[0], 0, frame.shape[1])
        r0, r1, c0, c1 = box
        frame, blank = frame[r0:r1, c0:c1], blank[r0:r1, c0:c1]
        diff = frame.astype(np.float64) - blank.astype(np.float64)
        planes = np.empty(diff.shape[:2] + (4,))
        for c in range(3):
            planes[..., c] = ndimage.gaussian_filter(diff[..., c], smooth_px)
        saturated = ((frame >= SATURATED_DN) | (blank >= SATURATED_DN)).any(axis=-1)
        planes[..., 3] = ndimage.binary_erosion(~saturated, iterations=2, border_value=1)
        return cls(table=_bilinear_table(planes), shape=planes.shape, origin=(r0, c0))

    @classmethod
    def around(
        cls, frame: np.ndarray, blank: np.ndarray, smooth_px: float, contact: Contact, reach: float
    ) -> _Window:
        """The box a symmetry fit of `contact` can reach: its disk, mirrored about any axis through
        a centre moved by up to half a radius (the fit's limit), plus the blur's and erosion's
        reach so that the box's values equal the whole frame's."""
        half = math.ceil((reach + 0.5) * contact.radius_px) + 2 + math.ceil(4 * smooth_px) + 3
        height, width = frame.shape[:2]
        row, col = int(round(contact.y_px)), int(round(contact.x_px))
        box = (
            max(row - half, 0),
            min(row + half + 1, height),
            max(col - half, 0),
            min(col + half + 1, width),
        )
        return cls.of(frame, blank, smooth_px, box)


@dataclass(frozen=True)
class _Disk:
    """Offsets (x, y) from a contact's centre within `reach_px`, `spacing` px apart; the rim at
    `radius_px`."""

    qx: np.ndarray
    qy: np.ndarray
    radius_px: float

    @classmethod
    def around(cls, contact: Contact, reach: float, spacing: int = 1) -> _Disk:
        reach_px = reach * contact.radius_px
        g = np.arange(-math.ceil(reach_px), math.ceil(reach_px) + 1, spacing, dtype=np.float64)
        qx, qy = np.meshgrid(g, g)
        # Each row shifted by a golden-ratio fraction of the spacing: on an integer lattice every
        # sample crosses a pixel boundary at the same centre, and the bilinear residuals kink
        # there together. Spread out, the objective is smoother: fewer iterations, a slightly
        # smaller error (the 9 contacts of tests/dataset/test_registration.py).
        qx = qx + spacing * ((np.arange(g.size)[:, None] * 0.6180339887) % 1.0 - 0.5)
        inside = qx * qx + qy * qy <= reach_px * reach_px
        return cls(qx=qx[inside], qy=qy[inside], radius_px=contact.radius_px)


def _bilinear_table(planes: np.ndarray) -> np.ndarray:
    """Per plane and pixel, the bilinear coefficients of the cell to its lower right, (4P, h*w):
    v00, v01 - v00, v10 - v00 and v11 - v10 - v01 + v00 (the last row and column repeat). Planes
    first: a gather of pixels gives each coefficient's values in a row, as `_sample` returns them
    (pixels first cost a transposing copy of every result, ~20 % of a sample)."""
    p = np.pad(planes, ((0, 1), (0, 1), (0, 0)), mode="edge")
    v00, v01, v10, v11 = p[:-1, :-1], p[:-1, 1:], p[1:, :-1], p[1:, 1:]
    table = np.concatenate([v00, v01 - v00, v10 - v00, v11 - v10 - v01 + v00], axis=-1)
    return np.ascontiguousarray(table.reshape(-1, table.shape[-1]).T)


def _sample(window: _Window, rows: np.ndarray, cols: np.ndarray, gradient: bool = False):
    """Bilinear values (P, ...) of the window's planes (the last: usability) at frame points
    (any shape); points outside the window are 0 and unusable. With `gradient`, also the
    interpolant's derivatives along rows and columns, (P, ...) each.

    One gather of precomputed cell coefficients serves every plane (map_coordinates per plane
    costs ~10x).
    """
    height, width, n = window.shape
    shape = np.shape(rows)
    r = np.ravel(rows) - window.origin[0]
    c = np.ravel(cols) - window.origin[1]
    on = (r >= 0) & (r <= height - 1) & (c >= 0) & (c <= width - 1)
    r = np.clip(r, 0, height - 1)
    c = np.clip(c, 0, width - 1)
    r0 = r.astype(np.intp)
    c0 = c.astype(np.intp)
    fr = r - r0
    fc = c - c0
    cell = window.table[:, r0 * width + c0]
    v00, dc, dr, twist = cell[:n], cell[n : 2 * n], cell[2 * n : 3 * n], cell[3 * n :]
    along_rows = dr + fc * twist
    values = ((v00 + fc * dc + fr * along_rows) * on).reshape((n, *shape))
    if not gradient:
        return values
    along_rows = (along_rows * on).reshape((n, *shape))
    along_cols = ((dc + fr * twist) * on).reshape((n, *shape))
    return values, along_rows, along_cols


def _mirrored(disk: _Disk, centre, axes):
    """Frame (rows, cols), (K, Q) each, of the disk's offsets mirrored about each axis (angles,
    (K,)) through `centre`."""
    ux, uy = np.cos(axes)[:, None], np.sin(axes)[:, None]
    along = disk.qx * ux + disk.qy * uy
    return centre[1] + 2 * along * uy - disk.qy, centre[0] + 2 * along * ux - disk.qx


def _mirror_pairs(window: _Window, disk: _Disk, centre, axes):
    """Per axis k: the colour change at offsets q from `centre` and at q mirrored about axis k.

    Returns (a, b, weight): a (C, Q), b (K, C, Q), weight (K, Q) — 0 where either point of a pair
    is saturated or off the image.
    """
    here = _sample(window, centre[1] + disk.qy, centre[0] + disk.qx)
    there = _sample(window, *_mirrored(disk, centre, np.asarray(axes, dtype=float)))  # (P, K, Q)
    return here[:3], there[:3].transpose(1, 0, 2), here[3] * there[3]


def _dipole_axes(window: _Window, unmixing: np.ndarray, centre, disk: _Disk) -> np.ndarray:
    """Each unmixed channel's first moment about `centre`: the azimuth of its LED, roughly."""
    values = _sample(window, centre[1] + disk.qy, centre[0] + disk.qx)[:3]
    unmixed = unmixing @ values
    return np.arctan2(unmixed @ disk.qy, unmixed @ disk.qx)


def _without_ramps(
    differences: np.ndarray, weight: np.ndarray, axes: np.ndarray, disk: _Disk
) -> np.ndarray:
    """Weighted mirror differences (K, R, Q) about axes (K,), less their best-fitting ramps.

    Not all of frame − blank follows one LED's mirror symmetry: the unmixing leaves some of the
    other LEDs' scattered light (its colour is not their direct light's), and a domed blank is
    shaded on a slope. Across one contact such light varies smoothly, to first order as a ramp,
    whose mirror difference is proportional to the distance from the axis. One such term inside
    the contact and one outside it are fitted and removed. On the Mini's flat gel this takes the
    symmetric centres' RMS error from 0.16 to 0.09 px (a 2 mm ball 1 mm deep at 63 known centres).
    The two terms have disjoint supports, so each is a one-unknown least-squares fit. `weight`
    is (K, Q): each pair's usability about each axis.
    """
    axes = np.asarray(axes, dtype=float)[:, None]
    across = (-disk.qx * np.sin(axes) + disk.qy * np.cos(axes)) * weight  # (K, Q)
    inner = np.hypot(disk.qx, disk.qy) <= disk.radius_px
    weighted = differences * weight[:, None, :]
    for part in (inner, ~inner):
        basis = across * part
        norm = np.einsum("kq,kq->k", basis, basis)
        share = np.einsum("krq,kq->kr", weighted, basis) / np.where(norm > 0, norm, 1.0)[:, None]
        weighted = weighted - share[:, :, None] * basis[:, None, :]
    return weighted


class _SymmetryResiduals:
    """The symmetry fit's normal equations, for one contact and unmixing.

    Residual block k is LED k's image at the disk's offsets minus its value at the offsets mirrored
    about axis k (weighted, less ramps, per usable pair). Its Jacobian comes with it, from the
    bilinear interpolant's own derivatives: one evaluation per iteration instead of one per
    parameter. Held fixed in the Jacobian (not in the residuals): the usability weights, and
    the ramp basis's turn with the axis — both change only where a pair meets a saturated pixel.
    Block k depends on the centre and axis k only: all blocks are evaluated together and the
    normal matrix is summed block by block, never forming the (KQ × 2+K) Jacobian.
    """

    def __init__(self, window: _Window, unmixing: np.ndarray, disk: _Disk):
        self.window, self.unmixing, self.disk = window, unmixing, disk

    def normal_equations(self, params: np.ndarray):
        """(cost, gradient, normal matrix): Σr², Jᵀr and JᵀJ at `params` (centre x, y, axes)."""
        d, k, u = self.disk, len(self.unmixing), self.unmixing
        cx, cy = params[:2]
        axes = params[2:]
        # The colour planes are sampled and then unmixed (cheaper than unmixing the window).
        here, here_dr, here_dc = _sample(self.window, cy + d.qy, cx + d.qx, gradient=True)
        ux, uy = np.cos(axes)[:, None], np.sin(axes)[:, None]
        along = d.qx * ux + d.qy * uy
        across = -d.qx * uy + d.qy * ux
        there, there_dr, there_dc = _sample(
            self.window, cy + 2 * along * uy - d.qy, cx + 2 * along * ux - d.qx, True
        )  # (P, K, Q): every plane about every axis; axis k reads LED k's image
        weight = here[3] * there[3]
        here, here_dr, here_dc = (
            np.einsum("kj,jq->kq", u, v[:3]) for v in (here, here_dr, here_dc)
        )
        there, there_dr, there_dc = (
            np.einsum("kj,jkq->kq", u, v[:3]) for v in (there, there_dr, there_dc)
        )
        # the mirrored point moves with the centre one for one, and turns with the axis
        turn = -(there_dc * 2 * (across * ux - along * uy))
        turn -= there_dr * 2 * (across * uy + along * ux)
        stack = np.stack([here - there, here_dc - there_dc, here_dr - there_dr, turn], axis=1)
        # (K, 4, Q): residual, then its derivatives along x, y and axis k
        # Per pair usable: the mean, not the sum, so that pushing pairs onto saturated pixels
        # (weight 0) does not pay.
        cleaned = _without_ramps(stack, weight, axes, d)
        cleaned /= np.sqrt(np.maximum(weight.sum(axis=1), 1e-9))[:, None, None]
        blocks = np.einsum("kiq,kjq->kij", cleaned, cleaned)  # (K, 4, 4)
        gradient, normal = np.zeros(params.size), np.zeros((params.size, params.size))
        for j in range(k):
            block = [0, 1, 2 + j]
            gradient[block] += blocks[j, 1:, 0]
            normal[np.ix_(block, block)] += blocks[j, 1:, 1:]
        return float(blocks[:, 0, 0].sum()), gradient, normal


def _levenberg_marquardt(problem, start: np.ndarray, scale: np.ndarray, tolerance: float):
    """Minimise Σr² from the problem's normal equations; (x, converged, Σr² at x).

    Steps are taken in units of `scale` (a pixel of centre, 0.05 rad of axis). The fit has
    converged once a step would move the first two unknowns (the centre) by less than
    `tolerance` (taken if it lowers the cost): near the minimum the bilinear samples make the
    cost bumpy at that scale, and further steps only polish noise. Damping (a multiple of the
    normal matrix's diagonal) shrinks after a step that lowered the cost and grows after one
    that did not; a problem with few unknowns needs no more.
    """
    x = start.astype(np.float64)
    cost, gradient, normal = problem.normal_equations(x)
    if not np.isfinite(cost):
        return x, False, cost
    damping = 1e-4
    for _ in range(MAX_FIT_EVALUATIONS):
        scaled = normal * np.outer(scale, scale)
        diagonal = np.maximum(np.diag(scaled), 1e-12)
        try:
            step = -np.linalg.solve(scaled + damping * np.diag(diagonal), gradient * scale)
        except np.linalg.LinAlgError:
            return x, False, cost
        short = float(np.linalg.norm(step[:2] * scale[:2])) < tolerance
        trial = x + step * scale
        trial_cost, trial_gradient, trial_normal = problem.normal_equations(trial)
        if np.isfinite(trial_cost) and trial_cost <= cost:
            x, cost, gradient, normal = trial, trial_cost, trial_gradient, trial_normal
            damping = max(damping / 10, 1e-7)
        else:
            damping *= 10
        if short:  # the minimum lies within `tolerance` of x (a shorter step cannot help)
            return x, True, cost
    return x, False, cost


# Evaluations one symmetry fit may spend (as many as scipy's least_squares allows per unknown).
MAX_FIT_EVALUATIONS = 100
# The fit samples the disk every SAMPLE_SPACING_PX pixels (each row still shifted by a fraction):
# a quarter of the samples and of the cost, for about 4 % more noise per contact against the known
# centres (benchmarks/bench_registration.py, tests/dataset/test_registration.py, Mini contacts at
# 1-3 mm), which an affine over many contacts averages.
SAMPLE_SPACING_PX = 2
# A fit left this many times less symmetric than the set's median is dropped, not kept: on the
# Mini's frames overexposed by 20 % (tests/dataset/test_registration.py) a contact the clipping
# cuts in two kept a centre 7 px off at about 23x the median cost; the sound fits lie within 2.5x.
ASYMMETRY_OUTLIER = 5.0
# Below this spread of the usable mirror axes (`_axes_information`) the centre along their common
# line is the anchor's (the rim's): the fit's own is only where the damped steps happened to stop.
MIN_AXES_SPREAD = 0.1
# A fit has converged once a step would move the centre by less than this (px). The axes may
# still creep then; the centre no longer follows them by more than noise.
STEP_TOLERANCE_PX = 5e-3


def _symmetry_fit(
    window: _Window, unmixing: np.ndarray, coarse: Contact, reach: float, anchor=None
):
    """(centre x, centre y, axes, cost) that make every unmixed channel mirror-symmetric, or None.
    `cost` is what is left of the asymmetry: the mean squared mirror difference per usable pair
    (DN², summed over the LEDs). `anchor` (x, y; default the start) fixes the centre along the
    axes' line where they are one."""
    disk = _Disk.around(coarse, reach, SAMPLE_SPACING_PX)
    start = np.array([coarse.x_px, coarse.y_px])
    axes0 = _dipole_axes(window, unmixing, start, disk)
    x, converged, cost = _levenberg_marquardt(
        _SymmetryResiduals(window, unmixing, disk),
        np.concatenate([start, axes0]),
        np.concatenate([[1.0, 1.0], np.full(len(axes0), 0.05)]),  # a pixel; 0.05 rad of axis
        tolerance=STEP_TOLERANCE_PX,
    )
    cx, cy = x[:2]
    _, _, w = _mirror_pairs(window, disk, (cx, cy), x[2:])
    usable = float(w.mean())
    moved = math.hypot(cx - coarse.x_px, cy - coarse.y_px)
    if not converged or usable < 0.1 or moved > 0.5 * coarse.radius_px:
        return None
    spread, across = _axes_information(x[2:], w.mean(axis=1))
    if spread < MIN_AXES_SPREAD:
        # The usable axes are one line: symmetry fixes the centre across it, the anchor along it.
        anchor = start if anchor is None else np.asarray(anchor, dtype=float)
        cx, cy = anchor + across * float(across @ (np.array([cx, cy]) - anchor))
    return float(cx), float(cy), x[2:], cost


def _axes_information(axes: np.ndarray, usable: np.ndarray) -> tuple[float, np.ndarray]:
    """How well the mirror axes fix a centre in 2D, and the direction they fix best.

    Each axis fixes the centre across itself only, weighted by its usable pairs' share. Returns
    the smaller over the larger eigenvalue of the summed information (1: two equal axes at right
    angles; 0: every usable axis on one line, as when only the Mini's facing red and green LEDs
    are left) and the larger one's unit eigenvector."""
    normals = np.stack([-np.sin(axes), np.cos(axes)], axis=1)
    information = np.einsum("k,ki,kj->ij", np.asarray(usable, dtype=float), normals, normals)
    values, vectors = np.linalg.eigh(information)
    spread = float(values[0] / values[1]) if values[1] > 0 else 0.0
    return spread, vectors[:, 1]


def _symmetric_outliers(costs: np.ndarray) -> np.ndarray:
    """Which fits stayed far less symmetric than the set's typical one: a centre that settled on
    a false minimum, where clipping left only pairs that happen to match (cost above
    ASYMMETRY_OUTLIER times the median cost of the set's fits)."""
    costs = np.asarray(costs, dtype=float)
    if costs.size < 3:
        return np.zeros(costs.size, bool)
    return costs > ASYMMETRY_OUTLIER * np.median(costs)


def _fit_unmixing(windows, fits, contacts, reach: float) -> np.ndarray:
    """Rows w_k (w_kk = 1) that make channel mix w_k · ΔI mirror-symmetric about LED k's axes."""
    rows = []
    for k in range(3):
        differences = []
        for window, (cx, cy, axes, _), contact in zip(windows, fits, contacts, strict=True):
            disk = _Disk.around(contact, reach, SAMPLE_SPACING_PX)
            a, b, w = _mirror_pairs(window, disk, (cx, cy), axes[k : k + 1])
            differences.append(_without_ramps((a - b[0])[None], w, axes[k : k + 1], disk)[0].T)
        d = np.concatenate(differences)  # (pairs, C)
        others = [c for c in range(3) if c != k]
        solution, *_ = np.linalg.lstsq(d[:, others], -d[:, k], rcond=None)
        row = np.zeros(3)
        row[k], row[others] = 1.0, solution
        rows.append(row)
    return np.asarray(rows)


@dataclass(frozen=True)
class SymmetryRefinement:
    contacts: list[Contact | None]  # the refined contact of each input (None: no usable fit)
    unmixing: np.ndarray  # (3, 3): row k mixes the colour channels into LED k's image


def refine_by_symmetry(
    frames,
    blank: np.ndarray,
    coarse: list[Contact | None],
    rounds: int = 2,
    reach: float = 1.4,
    smooth_px: float = 1.0,
    calibration_contacts: int = 40,
    progress: bool = False,
    anchors: list[Contact | None] | None = None,
) -> SymmetryRefinement:
    """Contact centres from the mirror symmetry of each LED's image (see the module docstring).

    `frames[i]` is an (H, W, 3) frame with contact `coarse[i]` (from `locate_contact`; None is
    passed through). The unmixing starts as the identity and is refitted `rounds` times on up to
    `calibration_contacts` contacts spread over the list; the radius stays the rim's. Where a
    contact's usable mirror axes are one line, the centre along it is `anchors[i]`'s (default
    `coarse[i]`: pass the rim's when the fits start elsewhere). Fits far less symmetric than the
    set's (`_symmetric_outliers`) are dropped.
    """
    if np.ndim(blank) != 3 or np.shape(blank)[2] != 3:
        raise RegistrationError(
            f"symmetry refinement needs RGB frames (H, W, 3), got shape {np.shape(blank)}"
        )
    present = [i for i, c in enumerate(coarse) if c is not None]
    unmixing = np.eye(3)
    calibration = (
        [present[j] for j in np.linspace(0, len(present) - 1, calibration_contacts).astype(int)]
        if len(present) > calibration_contacts
        else present
    )

    def anchor(i: int):
        c = (anchors or coarse)[i]
        return None if c is None else (c.x_px, c.y_px)

    def window(i: int) -> _Window:
        return _Window.around(np.asarray(frames[i]), blank, smooth_px, coarse[i], reach)

    windows = {i: window(i) for i in calibration}
    for _ in range(rounds):
        fits, used = [], []
        for i in calibration:
            fit = _symmetry_fit(windows[i], unmixing, coarse[i], reach, anchor(i))
            if fit is not None:
                fits.append(fit)
                used.append(i)
        if len(used) < 3:
            break
        unmixing = _fit_unmixing([windows[i] for i in used], fits, [coarse[i] for i in used], reach)
    fits = {}
    for i in tqdm(present, desc="symmetric centres", unit="contact", disable=not progress):
        fit = _symmetry_fit(windows.get(i) or window(i), unmixing, coarse[i], reach, anchor(i))
        if fit is not None:
            fits[i] = fit
    outliers = _symmetric_outliers([fit[3] for fit in fits.values()])
    contacts: list[Contact | None] = [None] * len(coarse)
    for (i, fit), outlier in zip(fits.items(), outliers, strict=True):
        if not outlier:
            c = coarse[i]
            contacts[i] = Contact(
                x_px=fit[0], y_px=fit[1], radius_px=c.radius_px, strength=c.strength
            )
    return SymmetryRefinement(contacts=contacts, unmixing=unmixing)
