"""The smooth colour field a gel's LED model does not explain (housing, gel edges, paint): a
polynomial in the pixel's place, shared by the simulator, its fit and the unit draws."""

from __future__ import annotations

import numpy as np

from threedcal.errors import ConfigError


def field_terms(width: int, height: int, degree: int, margin: int = 0) -> list[np.ndarray]:
    """The monomials u^i v^j (i + j <= degree; by total degree, then by the power of v) of the
    pixel's place u = (x - cx) / cx, v = (y - cy) / cy (-1..1 from edge pixel to edge pixel of
    the frame; `margin` more pixels on every side reach beyond)."""
    cx, cy = (width - 1) / 2, (height - 1) / 2
    cols = np.arange(-margin, width + margin, dtype=np.float32)
    rows = np.arange(-margin, height + margin, dtype=np.float32)
    u = ((cols - cx) / max(cx, 1.0))[None, :]
    v = ((rows - cy) / max(cy, 1.0))[:, None]
    shape = (height + 2 * margin, width + 2 * margin)
    return [
        np.broadcast_to(u ** (k - j) * v**j, shape).astype(np.float32)
        for k in range(degree + 1)
        for j in range(k + 1)
    ]


def background_field(
    width: int, height: int, degree: int, coefficients_dn, margin: int = 0
) -> np.ndarray:
    """(H, W, 3) DN: a smooth colour field the LED model does not explain (housing, gel edges,
    paint), a polynomial of `degree` per channel (optics.background_field in the profile)."""
    terms = field_terms(width, height, degree, margin)
    coef = np.asarray(coefficients_dn, dtype=np.float32)
    if coef.shape != (3, len(terms)):
        raise ConfigError(
            f"optics.background_field: degree {degree} needs 3 rows of {len(terms)} coefficients, "
            f"got shape {coef.shape}"
        )
    return np.einsum("khw,ck->hwc", np.stack(terms), coef)
