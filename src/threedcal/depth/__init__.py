"""Gradient -> depth integration: correct fast Poisson solvers, a masked least-squares solver, the
authors' solver for comparison, and gradient sanitising. One convention for all (see
threedcal.depth.convention): pixel-centre dimensionless gradients of depth (positive into the gel),
depth in mm out through px_per_mm, and an explicit offset policy.

    depth_mm = integrate(gx, gy, method="poisson_dst", px_per_mm=19.5)
"""

from __future__ import annotations

from threedcal.depth.convention import OFFSETS, apply_offset, consistent_gradients, edge_gradients
from threedcal.depth.py3dcal import py3dcal, py3dcal_fast_poisson
from threedcal.depth.sanitize import DEFAULT_MAX_ANGLE_DEG, SanitizeReport, sanitize_gradients
from threedcal.depth.sparse import lstsq_sparse
from threedcal.depth.spectral import frankot_chellappa, poisson_dct, poisson_dst
from threedcal.errors import ConfigError

# The integrators a config may name; `py3dcal` is the authors' solver, kept for comparison only.
METHODS = {
    "poisson_dst": poisson_dst,
    "poisson_dct": poisson_dct,
    "frankot_chellappa": frankot_chellappa,
    "lstsq_sparse": lstsq_sparse,
    "py3dcal": py3dcal,
}


def integrate(
    gx,
    gy,
    method: str = "poisson_dst",
    *,
    px_per_mm: float = 1.0,
    mask=None,
    weights=None,
    offset: str = "border",
    max_angle_deg: float | None = DEFAULT_MAX_ANGLE_DEG,
    workers: int | None = None,
    return_report: bool = False,
):
    """Depth map (mm, positive into the gel) from pixel-centre gradients dz/dx, dz/dy.

    mask (True = valid) and weights need `lstsq_sparse`; the other methods refuse them rather than
    ignore them. With return_report=True returns (depth_mm, SanitizeReport).
    """
    if method not in METHODS:
        raise ConfigError(
            f"integrate: method {method!r} is not allowed (allowed: {', '.join(METHODS)})"
        )
    if (mask is not None or weights is not None) and method != "lstsq_sparse":
        raise ConfigError(f"integrate: mask/weights need method 'lstsq_sparse', not {method!r}")
    kwargs = dict(px_per_mm=px_per_mm, offset=offset, max_angle_deg=max_angle_deg, workers=workers)
    if method == "lstsq_sparse":  # it leaves non-finite pixels out of the fit by itself
        kwargs.update(mask=mask, weights=weights)
    depth = METHODS[method](gx, gy, **kwargs)
    if not return_report:
        return depth
    return depth, sanitize_gradients(gx, gy, max_angle_deg)[2]


__all__ = [
    "DEFAULT_MAX_ANGLE_DEG",
    "METHODS",
    "OFFSETS",
    "SanitizeReport",
    "apply_offset",
    "consistent_gradients",
    "edge_gradients",
    "frankot_chellappa",
    "integrate",
    "lstsq_sparse",
    "poisson_dct",
    "poisson_dst",
    "py3dcal",
    "py3dcal_fast_poisson",
    "sanitize_gradients",
]
