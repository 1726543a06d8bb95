"""Fit a sensor profile's photometric constants to real frames, reproducibly, on a chosen subset.

What is fitted (everything else in the profile is kept):

- LED azimuths: per colour channel, the direction in which the contacts' change grows with the
  sphere's normal (least squares on nx, ny, nz inside each contact), for the light of that colour.
- LED distances and the vignetting: least squares on the background field, the per-pixel median of
  background.png and the fitting frames away from their contacts (the halo reaches far: outside 3
  ball radii), blurred (sigma 4 px) and sampled every 4th pixel; for each trial the levels below
  are solved linearly, so only four numbers are searched (`scipy.optimize.least_squares`). With the
  smooth field below they are weakly determined and stay near the profile's.
- Levels: per colour channel the ambient, each light's directional level (gain x colour:
  `gain_dn` is its largest channel, `color_rgb` the rest over it), the hot spots' amplitudes
  (shapes kept) and a smooth colour field (`optics.background_field`, a degree-4 polynomial: the
  housing, gel edges and paint that no LED explains). All are linear in the image, so one bounded
  least-squares fit per channel covers the background field *and* the contacts' change (frame
  minus background.png, minus the frame's lighting drift = its per-channel median away from the
  contact; clipped pixels left out): the background alone cannot tell directional light from the
  rest. LED scatter is set to 0: on a background it is the same as the ambient and the field, and
  what tells it apart (its change with the gel's height under a press, a few DN) is too weak to fit.
- Shading shape: the LEDs' elevation, the response's quadratic term and the camera blur, from a
  small grid, by the contacts' residual (each grid point renders every fitting contact once,
  through the simulator's own shading, each light into its own channel).
- Noise: the per-pixel std (`noise_dn`) and its spatial correlation (`noise_correlation_px`) so
  that blank renders have the fitting frames' fine residual (frame minus its sigma-1 blur) and its
  neighbour correlation, both away from the contact (bisection on the correlation).

Not fitted (kept from the profile): wrap, cast shadows, paint texture, the gel's shape and
mechanics, per-frame flicker (one frame per press here: no repeated frames of a hold to see it).

A contact's place and size come from the dataset's labels, or, in an unlabelled folder, from the
frame minus the background (`realism.locate_ball`); the ball's depth is then the one whose
geometric contact radius is that radius.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml
from scipy.linalg import qr
from scipy.optimize import least_squares, lsq_linear

from threedcal.errors import ConfigError
from threedcal.realism.check import HALO_MAX_RADII, noise_figures, simulated_depth_mm
from threedcal.sim.background_field import field_terms
from threedcal.sim.indenters import Sphere
from threedcal.sim.optics import GelSimulator

FIELD_BLUR_PX = 4.0  # the background field is fitted at low frequency ...
FIELD_STRIDE = 4  # ... on every 4th pixel
CONTACT_STRIDE = 2  # contact pixels used, every 2nd
CONTACT_REACH = 1.6  # contact rows: within this many ball radii of the centre
ELEVATIONS_DEG = (10.0, 16.0, 22.0, 30.0)
NONLINEARITIES = (0.4, 0.8)
BLURS_PX = (1.0, 2.5, 4.0, 6.0)
NOISE_CORRELATION_RANGE_PX = (0.0, 2.0)
BISECTIONS = 7
FIELD_DEGREE = 4  # the background colour field's polynomial (15 terms per channel)


@dataclass
class OpticsFit:
    """The fitted profile and what the fit saw."""

    profile: dict[str, Any]
    images: list[str]
    field_rms_dn: float  # background-field residual (DN, all channels)
    contact_rms_dn: float  # contact-change residual (DN, all channels)
    real_noise: dict[str, Any] = field(default_factory=dict)

    def write_profile(self, path) -> None:
        """The whole fitted profile as YAML, headed by what it was fitted on."""

        head = self.summary().splitlines()[0]
        body = yaml.safe_dump(_plain(self.profile), sort_keys=False, width=100)
        Path(path).write_text(head + "\n" + body)

    def summary(self) -> str:
        """The fitted constants, as profile YAML lines with where they came from."""
        p = self.profile
        lines = [
            f"# fitted by threedcal.realism.fit.fit_optics on {len(self.images)} images "
            f"({', '.join(self.images)}) + background.png: background-field rms "
            f"{self.field_rms_dn:.2f} DN, contact-change rms {self.contact_rms_dn:.2f} DN",
            "lights:",
        ]
        for li in p["lights"]:
            lines.append(
                f"  - {{name: {li['name']}, color_rgb: {_r(li['color_rgb'], 3)}, "
                f"azimuth_deg: {li['azimuth_deg']:.1f}, elevation_deg: {li['elevation_deg']:g}, "
                f"distance_mm: {li['distance_mm']:.1f}, gain_dn: {li['gain_dn']:.1f}, "
                f"scatter_dn: {_r(li['scatter_dn'], 1)}}}"
            )
        o = p["optics"]
        lines += [
            "optics:",
            f"  ambient_dn: {_r(o['ambient_dn'], 1)}",
            f"  vignetting: {o['vignetting']:.3f}",
            f"  nonlinearity: {o['nonlinearity']:g}",
            f"  blur_sigma_px: {o['blur_sigma_px']:g}",
            f"  noise_dn: {_r(o['noise_dn'], 2)}",
            f"  noise_correlation_px: {o['noise_correlation_px']:g}",
        ]
        if o.get("background_field"):
            f = o["background_field"]
            lines.append(
                f"  background_field: degree {f['degree']}, "
                f"{sum(len(r) for r in f['coefficients_dn'])} coefficients (--write-fitted)"
            )
        if o.get("hot_spots"):
            lines.append("  hot_spots:")
            for h in o["hot_spots"]:
                lines.append(
                    f"    - {{x: {h['x']:g}, y: {h['y']:g}, sigma: {h['sigma']:g}, "
                    f"amplitude_dn: {_r(h['amplitude_dn'], 1)}}}"
                )
        return "\n".join(lines)


def _plain(value):
    """numpy scalars and tuples as plain YAML-able Python."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _r(values, nd: int) -> list[float]:
    return [round(float(v), nd) for v in values]


