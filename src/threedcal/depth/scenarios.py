"""Analytic test scenes for the integrators: true depth (mm) and its pixel-centre gradients.

The field of view is a DIGIT frame (240 x 320 px at 19.5 px/mm, 12.3 x 16.4 mm); a larger grid
samples the same scene more finely (px/mm grows with the shorter side), so sizes compare like with
like. Depth is positive into the gel; gradients are the exact analytic derivatives at pixel centres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from threedcal.errors import ConfigError

BASE_PX_PER_MM = 19.5
BASE_SHORT_SIDE_PX = 240


@dataclass(frozen=True)
class Scene:
    depth_mm: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    px_per_mm: float


def pixel_centres_mm(h: int, w: int, px_per_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates in mm relative to the frame centre (x right, y down)."""
    x = (np.arange(w) - (w - 1) / 2) / px_per_mm
    y = (np.arange(h) - (h - 1) / 2) / px_per_mm
    return np.meshgrid(x, y)


def sphere_cap(x, y, radius_mm: float, depth_mm: float, cx: float = 0.0, cy: float = 0.0):
    """A ball of radius R pressed depth d: z = sqrt(R^2 - r^2) - (R - d) where positive."""
    dx, dy = x - cx, y - cy
    s = np.sqrt(np.maximum(radius_mm**2 - dx**2 - dy**2, 0.0))
    inside = s > radius_mm - depth_mm
    safe = np.where(inside & (s > 0), s, 1.0)
    z = np.where(inside, s - (radius_mm - depth_mm), 0.0)
    gx = np.where(inside, -dx / safe, 0.0)
    gy = np.where(inside, -dy / safe, 0.0)
    return z, gx, gy


def gaussian(x, y, amplitude_mm: float, sigma_mm: float):
    z = amplitude_mm * np.exp(-(x**2 + y**2) / (2 * sigma_mm**2))
    return z, -x / sigma_mm**2 * z, -y / sigma_mm**2 * z


