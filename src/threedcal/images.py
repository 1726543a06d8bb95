"""Sensor images from files: 8-bit RGB, as a sensor gives them, or an error naming the file."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from threedcal.errors import ConfigError


def read_rgb(path: Path) -> np.ndarray:
    """An 8-bit colour image as (H, W, 3) uint8 RGB. Grey, 16-bit or transparent images are refused
    (naming the file) rather than converted: a silently rescaled or replicated channel would train
    a model on something no sensor gives it."""
    path = Path(path)
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
    if image is None:
        raise ConfigError(f"{path}: missing or not a readable image")
    channels = 1 if image.ndim == 2 else image.shape[2]
    if image.dtype != np.uint8:
        raise ConfigError(
            f"{path}: a {8 * image.dtype.itemsize}-bit image ({image.dtype}); threedcal reads 8-bit "
            "RGB images (save it with 8 bits per channel)"
        )
    if channels == 4:
        if not np.all(image[..., 3] == 255):
            raise ConfigError(
                f"{path}: has transparent pixels (an alpha channel); threedcal reads opaque RGB images"
            )
        image = image[..., :3]
    elif channels != 3:
        raise ConfigError(
            f"{path}: a {'grey' if channels == 1 else f'{channels}-channel'} image; threedcal reads "
            "8-bit RGB images (a sensor frame has three colour channels)"
        )
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2RGB)