def fit_optics(
    profile: Mapping[str, Any],
    data,
    labels: Sequence,
    *,
    elevations_deg: Sequence[float] = ELEVATIONS_DEG,
    nonlinearities: Sequence[float] = NONLINEARITIES,
    blurs_px: Sequence[float] = BLURS_PX,
    noise_correlation_range_px: tuple[float, float] = NOISE_CORRELATION_RANGE_PX,
    field_degree: int = FIELD_DEGREE,
) -> OpticsFit:
    """Fit `profile`'s photometric constants (module docstring) to the images of `labels` (a subset
    of `data`, a `realism.BallDataset`) and data's background.png. Returns a fitted deep copy."""
    if not labels:
        raise ConfigError(f"{data.root}: no images to fit the optics to")
    fitted = copy.deepcopy(dict(profile))
    fitted["optics"] = dict(fitted["optics"])
    fitted["lights"] = [dict(li) for li in fitted["lights"]]
    bg = data.read("background.png").astype(np.float32)
    frames = [data.read(label.image).astype(np.float32) for label in labels]
    ball_px = data.ball_radius_mm * data.px_per_mm
    target = _field_target(bg, frames, labels, ball_px)
    for li, azimuth in zip(
        fitted["lights"], _light_azimuths(fitted, frames, bg, labels, ball_px), strict=True
    ):
        li["azimuth_deg"] = azimuth
    geo = _FieldModel(fitted, data, field_degree)
    x = geo.fit(target)
    geo.apply(x, fitted)
    contacts = [
        _real_change(f, bg, label, ball_px) for f, label in zip(frames, labels, strict=True)
    ]
    best = None
    for elevation in elevations_deg:
        for nonlinearity in nonlinearities:
            trial = copy.deepcopy(fitted)
            for li in trial["lights"]:
                li["elevation_deg"] = float(elevation)
            trial["optics"]["nonlinearity"] = float(nonlinearity)
            bases = _contact_bases(trial, data, labels)
            geo.lights = [
                dict(li) for li in trial["lights"]
            ]  # the background at this elevation too
            for blur in blurs_px:
                levels, field_rms, contact_rms = _solve_levels(
                    geo, target, contacts, bases, float(blur)
                )
                if best is None or contact_rms < best[0]:
                    best = (contact_rms, field_rms, trial, levels, float(blur))
    contact_rms, field_rms, fitted, levels, blur = best
    fitted["optics"]["blur_sigma_px"] = blur
    geo.apply_levels(levels, fitted)
    noise = _fit_noise(fitted, data, frames, labels, ball_px, noise_correlation_range_px)
    return OpticsFit(fitted, [label.image for label in labels], field_rms, contact_rms, noise)


