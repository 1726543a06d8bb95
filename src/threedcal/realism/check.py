"""Is the simulator realistic? The same image statistics on real ball frames and on renders of the
same ball at the same scale and placement, side by side, with a stated tolerance per figure.

Figures (per image; the real *range* is min..max over the real images — for the four background
figures the real background frame, under each image's mask, counts as a real image too, since the
contact frames were lit a little differently from it — and the simulated figure is the median over
the renders):

- ``bg_lowfreq_std``: spatial std (DN, mean over channels) of the frame blurred with sigma 10 px,
  outside 1.5 ball radii of the contact: how non-uniform the illumination field is.
- ``corner_centre_min`` / ``corner_centre_max``: luminance of the four 24 px corner patches over the
  centre patch (pixels near the contact left out): vignetting against LED fall-off.
- ``hf_noise_std``: std (DN, mean over channels) of the frame minus its sigma-1 px blur, outside the
  contact: sensor noise plus fine texture.
- ``dI_p1_<c>`` / ``dI_p99_<c>``: 1st / 99th percentile of (frame - background) per channel inside the
  evaluation disc 0.9 x min(label radius, 0.98 ball radius), less the frame's lighting drift (its
  per-channel median change over the whole frame, as for the halo; the optics fit takes the
  median outside 2 ball radii, within 1 DN of this on the real Mini frames): the contact's contrast.
- ``r2_<c>``: R² of the per-channel linear fit of ΔI on the true sphere normals (nx, ny, nz, 1) inside
  the same disc: how photometric-stereo-like the shading is (1 = perfectly Lambertian and noiseless).

Tolerances (how far the simulated figure may sit outside the real range) and why:

- DN-valued background figures: 2 DN for the low-frequency std (the real frames drift by several DN
  between the background shot and the contact shots — the outside-contact mean difference is up to
  ±9 DN — so 2 DN is well inside the real frame-to-frame variation), 0.25 DN for the noise std
  (a quarter of the ~1 DN noise, the quantisation step's own std is 0.29 DN).
- Corner/centre ratios: 0.05 (5 % of the luminance, the spread between the four real corners of one
  frame is larger).
- ΔI percentiles: 8 DN. The labels are hand-drawn circles (the dataset notes they include part of the
  halo), and a 2 px error in a ~38 px radius moves the disc's 1st/99th percentiles by several DN; no
  depth was recorded, so the simulated depth comes from the label radius with the same uncertainty.
- R²: 0.05, about the spread of R² between real images of neighbouring placements.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from threedcal.dataset.folds import linked_groups
from threedcal.errors import ConfigError
from threedcal.images import read_rgb
from threedcal.orientation import TURN_KEY, folder_turn, turn_image, turn_points
from threedcal.schema import load_yaml
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator

CHANNELS = "RGB"
TOLERANCE = {
    "bg_lowfreq_std": 2.0,
    "corner_centre_min": 0.05,
    "corner_centre_max": 0.05,
    "hf_noise_std": 0.25,
    **{f"dI_p1_{c}": 8.0 for c in CHANNELS},
    **{f"dI_p99_{c}": 8.0 for c in CHANNELS},
    **{f"r2_{c}": 0.05 for c in CHANNELS},
    "noise_acf1": 0.05,
    "halo_r50_px": 3.0,
    "halo_width_px": 3.0,
}
FIGURES = list(TOLERANCE)
BACKGROUND = (
    "bg_lowfreq_std",
    "corner_centre_min",
    "corner_centre_max",
    "hf_noise_std",
    "noise_acf1",
)
# figures that need a known contact (true sphere normals, a radius not measured from the image)
LABELLED_ONLY = (*(f"r2_{c}" for c in CHANNELS), "halo_r50_px")
PATCH = 24
HALO_MAX_RADII = 3.0  # the halo's radial profile is followed out to 3 ball radii


@dataclass(frozen=True)
class BallLabel:
    image: str
    center_px: tuple[float, float]
    radius_px: float
    located: bool = False  # True: found in frame minus background (locate_ball), not labelled


@dataclass(frozen=True)
class BallDataset:
    """A real ball-image folder: images, background.png, dataset.yaml and labels.csv, or, without
    labels.csv, every other PNG with its contact located from the frame minus the background."""

    root: Path
    px_per_mm: float
    ball_radius_mm: float
    width_px: int
    height_px: int
    labels: list[BallLabel]
    labelled: bool = True
    turn: str | None = None  # stored on its side: every image and label read turned this way

    @property
    def turned(self) -> bool:
        return self.turn is not None

    def read(self, name: str) -> np.ndarray:
        image = read_rgb(self.root / name)
        return turn_image(image, turn=self.turn) if self.turn else image


def load_ball_dataset(root: str | Path, orientation: str | None = None) -> BallDataset:
    """The folder as `orientation` ('portrait' or 'landscape': the sensor profile's frame) sees it:
    a folder stored on its side is read turned a quarter the way its dataset.yaml states
    (threedcal.orientation), labels too."""
    root = Path(root)
    meta_path = root / "dataset.yaml"
    if not meta_path.is_file():
        raise ConfigError(f"{root}: not a ball-image dataset (no dataset.yaml)")
    meta = load_yaml(meta_path) or {}
    for key in ("px_per_mm", "ball_radius_mm"):
        if not isinstance(meta.get(key), int | float) or meta[key] <= 0:
            raise ConfigError(f"{meta_path}: {key} must be a positive number")
    if not (root / "background.png").is_file():
        raise ConfigError(
            f"{root}: no background.png (the no-contact frame every contact is compared against)"
        )
    bg = read_rgb(root / "background.png")
    stored_height, stored_width = bg.shape[:2]
    turn = folder_turn(stored_height, stored_width, orientation, meta.get(TURN_KEY), str(meta_path))
    bg = turn_image(bg, turn=turn) if turn else bg
    scale, ball_mm = float(meta["px_per_mm"]), float(meta["ball_radius_mm"])
    label_path = root / "labels.csv"
    if not label_path.exists():
        names = sorted(p.name for p in root.glob("*.png") if p.name != "background.png")
        if not names:
            raise ConfigError(f"{root}: no contact images (*.png besides background.png)")
        data = BallDataset(root, scale, ball_mm, bg.shape[1], bg.shape[0], [], False, turn)
        located = [locate_ball(data.read(n), bg, ball_mm * scale, n) for n in names]
        return dataclasses.replace(data, labels=located)
    labels = []
    try:
        with label_path.open(newline="") as fh:
            for row_no, row in enumerate(csv.DictReader(fh), start=2):
                try:
                    labels.append(
                        BallLabel(
                            row["image"],
                            (float(row["center_x_px"]), float(row["center_y_px"])),
                            float(row["radius_px"]),
                        )
                    )
                except (KeyError, TypeError, ValueError) as exc:
                    raise ConfigError(
                        f"{label_path}: row {row_no}: need image,center_x_px,center_y_px,radius_px ({exc})"
                    ) from None
    except OSError as exc:
        raise ConfigError(f"{label_path}: cannot read ({exc.strerror})") from None
    if not labels:
        raise ConfigError(f"{label_path}: no labelled images")
    if turn:
        centres = turn_points(
            [label.center_px for label in labels], stored_width, stored_height, turn
        )
        labels = [
            dataclasses.replace(label, center_px=(float(x), float(y)))
            for label, (x, y) in zip(labels, centres, strict=True)
        ]
    return BallDataset(root, scale, ball_mm, bg.shape[1], bg.shape[0], labels, True, turn)


def image_figures(
    img: np.ndarray, background: np.ndarray, label: BallLabel, ball_radius_px: float
) -> dict[str, float]:
    """Every figure of one contact image against its background."""
    img = img.astype(np.float32)
    bg = background.astype(np.float32)
    h, w = img.shape[:2]
    yy, xx = np.mgrid[:h, :w]
    cx, cy = label.center_px
    r2 = (xx - cx) ** 2 + (yy - cy) ** 2
    far = r2 > (1.5 * ball_radius_px) ** 2
    out: dict[str, float] = {}
    low = cv2.GaussianBlur(img, (0, 0), 10)
    out["bg_lowfreq_std"] = float(np.mean(low[far].std(axis=0)))
    lum = img @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    centre = _patch_mean(lum, far, h // 2 - PATCH // 2, w // 2 - PATCH // 2)
    corners = [_patch_mean(lum, far, y, x) for y in (0, h - PATCH) for x in (0, w - PATCH)]
    ratios = [c / centre for c in corners if not math.isnan(c)] if not math.isnan(centre) else []
    out["corner_centre_min"] = min(ratios) if ratios else math.nan
    out["corner_centre_max"] = max(ratios) if ratios else math.nan
    std, out["noise_acf1"] = noise_figures(img, far)
    out["hf_noise_std"] = float(np.mean(std))
    r50, r10 = halo_radii(img, bg, label.center_px, ball_radius_px)
    out["halo_r50_px"] = r50
    out["halo_width_px"] = r10 - r50
    rad = 0.9 * min(label.radius_px, 0.98 * ball_radius_px)
    disc = r2 < rad**2
    d_i = contact_change(img, bg)[disc]  # the contact's contrast, not the lighting's drift
    nx = (xx[disc] - cx) / ball_radius_px
    ny = (yy[disc] - cy) / ball_radius_px
    nz = np.sqrt(np.clip(1 - nx**2 - ny**2, 0, 1))
    design = np.stack([nx, ny, nz, np.ones_like(nx)], axis=1)
    for c, name in enumerate(CHANNELS):
        y = d_i[:, c]
        out[f"dI_p1_{name}"] = float(np.percentile(y, 1))
        out[f"dI_p99_{name}"] = float(np.percentile(y, 99))
        coef, *_ = np.linalg.lstsq(design, y, rcond=None)
        resid = y - design @ coef
        out[f"r2_{name}"] = float(1 - resid.var() / y.var()) if y.var() > 0 else math.nan
    if label.located:  # no true normals, and the radius was measured where r50 is
        for fig in LABELLED_ONLY:
            out[fig] = math.nan
    return out


def noise_figures(img: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, float]:
    """Per-channel std (DN) of the frame minus its sigma-1 px blur where `keep`, and the residual's
    correlation between horizontal and vertical neighbours (both kept): 0 for white noise filtered
    so, larger where the camera spreads noise over neighbours (a one-number noise spectrum)."""
    img = img.astype(np.float32)
    hf = img - cv2.GaussianBlur(img, (0, 0), 1.0)
    std = hf[keep].std(axis=0)
    corr = []
    for a, b, both in (
        (hf[:, 1:], hf[:, :-1], keep[:, 1:] & keep[:, :-1]),
        (hf[1:], hf[:-1], keep[1:] & keep[:-1]),
    ):
        x, y = a[both], b[both]
        x = x - x.mean(axis=0)
        y = y - y.mean(axis=0)
        corr.append((x * y).mean(axis=0) / np.maximum(x.std(axis=0) * y.std(axis=0), 1e-12))
    return std, float(np.mean(corr))


def contact_change(img: np.ndarray, background: np.ndarray) -> np.ndarray:
    """frame - background (DN, float32) less the frame's lighting drift: its per-channel median
    change, the contact being small. Real frames drift by several DN from their background shot
    (blue +8 DN over the FOTS GelSight frames), the simulator's by its own draws."""
    diff = img.astype(np.float32) - background.astype(np.float32)
    return diff - np.median(diff.reshape(-1, diff.shape[-1]), axis=0)


def contact_magnitude(img: np.ndarray, background: np.ndarray) -> np.ndarray:
    """|contact_change| summed over channels (DN), smoothed by sigma 2 px."""
    return cv2.GaussianBlur(np.abs(contact_change(img, background)).sum(axis=2), (0, 0), 2.0)


def halo_radii(img, background, center_px, ball_radius_px: float) -> tuple[float, float]:
    """(r50, r10) px: where the radially averaged contact magnitude, past its peak, first falls
    below 50 % and 10 % of the peak. r10 - r50 is the width of the shading halo around the contact.
    NaN when the profile does not fall that far within HALO_MAX_RADII ball radii."""
    m = contact_magnitude(img, background)
    h, w = m.shape
    yy, xx = np.mgrid[:h, :w]
    r = np.hypot(xx - center_px[0], yy - center_px[1])
    n_bins = int(HALO_MAX_RADII * ball_radius_px) + 1
    idx = np.minimum(r.astype(np.int64), n_bins)
    sums = np.bincount(idx.ravel(), weights=m.ravel(), minlength=n_bins + 1)[:n_bins]
    counts = np.bincount(idx.ravel(), minlength=n_bins + 1)[:n_bins]
    with np.errstate(invalid="ignore", divide="ignore"):
        prof = sums / counts
    prof = np.where(counts > 0, prof, np.nan)
    peak = int(np.nanargmax(prof))
    top = prof[peak]
    out = []
    for level in (0.5, 0.1):
        below = np.nonzero(prof[peak:] < level * top)[0]
        if not below.size:
            out.append(math.nan)
            continue
        k = peak + int(below[0])  # crossing between bins k - 1 and k (centred at k + 0.5)
        y0, y1 = prof[k - 1], prof[k]
        out.append(float(k - 0.5 + (y0 - level * top) / (y0 - y1)) if y0 != y1 else k + 0.5)
    return out[0], out[1]


def locate_ball(img, background, ball_radius_px: float, name: str = "") -> BallLabel:
    """A ball's label found in an unlabelled real frame: the largest region where the contact
    magnitude exceeds half its 99.9th percentile, holes filled; centre its centroid, radius that of
    the disc of its area. Raises ConfigError when the frame shows no contact above the noise.

    Not the registration's locator (threedcal.dataset.contacts): this one works on the change less
    the frame's lighting drift (real frames drift from their background shot) and is what the
    realism table and the optics fit were measured with; the registration's refines the rim."""
    m = contact_magnitude(img, background)
    peak = float(np.percentile(m, 99.9))
    floor = float(np.median(m))
    if peak < 4 * max(floor, 1.0):
        raise ConfigError(
            f"{name or 'frame'}: no contact found (frame minus background peaks at {peak:.1f} DN "
            f"against a typical {floor:.1f} DN)"
        )
    mask = (m > 0.5 * peak).astype(np.uint8)
    n, comp, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    best = max(range(1, n), key=lambda k: float(m[comp == k].sum()))
    region = (comp == best).astype(np.uint8)
    contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    filled = np.zeros_like(region)
    cv2.drawContours(filled, contours, -1, 1, thickness=-1)
    ys, xs = np.nonzero(filled)
    radius = math.sqrt(xs.size / math.pi)
    return BallLabel(
        name, (float(xs.mean()), float(ys.mean())), min(radius, ball_radius_px), located=True
    )


def _patch_mean(lum: np.ndarray, keep: np.ndarray, y: int, x: int) -> float:
    sel = keep[y : y + PATCH, x : x + PATCH]
    if sel.mean() < 0.5:  # the contact covers this patch
        return math.nan
    return float(lum[y : y + PATCH, x : x + PATCH][sel].mean())


def simulated_depth_mm(label: BallLabel, data: BallDataset, radii=None) -> float:
    """The depth whose contact radius equals the label's (capped at 0.98 R): a = sqrt(2Rd - d^2) for
    the geometric gel; for an elastic gel `radii` = (depths, contact radii) of its own, smaller
    contacts (elastic_contact_radii)."""
    R = data.ball_radius_mm
    a = min(label.radius_px / data.px_per_mm, 0.98 * R)
    if radii is None:
        return R - math.sqrt(R * R - a * a)
    return float(np.interp(a, radii[1], radii[0]))


def elastic_contact_radii(sim, radius_mm: float, center_px, depths=None):
    """(depths, contact radii) mm of a ball of `radius_mm` pressed at `center_px` into an elastic gel:
    the radius of the disc with the contact's area, on the simulator's own lattice."""
    ball = Sphere(radius_mm)
    if depths is None:
        depths = np.linspace(0.05, min(0.9 * radius_mm, sim.max_penetration_mm), 24)
    radii = []
    for d in depths:
        press = sim.press(ball, center_px, 0.0, float(d))
        area = (
            0.0 if press is None else float(press.result.contact.sum()) * sim._elastic.spacing_mm**2
        )
        radii.append(math.sqrt(area / math.pi))
    return np.asarray(depths, dtype=float), np.maximum.accumulate(np.asarray(radii))


def render_presses(
    data: BallDataset, profile: Mapping[str, Any], seed: int, labels: list[BallLabel]
) -> tuple[np.ndarray, list[np.ndarray]]:
    """The simulator's blank frame and its render of each press of `labels` (frame_index i + 1): the
    ball at the label's centre, pressed until its contact has the label's radius
    (`simulated_depth_mm`; an elastic gel's own contact radii)."""
    sim = GelSimulator(
        profile, seed, image_size=(data.width_px, data.height_px), px_per_mm=data.px_per_mm
    )
    ball = Sphere(data.ball_radius_mm)
    frames = []
    table = None
    for i, label in enumerate(labels):
        radii = None
        if sim.mechanics == "elastic":  # a flat gel contacts alike everywhere: one table
            if table is None or sim.domed:
                table = elastic_contact_radii(sim, data.ball_radius_mm, label.center_px)
            radii = table
        frames.append(
            sim.render(
                ball,
                label.center_px,
                0.0,
                simulated_depth_mm(label, data, radii),
                frame_index=i + 1,
            )
        )
    return sim.blank(frame_index=0), frames


def compare(
    data: BallDataset,
    profile: Mapping[str, Any],
    seed: int = 0,
    labels: list[BallLabel] | None = None,
    *,
    background_is_real: bool = True,
    renders: tuple[np.ndarray, list[np.ndarray]] | None = None,
) -> list[dict[str, Any]]:
    """One row per figure: real min/max, simulated median, tolerance, pass — over `labels` (default
    every image). `background_is_real`: the background frame's own figures join the real range
    (not when the optics were fitted to it). Located (unlabelled) contacts are located in the
    renders too, and the figures that need a known contact are left out (NaN, never failing).
    `renders`: `render_presses(data, profile, seed, labels)` when already made."""
    labels = data.labels if labels is None else labels
    ball_px = data.ball_radius_mm * data.px_per_mm
    real_bg = data.read("background.png")
    sim_bg, frames = renders if renders is not None else render_presses(data, profile, seed, labels)
    if len(frames) != len(labels):
        raise ConfigError(f"{len(frames)} renders for {len(labels)} presses")
    real, simulated = [], []
    for label, frame in zip(labels, frames, strict=True):
        real.append(image_figures(data.read(label.image), real_bg, label, ball_px))
        if background_is_real:
            # the real background frame is a real frame too: its figures (same mask) join the range
            real.append(
                {
                    k: v
                    for k, v in image_figures(real_bg, real_bg, label, ball_px).items()
                    if k in BACKGROUND
                }
            )
        seen = label
        if label.located:  # find the rendered contact the way the real one was found
            seen = locate_ball(frame, sim_bg, ball_px, f"render of {label.image}")
        simulated.append(image_figures(frame, sim_bg, seen, ball_px))
    rows = []
    for fig in FIGURES:
        if not data.labelled and fig in LABELLED_ONLY:
            continue
        r = np.array([f[fig] for f in real if fig in f], dtype=float)
        s = float(np.median([f[fig] for f in simulated if not math.isnan(f[fig])] or [math.nan]))
        r = r[~np.isnan(r)]
        lo, hi = (float(r.min()), float(r.max())) if r.size else (math.nan, math.nan)
        tol = TOLERANCE[fig]
        rows.append(
            {
                "figure": fig,
                "real_min": lo,
                "real_max": hi,
                "sim": s,
                "tolerance": tol,
                "ok": bool(lo - tol <= s <= hi + tol),
            }
        )
    return rows


def format_table(rows: list[dict[str, Any]]) -> str:
    lines = [
        f"{'figure':20s} {'real min':>9s} {'real max':>9s} {'sim':>9s} {'tol':>6s}  verdict",
    ]
    for r in rows:
        lines.append(
            f"{r['figure']:20s} {r['real_min']:9.3f} {r['real_max']:9.3f} {r['sim']:9.3f} "
            f"{r['tolerance']:6.2f}  {'ok' if r['ok'] else 'OUT OF RANGE'}"
        )
    return "\n".join(lines)


def image_groups(labels: Sequence, group_px: float = 4.0) -> list[list[int]]:
    """Indices of images grouped by press: images whose contact centres lie within `group_px` of
    each other (the same place pressed again, or the same frame twice) share a group (transitively,
    threedcal.dataset.folds.linked_groups), groups in the order of their first image."""
    if not len(labels):
        return []
    centres = np.array([label.center_px for label in labels], dtype=float)
    offsets = centres[:, None, :] - centres[None, :, :]
    group = linked_groups(np.hypot(offsets[..., 0], offsets[..., 1]) <= group_px)
    return [np.flatnonzero(group == g).tolist() for g in range(int(group.max()) + 1)]
