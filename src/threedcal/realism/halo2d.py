"""The shading around a contact in two dimensions, real against simulated: the realism check's 2-D
figures (radially averaged statistics cannot see a halo that is round in one and a triangle in the
other).

Per press, the contact change (frame − background less the frame's lighting drift,
`realism.contact_change`) is blurred by half a grid step and resampled on a grid in *contact radii*
centred on the contact: u = (x − cx) / r, v = (y − cy) / r, −REACH ≤ u, v ≤ REACH, step STEP
(`cutout`). Real and simulated cut-outs of a press use the same centre and radius (the press as the
folder gives it), so a contact of another size shows as a difference. Cut-outs are averaged over
presses (`mean_image`; a grid point seen in fewer than MIN_COVERAGE of them, off the frame, is left
out). The figures, on the halo = the annulus 1 < rho <= REACH outside the contact:

- ``halo_nrms``: the RMS over the annulus and channels of (mean image − the real mean image) over
  the RMS of the real mean image there (`nrms`): 0 for identical images, 1 for a flat zero image.
- ``halo_m1_up`` / ``halo_m1_right``: the first angular Fourier moments of the halo's magnitude
  M = sum over channels of |mean image|, sum(M (−v / rho)) / sum(M) and sum(M u / rho) / sum(M)
  (`first_moments`): 0 for a round halo; positive when the halo reaches further up (toward row 0)
  or right; +1 for all of it straight up. A halo shaped like a triangle pointing up the image,
  beyond a contact at its base, has halo_m1_up > 0.

The tolerance comes from the real frames alone, stated before any simulated value was computed:
**the simulator must be as close to the held-out real mean as the other half of the real frames
is** (`tolerance`). The reference distance is that of the fitting half's real mean (other presses,
other places, the same sensor) from the held-out half's; its bootstrap by press (presses resampled
with replacement within each half, B draws) gives an interval, and the tolerance is its upper end
(97.5 %). A figure passes when the simulator's distance from the held-out real mean (the point
estimate, over the same presses) is at most the tolerance. For the moments the distance is the
absolute difference; for the image it is halo_nrms itself. Every quoted figure carries its 95 %
bootstrap interval (presses resampled; the simulator's renders resampled with their real frames).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from threedcal.errors import ConfigError
from threedcal.plotting import pyplot
from threedcal.realism.check import contact_change, image_groups

REACH = 3.0  # cut-outs reach 3 contact radii (realism.HALO_MAX_RADII)
STEP = 0.1  # grid step, contact radii: 61 x 61 points
MIN_COVERAGE = 0.5  # a grid point enters the mean where at least half the presses see it
BOOTSTRAP = 500
LEVEL = 0.95
FIGURES = ("halo_nrms", "halo_m1_up", "halo_m1_right", "halo_m3_up")


def radius_grid(reach: float = REACH, step: float = STEP) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) in contact radii, each (n, n), n = 2 round(reach / step) + 1; v down the image."""
    half = int(round(reach / step))
    axis = np.arange(-half, half + 1, dtype=np.float64) * step
    return np.meshgrid(axis, axis)