# ------------------------------------------------------------------------- background field
def _field_target(bg, frames, labels, ball_px) -> np.ndarray:
    """Median of background.png and the frames outside their contacts, low-passed and sampled."""
    h, w = bg.shape[:2]
    yy, xx = np.mgrid[:h, :w]
    stack = [bg]
    for f, label in zip(frames, labels, strict=True):
        reach = HALO_MAX_RADII * max(ball_px, label.radius_px)  # the halo reaches far
        far = (xx - label.center_px[0]) ** 2 + (yy - label.center_px[1]) ** 2 > reach**2
        stack.append(np.where(far[..., None], f, np.nan))
    med = np.nanmedian(np.stack(stack), axis=0)
    med = np.where(np.isnan(med), bg, med).astype(np.float32)
    return _low(med)


def _low(img: np.ndarray) -> np.ndarray:
    blurred = cv2.GaussianBlur(img, (0, 0), FIELD_BLUR_PX, borderType=cv2.BORDER_REPLICATE)
    return blurred[::FIELD_STRIDE, ::FIELD_STRIDE]


class _FieldModel:
    """The background field as a linear model per channel: columns ambient x vignetting, each
    light's irradiance (scatter) and irradiance x response (directional), each hot spot."""

    def __init__(self, profile, data, degree: int):
        quiet = _quiet(profile)
        self.sim = GelSimulator(
            quiet, 0, image_size=(data.width_px, data.height_px), px_per_mm=data.px_per_mm
        )
        self.lights = [dict(li) for li in profile["lights"]]
        self.vignetting = float(profile["optics"].get("vignetting", 0.0))
        self.spots = [dict(s) for s in profile["optics"].get("hot_spots", [])]
        k = FIELD_STRIDE
        sim = self.sim
        # the basis is smooth over the blur's few pixels: shaded at the sampled pixels directly
        self._at = (sim.X[::k, ::k], sim.Y[::k, ::k], sim.Z0[::k, ::k])
        self._n = tuple(n[::k, ::k] for n in sim._n0)
        self._rho2 = sim._rho2[::k, ::k]
        self._spot_images = [self._spot(s) for s in self.spots]
        self.degree = int(degree)
        # the constant term is the ambient's (left out: two equal columns)
        self._field = [t[::k, ::k] for t in field_terms(sim.width, sim.height, self.degree)[1:]]

    def _spot(self, spot) -> np.ndarray:
        sim = self.sim
        k = FIELD_STRIDE
        xx, yy = np.meshgrid(np.arange(sim.width)[::k], np.arange(sim.height)[::k])
        diag = math.hypot(sim.width, sim.height)
        d2 = (xx - spot["x"] * (sim.width - 1)) ** 2 + (yy - spot["y"] * (sim.height - 1)) ** 2
        return np.exp(-d2 / (2 * (spot["sigma"] * diag) ** 2)).astype(np.float32)

    def columns(self, lights, vignetting) -> list[np.ndarray]:
        """Sampled basis images: ambient, scatter x L, directional x L, spots."""
        sim = self.sim
        sim._setup_lights(lights)
        vig = (1.0 - vignetting * self._rho2).astype(np.float32)
        shading = sim._shading(*self._at, self._n, vig)
        cols = [vig]
        cols += [irr * resp for resp, irr in shading]
        return cols + self._spot_images + self._field

    def lower_bounds(self) -> np.ndarray:
        """Levels are >= 0, the smooth field's coefficients signed."""
        n_pos = 1 + len(self.lights) + len(self.spots)
        return np.r_[np.zeros(n_pos), np.full(len(self._field), -np.inf)]

    def _lights_at(self, x) -> list[dict]:
        out = []
        for i, li in enumerate(self.lights):
            li = dict(li)
            li["distance_mm"] = float(math.exp(x[i]))
            out.append(li)
        return out

    def fit(self, target: np.ndarray) -> np.ndarray:
        b = target.reshape(-1, 3).astype(np.float64)

        def residual(x):
            a = np.stack([c.ravel() for c in self.columns(self._lights_at(x), x[-1])], axis=1)
            a = a.astype(np.float64)
            return (a @ _bounded_lstsq(a, b, self.lower_bounds()) - b).ravel()

        x0 = np.array([math.log(li["distance_mm"]) for li in self.lights] + [self.vignetting])
        n = len(self.lights)
        lo = np.r_[[math.log(3.0)] * n, 0.0]
        hi = np.r_[[math.log(200.0)] * n, 0.9]
        x0 = np.clip(x0, lo + 1e-9, hi - 1e-9)
        return least_squares(residual, x0, bounds=(lo, hi), x_scale="jac", max_nfev=400).x

    def apply(self, x, profile) -> None:
        for li, new in zip(profile["lights"], self._lights_at(x), strict=True):
            li["distance_mm"] = round(new["distance_mm"], 2)
        profile["optics"]["vignetting"] = round(float(x[-1]), 4)
        self.lights = [dict(li) for li in profile["lights"]]
        self.vignetting = float(profile["optics"]["vignetting"])

    def apply_levels(self, levels: np.ndarray, profile) -> None:
        """levels (3 channels, columns) -> ambient, scatter_dn, gain_dn x color_rgb, hot spots."""
        n = len(profile["lights"])
        profile["optics"]["ambient_dn"] = _r(levels[:, 0], 2)
        for i, li in enumerate(profile["lights"]):
            li["scatter_dn"] = [0.0, 0.0, 0.0]  # normal-independent light: the ambient and field
            directional = levels[:, 1 + i]
            gain = float(directional.max())
            li["gain_dn"] = round(gain, 2)
            if gain > 0:
                li["color_rgb"] = _r(directional / gain, 4)
        spots = profile["optics"].get("hot_spots", [])
        for k, spot in enumerate(spots):
            spot["amplitude_dn"] = _r(levels[:, 1 + n + k], 2)
        first = 1 + n + len(spots)
        profile["optics"]["background_field"] = {
            "degree": self.degree,
            "coefficients_dn": [[0.0, *_r(row, 2)] for row in levels[:, first:]],
        }


