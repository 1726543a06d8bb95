"""Checkpoints: one self-contained file with the weights and everything inference needs.

A threedcal checkpoint is a plain dict of tensors, numbers and strings (so it loads with
``torch.load(weights_only=True)`` — never unpickling code): preset and its arguments, state_dict,
blank frame, px/mm, image shape and the input/output normalisation. The authors' published TouchNet
weights (a bare state_dict) load too: they are recognised by their parameter names and get the
authors' normalisation (coordinate channels 1…W and 1…H; gradients of the opposite sign).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from threedcal.errors import ConfigError, ThreedcalError
from threedcal.model.presets import build_model

FORMAT = "threedcal-model"
FORMAT_VERSION = 1
# Our inputs: coordinate channels in [-1, 1] over the full image, lighting drift removed
# (threedcal.model.drift); labels ∂z/∂x with z into the gel.
OUR_NORMALISATION = {"coords": "unit", "gradient_sign": 1.0, "drift": "median"}
# py3DCal: coordinate channels are 1-based pixel indices, no drift removal; its labels are −∂z/∂x
# in our convention.
AUTHORS_NORMALISATION = {"coords": "pixel_index", "gradient_sign": -1.0, "drift": "none"}


class CheckpointError(ThreedcalError):
    """A checkpoint file cannot be used (unreadable, unsafe, or not a model we know)."""


def save_checkpoint(path: str | Path, checkpoint: dict[str, Any]) -> None:
    """Write atomically (temp file + rename), so an interrupted job never leaves half a checkpoint."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(checkpoint, tmp)
    tmp.replace(path)


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load with weights_only=True; wrap an authors' bare TouchNet state_dict as a touchnet checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: checkpoint missing")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # an unsafe pickle raises UnpicklingError; a corrupt file others
        raise CheckpointError(
            f"{path}: refused to load (only tensors, numbers and strings are allowed): "
            f"{str(exc).splitlines()[0]}"
        ) from exc
    if isinstance(data, dict) and data.get("format") == FORMAT:
        if data.get("format_version") != FORMAT_VERSION:
            raise CheckpointError(f"{path}: checkpoint format version {data.get('format_version')}")
        return data
    if isinstance(data, dict) and "conv1.weight" in data and "conv9.weight" in data:
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "preset": "touchnet",
            "preset_args": {},
            "state_dict": dict(data),
            "normalisation": dict(AUTHORS_NORMALISATION),
            "source": "authors' TouchNet weights",
        }
    raise CheckpointError(
        f"{path}: neither a threedcal checkpoint nor a TouchNet state_dict "
        "(expected keys format/state_dict or conv1.weight … conv9.weight)"
    )


def model_from_checkpoint(checkpoint: dict[str, Any]) -> torch.nn.Module:
    model = build_model(checkpoint["preset"], **checkpoint.get("preset_args", {}))
    try:
        model.load_state_dict(checkpoint["state_dict"])
    except RuntimeError as exc:
        raise CheckpointError(
            f"weights do not fit preset {checkpoint['preset']!r}: {str(exc).splitlines()[0]}"
        ) from exc
    return model


def adapt_inputs(
    x: torch.Tensor, normalisation: dict, image_shape: tuple[int, int]
) -> torch.Tensor:
    """Our (N,5,h,w) inputs (unit coordinates) → what the checkpoint's network was trained on."""
    if normalisation.get("coords", "unit") == "unit":
        return x
    height, width = image_shape
    x = x.clone()
    x[:, 3] = (x[:, 3] + 1.0) * ((width - 1) / 2.0) + 1.0
    x[:, 4] = (x[:, 4] + 1.0) * ((height - 1) / 2.0) + 1.0
    return x
