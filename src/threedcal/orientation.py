"""The one quarter turn between a sensor's portrait and landscape frames.

A folder of frames stored on its side (FOTS's portrait GelSight frames against the Mini profile's
landscape ones) is read turned, so that its lights fall where the profile puts them. The turn is
counter-clockwise (numpy's rot90): pixel (x, y) goes to (y, W - 1 - x), and an image-frame azimuth
θ to θ - 90°.
"""

from __future__ import annotations

import numpy as np

ORIENTATIONS = ("portrait", "landscape")


def orientation_of(height: int, width: int) -> str | None:
    """'portrait' (taller than wide), 'landscape' (wider than tall), or None for a square frame."""
    if height == width:
        return None
    return "portrait" if height > width else "landscape"


def needs_turn(height: int, width: int, orientation: str | None) -> bool:
    """True when an (height, width) frame lies on its side against `orientation` (None: never)."""
    if orientation is None:
        return False
    if orientation not in ORIENTATIONS:
        raise ValueError(f"orientation must be one of {ORIENTATIONS}, got {orientation!r}")
    here = orientation_of(int(height), int(width))
    return here is not None and here != orientation


def turn_image(image: np.ndarray, axes: tuple[int, int] = (0, 1)) -> np.ndarray:
    """`image` turned a quarter counter-clockwise in the plane of `axes` (rows, columns)."""
    return np.ascontiguousarray(np.rot90(image, axes=axes))


def turn_points(xy, width: int) -> np.ndarray:
    """(N, 2) pixel points (x, y) of a frame `width` pixels wide, where the turned frame has them."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    return np.stack([xy[:, 1], (int(width) - 1) - xy[:, 0]], axis=1)