def _quiet(profile) -> dict:
    """A copy without noise, texture, flicker or markers: only the deterministic shading."""
    quiet = copy.deepcopy(dict(profile))
    quiet["optics"] = dict(quiet["optics"])
    quiet["optics"].update(
        noise_dn=[0.0, 0.0, 0.0], texture_dn=0.0, frame_gain_jitter=0.0, markers=None
    )
    quiet["gel"] = dict(quiet["gel"], mechanics=quiet["gel"].get("mechanics", "geometric"))
    return quiet


# ------------------------------------------------------------------------- contacts
def _light_azimuths(profile, frames, bg, labels, ball_px) -> list[float]:
    """Each light's azimuth (deg, image frame) from the contacts: per channel, the direction in
    which the change (frame - background - drift) grows with the sphere's normal (least squares on
    nx, ny, nz, 1 inside the contact), for the light whose colour that channel is."""
    design, values = [], []
    for f, label in zip(frames, labels, strict=True):
        change = _real_change(f, bg, label, ball_px)
        nx = (change.cols - label.center_px[0]) / ball_px
        ny = (change.rows - label.center_px[1]) / ball_px
        rad = 0.9 * min(label.radius_px, 0.98 * ball_px) / ball_px
        inside = nx**2 + ny**2 < rad**2
        nz = np.sqrt(np.clip(1 - nx**2 - ny**2, 0, 1))
        # one offset per contact: its mean change
        onehot = np.zeros((inside.sum(), len(labels)))
        onehot[:, len(design)] = 1.0
        design.append(np.c_[nx[inside], ny[inside], nz[inside], onehot])
        values.append(change.change[inside])
    coef, *_ = np.linalg.lstsq(np.concatenate(design), np.concatenate(values), rcond=None)
    out = []
    for li in profile["lights"]:
        c = int(np.argmax(li["color_rgb"]))
        out.append(round(math.degrees(math.atan2(coef[1, c], coef[0, c])) % 360.0, 1))
    return out