def cutout(
    change: np.ndarray,
    center_px: Sequence[float],
    radius_px: float,
    *,
    reach: float = REACH,
    step: float = STEP,
    name: str = "",
) -> np.ndarray:
    """`change` (H, W, C) resampled on the contact-radius grid around `center_px` (x, y): (n, n, C)
    float32, NaN where the grid leaves the frame. Raises ConfigError for an empty contact (radius
    not a positive finite number) or a centre that is not finite."""
    where = name or "contact"
    r = float(radius_px)
    if not (math.isfinite(r) and r > 0):
        raise ConfigError(f"{where}: contact radius must be a positive number of pixels, got {r!r}")
    cx, cy = (float(c) for c in center_px)
    if not (math.isfinite(cx) and math.isfinite(cy)):
        raise ConfigError(f"{where}: contact centre must be finite, got {tuple(center_px)!r}")
    img = np.asarray(change, dtype=np.float32)
    if img.ndim == 2:
        img = img[..., None]
    h, w = img.shape[:2]
    sigma = 0.5 * step * r  # half a grid step: no aliasing of the noise into the mean
    if sigma >= 0.3:
        img = cv2.GaussianBlur(img, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
        if img.ndim == 2:
            img = img[..., None]
    u, v = radius_grid(reach, step)
    mx = (cx + u * r).astype(np.float32)
    my = (cy + v * r).astype(np.float32)
    out = np.stack(
        [
            cv2.remap(
                np.ascontiguousarray(img[..., c]),
                mx,
                my,
                cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_REPLICATE,
            )
            for c in range(img.shape[2])
        ],
        axis=-1,
    )
    inside = (mx >= 0) & (mx <= w - 1) & (my >= 0) & (my <= h - 1)
    out[~inside] = np.nan
    return out


def mean_image(cutouts: Sequence[np.ndarray], min_coverage: float = MIN_COVERAGE) -> np.ndarray:
    """The mean of cut-outs (n, n, C) over presses, NaN where fewer than `min_coverage` of them see
    a grid point. Raises ConfigError with no cut-outs."""
    if len(cutouts) == 0:
        raise ConfigError("no presses to average (every contact was empty or off the frame)")
    stack = np.stack([np.asarray(c, dtype=np.float64) for c in cutouts])
    seen = np.isfinite(stack)
    count = seen.sum(axis=0)
    total = np.where(seen, stack, 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
    return np.where(count >= min_coverage * len(cutouts), mean, np.nan)


def annulus(shape: tuple[int, int], reach: float = REACH, inner: float = 1.0) -> np.ndarray:
    """True on the halo: inner < rho <= reach on a grid of `shape` (square, odd) spanning ±reach."""
    n = shape[0]
    if shape[0] != shape[1] or n % 2 == 0:
        raise ConfigError(f"a halo grid is square with an odd side, got {shape}")
    step = reach / ((n - 1) // 2) if n > 1 else 1.0
    u, v = radius_grid(reach, step)
    rho = np.hypot(u, v)
    return (rho > inner) & (rho <= reach + 1e-9)


def nrms(image: np.ndarray, reference: np.ndarray, reach: float = REACH) -> float:
    """RMS of (image − reference) over the halo and channels, over the RMS of the reference there
    (grid points finite in both). NaN when the reference is zero there or nothing is finite."""
    ring = annulus(reference.shape[:2], reach)
    a, b = image[ring], reference[ring]
    ok = np.isfinite(a) & np.isfinite(b)
    if not ok.any():
        return math.nan
    scale = float(np.sqrt(np.mean(b[ok] ** 2)))
    if scale == 0:
        return math.nan
    return float(np.sqrt(np.mean((a[ok] - b[ok]) ** 2))) / scale


def first_moments(image: np.ndarray, reach: float = REACH) -> tuple[float, float]:
    """(up, right): the halo magnitude's first angular Fourier moments (module docstring); NaN when
    the halo is zero or off the frame."""
    n = image.shape[0]
    ring = annulus(image.shape[:2], reach)
    step = reach / ((n - 1) // 2) if n > 1 else 1.0
    u, v = radius_grid(reach, step)
    rho = np.hypot(u, v)
    mag = np.abs(np.asarray(image, dtype=np.float64)).sum(axis=-1) if image.ndim == 3 else image
    keep = ring & np.isfinite(mag)
    total = float(mag[keep].sum())
    if not keep.any() or total == 0:
        return math.nan, math.nan
    up = float((mag[keep] * (-v[keep] / rho[keep])).sum()) / total
    right = float((mag[keep] * (u[keep] / rho[keep])).sum()) / total
    return up, right


def third_moment(image: np.ndarray, reach: float = REACH) -> float:
    """halo_m3_up (module docstring); NaN when the halo is zero or off the frame."""
    n = image.shape[0]
    ring = annulus(image.shape[:2], reach)
    step = reach / ((n - 1) // 2) if n > 1 else 1.0
    u, v = radius_grid(reach, step)
    mag = np.abs(np.asarray(image, dtype=np.float64)).sum(axis=-1) if image.ndim == 3 else image
    keep = ring & np.isfinite(mag)
    total = float(mag[keep].sum())
    if not keep.any() or total == 0:
        return math.nan
    alpha = np.arctan2(-v[keep], u[keep])
    return float((mag[keep] * np.cos(3 * (alpha - np.pi / 2))).sum()) / total


def figures(image: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """Each figure of `image` and its distance from `reference` (both mean cut-outs): the moments
    and their absolute differences; halo_nrms is a distance only."""
    up, right = first_moments(image)
    ref_up, ref_right = first_moments(reference)
    m3, ref_m3 = third_moment(image), third_moment(reference)
    return {
        "halo_nrms": math.nan,
        "halo_m1_up": up,
        "halo_m1_right": right,
        "d_halo_nrms": nrms(image, reference),
        "d_halo_m1_up": abs(up - ref_up),
        "d_halo_m1_right": abs(right - ref_right),
        "halo_m3_up": m3,
        "d_halo_m3_up": abs(m3 - ref_m3),
    }


def tolerance(reference_distances: Sequence[float], level: float = LEVEL) -> float:
    """The upper end of the reference distance's bootstrap interval (`level`, two-sided): how far
    one real half may sit from the other. NaN when no draw gave a finite distance."""
    d = np.asarray(reference_distances, dtype=float)
    d = d[np.isfinite(d)]
    if not d.size:
        return math.nan
    return float(np.percentile(d, 100 * (1 - (1 - level) / 2)))


def passes(sim_distance: float, tol: float) -> bool:
    """The simulator's distance (point estimate) within the tolerance; never passes on NaN."""
    return bool(math.isfinite(sim_distance) and math.isfinite(tol) and sim_distance <= tol)


def _interval(values, level: float = LEVEL) -> tuple[float, float]:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if not v.size:
        return math.nan, math.nan
    tail = 100 * (1 - level) / 2
    return float(np.percentile(v, tail)), float(np.percentile(v, 100 - tail))


@dataclass
class HaloComparison:
    """The mean halo images and each figure with its interval, tolerance and verdict."""

    real: np.ndarray  # the held-out real mean cut-out (n, n, C)
    sim: np.ndarray  # the simulator's, the same presses
    other: np.ndarray  # the other real half's (the reference)
    rows: list[dict] = field(default_factory=list)
    n_presses: tuple[int, int] = (0, 0)  # held-out, other
    n_images: tuple[int, int] = (0, 0)

    @property
    def ok(self) -> bool:
        return all(r["ok"] for r in self.rows)


def compare_halos(
    real: Sequence[np.ndarray],
    sim: Sequence[np.ndarray],
    other: Sequence[np.ndarray],
    groups: Sequence[Sequence[int]],
    other_groups: Sequence[Sequence[int]],
    *,
    draws: int = BOOTSTRAP,
    seed: int = 0,
    level: float = LEVEL,
) -> HaloComparison:
    """The 2-D figures of `sim` cut-outs against the `real` ones of the same presses (index for
    index), with the `other` real half as the reference; `groups` / `other_groups`: indices of the
    cut-outs of each press (resampled together). Raises ConfigError when the inputs disagree."""
    if len(real) != len(sim):
        raise ConfigError(f"{len(real)} real cut-outs but {len(sim)} simulated: one per press each")
    for name, cuts, grp in (("held-out", real, groups), ("other", other, other_groups)):
        flat = sorted(i for g in grp for i in g)
        if flat != list(range(len(cuts))) or any(len(g) == 0 for g in grp):
            raise ConfigError(
                f"{name} half: the press groups must cover each of its {len(cuts)} cut-outs once"
            )
    real_s, sim_s, other_s = (np.stack(c).astype(np.float64) for c in (real, sim, other))

    def stats(idx, other_idx):
        r = mean_image(list(real_s[idx]))
        s = mean_image(list(sim_s[idx]))
        o = mean_image(list(other_s[other_idx]))
        return figures(r, r), figures(s, r), figures(o, r)

    all_idx = np.arange(len(real_s))
    all_other = np.arange(len(other_s))
    point = stats(all_idx, all_other)
    rng = np.random.default_rng(int(seed))
    boot = []
    for _ in range(int(draws)):
        pick = rng.integers(len(groups), size=len(groups))
        pick_o = rng.integers(len(other_groups), size=len(other_groups))
        idx = np.concatenate([groups[k] for k in pick]).astype(int)
        idx_o = np.concatenate([other_groups[k] for k in pick_o]).astype(int)
        boot.append(stats(idx, idx_o))
    rows = []
    for fig in FIGURES:
        entry = {"figure": fig}
        for j, who in enumerate(("real", "sim", "other")):
            entry[who] = point[j][fig]
            entry[f"{who}_lo"], entry[f"{who}_hi"] = _interval([b[j][fig] for b in boot], level)
        for j, who in ((1, "sim_distance"), (2, "real_distance")):
            entry[who] = point[j][f"d_{fig}"]
            entry[f"{who}_lo"], entry[f"{who}_hi"] = _interval(
                [b[j][f"d_{fig}"] for b in boot], level
            )
        entry["tolerance"] = tolerance([b[2][f"d_{fig}"] for b in boot], level)
        entry["ok"] = passes(entry["sim_distance"], entry["tolerance"])
        rows.append(entry)
    return HaloComparison(
        point_mean(real_s),
        point_mean(sim_s),
        point_mean(other_s),
        rows,
        (len(groups), len(other_groups)),
        (len(real_s), len(other_s)),
    )


def point_mean(stack: np.ndarray) -> np.ndarray:
    return mean_image(list(stack))


# ------------------------------------------------------------------------- a real folder
def folder_halos(
    data,
    test_labels: Sequence,
    other_labels: Sequence,
    renders: tuple[np.ndarray, list[np.ndarray]],
    *,
    seed: int = 0,
    draws: int = BOOTSTRAP,
) -> HaloComparison:
    """The 2-D comparison on a real ball folder (`realism.BallDataset`): `renders` (the simulator's
    blank and its render of each of `test_labels`, `realism.render_presses`) against the real frames
    of `test_labels`, the real frames of `other_labels` as the reference. Each press is cut out
    around its label (centre and radius) in real and render alike; presses are grouped by place
    (`realism.image_groups`) for the bootstrap."""
    sim_bg, frames = renders
    if len(frames) != len(test_labels):
        raise ConfigError(f"{len(frames)} renders for {len(test_labels)} held-out presses")
    real_bg = data.read("background.png")

    def cut(img, bg, label, what):
        return cutout(
            contact_change(img, bg),
            label.center_px,
            label.radius_px,
            name=f"{data.root}/{label.image} ({what})",
        )

    real = [cut(data.read(lb.image), real_bg, lb, "real") for lb in test_labels]
    sim = [cut(f, sim_bg, lb, "render") for f, lb in zip(frames, test_labels, strict=True)]
    other = [cut(data.read(lb.image), real_bg, lb, "real") for lb in other_labels]
    return compare_halos(
        real,
        sim,
        other,
        image_groups(test_labels),
        image_groups(other_labels),
        draws=draws,
        seed=seed,
    )


def format_halos(result: HaloComparison) -> str:
    """The 2-D figures as table lines (one per figure, then the verdict)."""
    n, n_o = result.n_presses
    m, m_o = result.n_images
    lines = [
        f"halo 2-D: mean contact-centred change (1-{REACH:g} contact radii) of {m} held-out real "
        f"images ({n} presses) against their renders; reference: the other {m_o} real images "
        f"({n_o} presses); [95 % bootstrap by press]; tolerance: the reference distance's upper end",
        f"{'figure':14s} {'real':>22s} {'sim':>22s} {'sim-real':>22s} {'real-real':>22s} "
        f"{'tol':>6s}  verdict",
    ]

    def fmt(r, key):
        if not math.isfinite(r[key]):
            return f"{'-':>22s}"
        return f"{r[key]:7.3f} [{r[key + '_lo']:6.3f},{r[key + '_hi']:6.3f}]"

    for r in result.rows:
        lines.append(
            f"{r['figure']:14s} {fmt(r, 'real')} {fmt(r, 'sim')} {fmt(r, 'sim_distance')} "
            f"{fmt(r, 'real_distance')} {r['tolerance']:6.3f}  "
            f"{'ok' if r['ok'] else 'OUT OF RANGE'}"
        )
    bad = [r["figure"] for r in result.rows if not r["ok"]]
    lines.append(
        f"halo 2-D: FAIL, further from the held-out real mean than the other real half: "
        f"{', '.join(bad)}"
        if bad
        else "halo 2-D: ok, as close to the held-out real mean as the other real half"
    )
    return "\n".join(lines)


CSV_COLUMNS = (
    "real_folder",
    "sensor",
    "figure",
    *(f"{w}{s}" for w in ("real", "sim", "other") for s in ("", "_lo", "_hi")),
    *(f"{w}{s}" for w in ("sim_distance", "real_distance") for s in ("", "_lo", "_hi")),
    "tolerance",
    "ok",
    "presses",
    "other_presses",
    "images",
    "other_images",
)


def write_csv(results: Sequence[tuple[str, str, HaloComparison]], path) -> None:
    """One row per (folder, sensor, figure): CSV_COLUMNS; a folder without a 2-D comparison (None)
    has no rows."""
    with open(path, "w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(CSV_COLUMNS)
        for folder, sensor, res in results:
            for r in res.rows if res is not None else []:
                out.writerow(
                    [
                        folder,
                        sensor,
                        r["figure"],
                        *(_num(r[c]) for c in CSV_COLUMNS[3:-5]),
                        r["ok"],
                        *res.n_presses,
                        *res.n_images,
                    ]
                )


def _num(x: float) -> str:
    return "" if not math.isfinite(x) else f"{x:.6g}"


def draw(results: Sequence[tuple[str, str, HaloComparison]], path) -> None:
    """Per folder a row: the held-out real mean, the simulated mean, simulated − real and the other
    real half, each as 128 + gain x change (RGB; the gain maps the real mean's 99th percentile of
    |change| on the halo to 100 DN: the contact saturates), the contact (1 radius) and the halo's
    edge (REACH) drawn."""
    plt = pyplot()
    n = max(len(results), 1)
    fig, axes = plt.subplots(n, 4, figsize=(10, 2.8 * n), squeeze=False)
    t = np.linspace(0, 2 * np.pi, 200)
    for row, (folder, sensor, res) in zip(axes, results, strict=False):
        ring = annulus(res.real.shape[:2])
        scale = float(np.nanpercentile(np.abs(res.real[ring]), 99)) or 1.0
        gain = 100.0 / scale
        panels = [
            ("real (held out)", res.real),
            ("simulated", res.sim),
            ("simulated - real", res.sim - res.real),
            ("real (other half)", res.other),
        ]
        nrms_row = next(r for r in res.rows if r["figure"] == "halo_nrms")
        up_row = next(r for r in res.rows if r["figure"] == "halo_m1_up")
        m3_row = next(r for r in res.rows if r["figure"] == "halo_m3_up")
        for ax, (title, img) in zip(row, panels, strict=True):
            rgb = np.clip(128 + gain * np.nan_to_num(img, nan=0.0), 0, 255).astype(np.uint8)
            ax.imshow(rgb, extent=(-REACH, REACH, REACH, -REACH))
            for rad in (1.0, REACH):
                ax.plot(rad * np.cos(t), rad * np.sin(t), "w-", lw=0.6)
            ax.set_title(title, fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
        row[0].set_ylabel(f"{sensor}\n{folder}", fontsize=7)
        row[2].set_xlabel(
            f"nrms {nrms_row['sim_distance']:.2f} (tol {nrms_row['tolerance']:.2f}); "
            f"m1_up real {up_row['real']:.2f} sim {up_row['sim']:.2f}; "
            f"m3_up real {m3_row['real']:.2f} sim {m3_row['sim']:.2f}",
            fontsize=7,
        )
    fig.suptitle(
        "contact-centred mean change, in contact radii (x 100 DN / real halo p99)", fontsize=9
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
