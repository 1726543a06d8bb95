"""Ground-truth depth of a test object pressed into the gel, on the sensor's pixel grid.

The object (a mesh in the press frame, see :mod:`threedcal.evaluate.objects`) is posed on the image
and its gel-facing surface — the lowest z along each vertical line — is rasterised at the pixel
centres with a z-buffer: h(x, y) = z_surface − z_min ≥ 0, +inf where the object is absent. Pressing
the object d mm into the gel gives depth = max(0, d − h), positive into the gel. Keeping h makes the
depth at any d a clip, which the indentation fit exploits.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from threedcal.dataset.labels import local_dome
from threedcal.errors import ConfigError
from threedcal.evaluate.mesh import Mesh

_BARY_EPS = 1e-9  # pixel centres on a shared edge belong to both triangles
_MIN_AREA2_PX = 1e-9  # faces seen edge-on (vertical walls) cover no pixel centre
_CHUNK_CELLS = 2_000_000


class PenetrationError(ConfigError):
    """An indentation deeper than the gel allows (or negative)."""


@dataclass(frozen=True)
class HeightMap:
    """The gel-facing surface of a posed object: height above its lowest point, mm (+inf: absent)."""

    height_mm: np.ndarray
    px_per_mm: float
    center_px: tuple[float, float]
    rotation_deg: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.height_mm.shape

    @property
    def covered(self) -> np.ndarray:
        return np.isfinite(self.height_mm)

    def depth(self, indentation_mm: float, max_penetration_mm: float | None = None) -> np.ndarray:
        """Depth map (mm, positive into the gel) with the lowest point pressed `indentation_mm` deep."""
        check_indentation(indentation_mm, max_penetration_mm)
        return np.maximum(indentation_mm - self.height_mm, 0.0)


def check_indentation(indentation_mm: float, max_penetration_mm: float | None) -> None:
    if not np.isfinite(indentation_mm) or indentation_mm < 0:
        raise PenetrationError(f"indentation must be finite and >= 0 mm, got {indentation_mm}")
    if max_penetration_mm is not None and indentation_mm > max_penetration_mm:
        raise PenetrationError(
            f"indentation {indentation_mm:.4g} mm is deeper than the maximum penetration "
            f"{max_penetration_mm:.4g} mm the gel allows"
        )


def pose_vertices(
    mesh: Mesh,
    px_per_mm: float,
    center_px: Sequence[float],
    rotation_deg: float,
    linear_px_per_mm: np.ndarray | None = None,
) -> np.ndarray:
    """(V, 3): column, row (pixels) and height above the mesh's lowest point (mm).

    The object's origin goes to `center_px` (x = column, y = row); it turns by `rotation_deg`
    about its origin, clockwise as displayed (image y points down). `linear_px_per_mm` (2 x 2,
    object mm → pixels) replaces scale and rotation with any linear map, e.g. a registration's.
    """
    linear = pose_linear(px_per_mm, rotation_deg, linear_px_per_mm)
    x, y, z = mesh.vertices.T
    col = center_px[0] + linear[0, 0] * x + linear[0, 1] * y
    row = center_px[1] + linear[1, 0] * x + linear[1, 1] * y
    return np.column_stack([col, row, z - z.min()])


def pose_linear(
    px_per_mm: float, rotation_deg: float, linear_px_per_mm: np.ndarray | None = None
) -> np.ndarray:
    """The 2 x 2 map object mm → image pixels of a pose."""
    if linear_px_per_mm is not None:
        linear = np.asarray(linear_px_per_mm, dtype=np.float64)
        if linear.shape != (2, 2) or not np.all(np.isfinite(linear)):
            raise ConfigError(f"linear_px_per_mm must be a finite 2 x 2 matrix, got {linear}")
        if abs(np.linalg.det(linear)) < 1e-12:
            raise ConfigError(f"linear_px_per_mm is singular: {linear.tolist()}")
        return linear
    c, s = np.cos(np.radians(rotation_deg)), np.sin(np.radians(rotation_deg))
    return px_per_mm * np.array([[c, -s], [s, c]])


def surface_height(
    mesh: Mesh,
    shape: Sequence[int],
    px_per_mm: float,
    center_px: Sequence[float] | None = None,
    rotation_deg: float = 0.0,
    linear_px_per_mm: np.ndarray | None = None,
    dome: Mapping | None = None,
) -> HeightMap:
    """Rasterise the gel-facing surface of `mesh` posed on an image of `shape` (H, W).

    `center_px` defaults to the image centre. Parts outside the image are clipped; the lowest point
    counts even when it lies outside the image (the object still rests on it). With
    `linear_px_per_mm` the pose is that linear map (see `pose_vertices`); the HeightMap then
    records its mean scale and the turn of the object's x axis. `dome`: the gel's (profile
    `gel.dome`); the height is then measured from the undeformed dome, which falls away from the
    object by its sag relative to the sag under `center_px` (where the press depth is measured).
    """
    height, width = (int(v) for v in shape[:2])
    if height < 1 or width < 1:
        raise ConfigError(f"image shape must be positive, got {tuple(shape)}")
    if not np.isfinite(px_per_mm) or px_per_mm <= 0:
        raise ConfigError(f"px_per_mm must be > 0, got {px_per_mm}")
    if center_px is None:
        center_px = ((width - 1) / 2, (height - 1) / 2)
    center = (float(center_px[0]), float(center_px[1]))
    linear = pose_linear(px_per_mm, float(rotation_deg), linear_px_per_mm)
    verts = pose_vertices(mesh, px_per_mm, center, 0.0, linear)
    faces = mesh.faces
    if np.linalg.det(linear) < 0:  # a mirroring map (flipped camera) turns every face's winding
        faces = faces[:, ::-1]
    zbuf = _rasterise_min(verts[faces], height, width)
    if linear_px_per_mm is not None:
        px_per_mm = math.sqrt(abs(np.linalg.det(linear)))
        rotation_deg = math.degrees(math.atan2(linear[1, 0], linear[0, 0]))
    if dome:
        zbuf = zbuf + dome_rise(dome, center, (height, width), px_per_mm)
    return HeightMap(zbuf, float(px_per_mm), center, float(rotation_deg))


def dome_rise(
    dome: Mapping, center_px: Sequence[float], shape: Sequence[int], px_per_mm: float, shift=(0, 0)
) -> np.ndarray:
    """How far the undeformed dome (profile `gel.dome`) falls below its height under `center_px`,
    mm, at every pixel of an image of `shape` — sampled at (x, y) + `shift` px."""
    height, width = (int(v) for v in shape[:2])
    local = local_dome(dome, center_px, (height, width), px_per_mm)
    x = (np.arange(width, dtype=np.float64) + shift[0] - center_px[0]) / px_per_mm
    y = (np.arange(height, dtype=np.float64) + shift[1] - center_px[1]) / px_per_mm
    return local.sag_mm(x[None, :], y[:, None])


def depth_map(
    mesh: Mesh,
    indentation_mm: float,
    shape: Sequence[int],
    px_per_mm: float,
    *,
    max_penetration_mm: float | None,
    center_px: Sequence[float] | None = None,
    rotation_deg: float = 0.0,
) -> np.ndarray:
    """Ground-truth depth (mm, positive into the gel) of `mesh` pressed `indentation_mm` deep."""
    check_indentation(indentation_mm, max_penetration_mm)
    surface = surface_height(mesh, shape, px_per_mm, center_px, rotation_deg)
    return surface.depth(indentation_mm)


def _rasterise_min(tris: np.ndarray, height: int, width: int) -> np.ndarray:
    """Lowest interpolated z of the triangles (F, 3, [col, row, z]) at each pixel centre; +inf if none."""
    zbuf = np.full(height * width, np.inf)
    x, y, z = tris[..., 0], tris[..., 1], tris[..., 2]
    area2 = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    c0 = np.maximum(np.ceil(x.min(axis=1) - 1e-7), 0)
    c1 = np.minimum(np.floor(x.max(axis=1) + 1e-7), width - 1)
    r0 = np.maximum(np.ceil(y.min(axis=1) - 1e-7), 0)
    r1 = np.minimum(np.floor(y.max(axis=1) + 1e-7), height - 1)
    # only faces turned towards the gel (-z) can be the lowest surface; in the image frame they
    # run clockwise (negative area). Faces seen edge-on (vertical walls) cover no pixel centre.
    live = (area2 < -_MIN_AREA2_PX) & (c1 >= c0) & (r1 >= r0)
    if not live.any():
        return zbuf.reshape(height, width)
    idx = np.flatnonzero(live)
    # bucket by bounding-box size (powers of two per axis) so long thin faces stay cheap
    bw = 2 ** np.ceil(np.log2(c1[idx] - c0[idx] + 1)).astype(np.int64)
    bh = 2 ** np.ceil(np.log2(r1[idx] - r0[idx] + 1)).astype(np.int64)
    for sw, sh in sorted(set(zip(bw.tolist(), bh.tolist(), strict=True))):
        group = idx[(bw == sw) & (bh == sh)]
        step = max(1, _CHUNK_CELLS // (sw * sh))
        offs_c = np.arange(sw, dtype=np.float64)
        offs_r = np.arange(sh, dtype=np.float64)
        for start in range(0, len(group), step):
            g = group[start : start + step]
            cols = c0[g, None, None] + offs_c[None, None, :]  # (n, 1, sw)
            rows = r0[g, None, None] + offs_r[None, :, None]  # (n, sh, 1)
            x0, y0 = x[g, 0, None, None], y[g, 0, None, None]
            dx, dy = cols - x0, rows - y0
            a = area2[g, None, None]
            l1 = (
                dx * (y[g, 2] - y[g, 0])[:, None, None] - dy * (x[g, 2] - x[g, 0])[:, None, None]
            ) / a
            l2 = (
                dy * (x[g, 1] - x[g, 0])[:, None, None] - dx * (y[g, 1] - y[g, 0])[:, None, None]
            ) / a
            l0 = 1.0 - l1 - l2
            inside = (
                (l0 >= -_BARY_EPS)
                & (l1 >= -_BARY_EPS)
                & (l2 >= -_BARY_EPS)
                & (cols <= c1[g, None, None])
                & (rows <= r1[g, None, None])
            )
            zi = l0 * z[g, 0, None, None] + l1 * z[g, 1, None, None] + l2 * z[g, 2, None, None]
            flat = (rows * width + cols).astype(np.int64)
            np.minimum.at(zbuf, flat[inside], zi[inside])
    return zbuf.reshape(height, width)