@dataclass
class _Contact:
    rows: np.ndarray  # (N,) pixel rows used
    cols: np.ndarray
    change: np.ndarray  # (N, 3) real change, drift removed


def _real_change(frame, bg, label, ball_px) -> _Contact:
    h, w = bg.shape[:2]
    yy, xx = np.mgrid[:h, :w]
    r2 = (xx - label.center_px[0]) ** 2 + (yy - label.center_px[1]) ** 2
    diff = frame - bg
    drift = np.median(diff[r2 > (2.0 * ball_px) ** 2], axis=0)
    near = r2 <= (CONTACT_REACH * ball_px) ** 2
    # a clipped pixel says only that the change was at least this large: left out
    near &= ((frame > 0) & (frame < 255) & (bg > 0) & (bg < 255)).all(axis=2)
    near[1::CONTACT_STRIDE, :] = False
    near[:, 1::CONTACT_STRIDE] = False
    rows, cols = np.nonzero(near)
    return _Contact(rows, cols, (diff - drift)[rows, cols])


def _contact_bases(profile, data, labels) -> list[np.ndarray]:
    """Per contact, the unblurred change (H, W, L) of each light's directional term at unit gain,
    full frame (zeros outside the contact's window)."""
    n = len(profile["lights"])
    if n != 3:
        raise ConfigError(f"sensor profile {profile.get('name')!r}: the fit needs three lights")
    unit = np.eye(3).tolist()
    directional = _quiet(profile)
    directional["optics"].update(
        blur_sigma_px=0.0, ambient_dn=[0, 0, 0], hot_spots=[], background_field=None
    )
    for i in range(n):  # light i into channel i
        directional["lights"][i].update(color_rgb=unit[i], gain_dn=1.0, scatter_dn=[0, 0, 0])
    sim = GelSimulator(
        directional, 0, image_size=(data.width_px, data.height_px), px_per_mm=data.px_per_mm
    )
    ball = Sphere(data.ball_radius_mm)
    out = []
    for label in labels:
        full = np.zeros((data.height_px, data.width_px, 3), np.float32)
        change = sim.contact_change(ball, label.center_px, 0.0, simulated_depth_mm(label, data))
        if change is not None:
            (y0, y1, x0, x1), d = change
            full[y0:y1, x0:x1] = d
        out.append(full)
    return out


def _solve_levels(geo: _FieldModel, target, contacts, bases, blur: float):
    """Per channel NNLS of the field and the contacts together; (levels (3, K), field rms, contact
    rms), each half of the rows weighted equally."""
    n = len(geo.lights)
    field_cols = geo.columns(geo.lights, geo.vignetting)
    k = len(field_cols)
    a_field = np.stack([c.ravel() for c in field_cols], axis=1)
    rows_c, b_c = [], []
    for contact, d_img in zip(contacts, bases, strict=True):
        if blur > 0:
            d_img = cv2.GaussianBlur(d_img, (0, 0), blur, borderType=cv2.BORDER_REPLICATE)
        a = np.zeros((contact.rows.size, k), np.float32)
        a[:, 1 : 1 + n] = d_img[contact.rows, contact.cols]
        rows_c.append(a)
        b_c.append(contact.change)
    a_contact = np.concatenate(rows_c)
    b_contact = np.concatenate(b_c)
    wf = 1.0 / math.sqrt(a_field.shape[0])
    wc = 1.0 / math.sqrt(a_contact.shape[0])
    a = np.concatenate([a_field * wf, a_contact * wc]).astype(np.float64)
    b_field = target.reshape(-1, 3)
    b = np.concatenate([b_field * wf, b_contact * wc]).astype(np.float64)
    coef = _bounded_lstsq(a, b, geo.lower_bounds())  # (K, 3)
    res_f = a_field @ coef - b_field
    res_c = a_contact @ coef - b_contact
    return coef.T, float(np.sqrt(np.mean(res_f**2))), float(np.sqrt(np.mean(res_c**2)))