def pawn_radius(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Radius r(s) and dr/ds of a pawn-like solid of revolution, s mm along its axis from the base.

    Base disc (r 5, flat end faces: vertical walls), tapering body, collar, neck, spherical head.
    """
    parts = [
        ((s >= 0) & (s <= 2.0), np.full_like(s, 5.0), np.zeros_like(s)),
        ((s > 2.0) & (s <= 7.0), 3.0 - 0.24 * (s - 2.0), np.full_like(s, -0.24)),
        ((s > 7.0) & (s <= 7.6), np.full_like(s, 2.6), np.zeros_like(s)),
        ((s > 7.6) & (s <= 8.6), np.full_like(s, 1.5), np.zeros_like(s)),
    ]
    r = np.zeros_like(s)
    dr = np.zeros_like(s)
    for where, radius, slope in parts:
        r = np.where(where, radius, r)
        dr = np.where(where, slope, dr)
    head = np.sqrt(np.maximum(2.3**2 - (s - 10.5) ** 2, 0.0))
    use_head = head > r
    dr = np.where(use_head, -(s - 10.5) / np.where(head > 0, head, 1.0), dr)
    return np.where(use_head, head, r), dr


def pawn_press(x, y, press_mm: float = 2.5):
    """The pawn lying on its side (axis along x), pressed `press_mm` into the gel by its base."""
    s = x + 6.4  # base face 6.4 mm left of the centre, head end 12.8 mm further
    r, dr = pawn_radius(s)
    t = y
    cross = np.sqrt(np.maximum(r**2 - t**2, 0.0))
    floor = 5.0 - press_mm
    inside = cross > floor
    safe = np.where(inside, cross, 1.0)
    z = np.where(inside, cross - floor, 0.0)
    gx = np.where(inside, r * dr / safe, 0.0)
    gy = np.where(inside, -t / safe, 0.0)
    return z, gx, gy


def _noise(rng, gx, gy, sigma):
    return gx + rng.normal(0, sigma, gx.shape), gy + rng.normal(0, sigma, gy.shape)


def _outliers(rng, gx, gy):
    gx, gy = gx.copy(), gy.copy()
    n = gx.size
    flat_x, flat_y = gx.reshape(-1), gy.reshape(-1)
    spikes = rng.choice(n, max(1, n // 200), replace=False)
    flat_x[spikes] = rng.choice([-1e6, 1e6], spikes.size)
    flat_y[spikes] = rng.choice([-1e6, 1e6], spikes.size)
    bad = rng.choice(n, max(2, n // 500), replace=False)
    flat_x[bad[: bad.size // 2]] = np.nan
    flat_y[bad[bad.size // 2 :]] = np.inf
    return gx, gy


def _curl(x, y, gx, gy, amplitude=0.05, sigma_mm=2.0):
    """Add a divergence-free (non-integrable) field: the rotated gradient of a Gaussian."""
    psi = amplitude * sigma_mm * np.exp(-((x - 1.0) ** 2 + (y + 0.5) ** 2) / (2 * sigma_mm**2))
    dpsi_dx = -(x - 1.0) / sigma_mm**2 * psi
    dpsi_dy = -(y + 0.5) / sigma_mm**2 * psi
    return gx - dpsi_dy, gy + dpsi_dx


def _cap(x, y):
    return sphere_cap(x, y, 4.0, 1.0)


# name -> (description, builder(x, y, rng) -> (z, gx_true_or_noisy, gy)).
SCENARIOS = {
    "hemisphere": (
        "3D Cal test hemisphere (R 3 mm) pressed to its full depth: vertical rim",
        lambda x, y, r: sphere_cap(x, y, 3.0, 3.0),
    ),
    "shallow_cap": ("ball R 4 mm pressed 0.2 mm", lambda x, y, r: sphere_cap(x, y, 4.0, 0.2)),
    "cap": ("ball R 4 mm pressed 1 mm, centred", lambda x, y, r: _cap(x, y)),
    "border_contact": (
        "ball R 4 mm pressed 1 mm, centre 1 mm inside the left edge: contact crosses the border",
        lambda x, y, r: sphere_cap(x, y, 4.0, 1.0, cx=x.min() + 1.0),
    ),
    "noise_low": (
        "cap + Gaussian gradient noise sigma 0.01",
        lambda x, y, r: (lambda z, gx, gy: (z, *_noise(r, gx, gy, 0.01)))(*_cap(x, y)),
    ),
    "noise_high": (
        "cap + Gaussian gradient noise sigma 0.1",
        lambda x, y, r: (lambda z, gx, gy: (z, *_noise(r, gx, gy, 0.1)))(*_cap(x, y)),
    ),
    "outliers": (
        "cap + 0.5 % spikes of 1e6 and 0.2 % NaN/Inf",
        lambda x, y, r: (lambda z, gx, gy: (z, *_outliers(r, gx, gy)))(*_cap(x, y)),
    ),
    "non_integrable": (
        "cap + a divergence-free field of slope 0.05",
        lambda x, y, r: (lambda z, gx, gy: (z, *_curl(x, y, gx, gy)))(*_cap(x, y)),
    ),
    "pawn": (
        "pawn-like solid of revolution on its side, pressed 2.5 mm: vertical walls, steps in depth",
        lambda x, y, r: pawn_press(x, y),
    ),
    "gaussian": (
        "smooth Gaussian bump, 0.5 mm high, sigma 1.5 mm",
        lambda x, y, r: gaussian(x, y, 0.5, 1.5),
    ),
}


def px_per_mm_for(h: int, w: int) -> float:
    return BASE_PX_PER_MM * min(h, w) / BASE_SHORT_SIDE_PX


def make_scene(name: str, h: int, w: int, seed: int = 0) -> Scene:
    """Scenario `name` sampled on an h x w grid (noise and outliers drawn from `seed`)."""
    if name not in SCENARIOS:
        raise ConfigError(f"scenario {name!r} is not allowed (allowed: {', '.join(SCENARIOS)})")
    px = px_per_mm_for(h, w)
    x, y = pixel_centres_mm(h, w, px)
    rng = np.random.default_rng(seed)
    z, gx, gy = SCENARIOS[name][1](x, y, rng)
    return Scene(z, gx, gy, px)
