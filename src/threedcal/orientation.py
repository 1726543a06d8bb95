"""The quarter turn between a sensor's portrait and landscape frames.

A folder of frames stored on its side (FOTS's portrait GelSight frames against the Mini profile's
landscape ones) is read turned, so that its lights fall where the profile puts them. Which way
is a fact of how that folder was stored, so the folder states it (`turn_to_sensor` in its
description). Counter-clockwise (numpy's rot90) takes pixel (x, y) to (y, W - 1 - x) and an
image-frame azimuth θ to θ - 90°; clockwise takes (x, y) to (H - 1 - y, x) and θ to θ + 90°.
"""

from __future__ import annotations

import numpy as np

from threedcal.errors import ConfigError

ORIENTATIONS = ("portrait", "landscape")
TURNS = ("counterclockwise", "clockwise")
TURN_KEY = "turn_to_sensor"  # a folder description's key: how its frames turn into the sensor's


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


def folder_turn(height: int, width: int, orientation: str | None, stated, where: str) -> str | None:
    """How a folder's (height, width) frames turn into a sensor's `orientation`: None when they
    need not, else the folder's `stated` turn, which it must give (ConfigError naming `where`)."""
    if not needs_turn(height, width, orientation):
        return None
    if stated not in TURNS:
        raise ConfigError(
            f"{where}: its {width} x {height} px frames lie on their side against the sensor's "
            f"{orientation} frame; say which way they turn into it: {TURN_KEY}: "
            f"{' or '.join(TURNS)} (got {stated!r})"
        )
    return str(stated)


def turn_image(
    image: np.ndarray, axes: tuple[int, int] = (0, 1), turn: str = "counterclockwise"
) -> np.ndarray:
    """`image` turned a quarter in the plane of `axes` (rows, columns)."""
    k = 1 if turn == "counterclockwise" else -1
    return np.ascontiguousarray(np.rot90(image, k=k, axes=axes))


def turn_points(xy, width: int, height: int, turn: str = "counterclockwise") -> np.ndarray:
    """(N, 2) pixel points (x, y) of a `width` x `height` frame, where the turned frame has them."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if turn == "counterclockwise":
        return np.stack([xy[:, 1], (int(width) - 1) - xy[:, 0]], axis=1)
    return np.stack([(int(height) - 1) - xy[:, 1], xy[:, 0]], axis=1)