def _bounded_lstsq(a: np.ndarray, b: np.ndarray, lower: np.ndarray) -> np.ndarray:
    """argmin ||a x - b|| with x >= lower for each column of b, through a's QR (||a x - b||^2 =
    ||r x - q'b||^2 + const): the tall problem's answer at the small one's cost."""

    k = a.shape[1]
    # R of [a | b] holds a's R and q'b side by side; Q itself is never formed
    r_aug = qr(np.concatenate([a, b], axis=1), mode="r", overwrite_a=True)[0]
    r, qb = r_aug[:k, :k], r_aug[:k, k:]
    bounds = (lower, np.full(lower.shape, np.inf))
    return np.stack(
        [lsq_linear(r, qb[:, c], bounds=bounds, method="bvls").x for c in range(b.shape[1])],
        axis=1,
    )


# ------------------------------------------------------------------------- noise
def _fit_noise(profile, data, frames, labels, ball_px, correlation_range_px) -> dict[str, Any]:
    """noise_dn and noise_correlation_px so that blank renders match the frames' fine residual."""
    h, w = data.height_px, data.width_px
    yy, xx = np.mgrid[:h, :w]
    stds, acfs = [], []
    for f, label in zip(frames, labels, strict=True):
        far = (xx - label.center_px[0]) ** 2 + (yy - label.center_px[1]) ** 2 > (
            1.5 * max(ball_px, label.radius_px)
        ) ** 2
        std, acf = noise_figures(f, far)
        stds.append(std)
        acfs.append(acf)
    real_std = np.median(np.array(stds), axis=0)
    real_acf = float(np.median(acfs))
    everywhere = np.ones((h, w), bool)
    quiet = copy.deepcopy(profile)
    quiet["optics"]["frame_gain_jitter"] = 0.0
    sim = GelSimulator(quiet, 0, image_size=(w, h), px_per_mm=data.px_per_mm)

    def measure(corr, sigma):
        sim.noise_correlation_px = float(corr)
        sim.noise_dn = np.asarray(sigma, np.float32)
        sim._setup_noise()
        return noise_figures(sim.blank(0), everywhere)

    def matched(corr):
        """noise_dn giving the real residual std at this correlation, and the acf it gives."""
        lo, hi = 0.5, 1.5
        s_lo, _ = measure(corr, [lo] * 3)
        s_hi, _ = measure(corr, [hi] * 3)
        # the residual's variance is the noise's (x a filter gain) plus a floor (texture, rounding)
        q = (s_hi**2 - s_lo**2) / (hi**2 - lo**2)
        p = s_lo**2 - q * lo**2
        sigma = np.sqrt(np.clip((real_std**2 - p) / np.maximum(q, 1e-9), 0.0, None))
        return sigma, measure(corr, sigma)[1]

    lo, hi = correlation_range_px
    sigma, acf = matched(lo)
    if acf < real_acf:  # the neighbour correlation grows with the blur: bisect
        for _ in range(BISECTIONS):
            mid = 0.5 * (lo + hi)
            s_mid, acf_mid = matched(mid)
            if acf_mid < real_acf:
                lo = mid
            else:
                hi = mid
        corr = 0.5 * (lo + hi)
        sigma, acf = matched(corr)
    else:
        corr = lo
    profile["optics"]["noise_dn"] = _r(sigma, 3)
    profile["optics"]["noise_correlation_px"] = round(float(corr), 3)
    return {"hf_noise_std_rgb": _r(real_std, 3), "noise_acf1": round(real_acf, 3)}
