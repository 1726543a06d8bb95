"""Checkpoints: one self-contained file with the weights and everything inference needs.

A threedcal checkpoint is a plain dict of tensors, numbers and strings (so it loads with
``torch.load(weights_only=True)`` — never unpickling code): format and version, preset and its
arguments, state_dict and the input/output normalisation, then what the sensor's kind needs: a
vision model's blank frame, px/mm, image shape and camera; a ReSkin model's input names
(threedcal.reskin.model, preset `RESKIN_PRESET`). The authors' published TouchNet weights (a bare
state_dict) load too: they are recognised by their parameter names and get the authors'
normalisation (coordinate channels 1…W and 1…H; gradients of the opposite sign).

Nothing beyond torch's own allow-list of safe types is unpickled (threedcal adds none to it); a
refused file is named with the globals torch found in it (`get_unsafe_globals_in_checkpoint`).
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import torch

from threedcal.errors import ConfigError, ThreedcalError
from threedcal.lens import RadialLens
from threedcal.model.points import Registration
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
    """Load with weights_only=True; wrap an authors' bare TouchNet state_dict as a touchnet checkpoint.

    Every way a file can be unusable is a CheckpointError naming the file: missing, empty,
    truncated or not a torch file, holding pickled Python objects (refused, never run), or a
    threedcal checkpoint without the keys inference needs."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: checkpoint missing")
    if path.stat().st_size == 0:
        raise CheckpointError(
            f"{path}: is empty (0 bytes), not a checkpoint; an interrupted copy? copy it again or retrain"
        )
    data = _load_plain(path)
    if isinstance(data, dict) and data.get("format") == FORMAT:
        if data.get("format_version") != FORMAT_VERSION:
            raise CheckpointError(
                f"{path}: checkpoint format version {data.get('format_version')!r}; this "
                f"threedcal reads version {FORMAT_VERSION}"
            )
        _check_keys(path, data)
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


# What a threedcal checkpoint must hold, and of which type (training writes all of them).
REQUIRED_KEYS = {"preset": str, "state_dict": dict, "normalisation": dict}
# The ReSkin MLP's preset (threedcal.reskin.model): its checkpoint's arguments and normalisation.
RESKIN_PRESET = "reskin_mlp"
RESKIN_KEYS = {
    "preset_args": ("n_inputs", "hidden"),
    "normalisation": ("input_scale_ut", "in_mean", "in_std", "out_mean", "out_std"),
}


def _load_plain(path: Path):
    """torch.load with weights_only=True: tensors, numbers, strings and containers, nothing else."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        unsafe = _unsafe_globals(path)
        if not unsafe:
            raise CheckpointError(
                f"{path}: refused to load: not a readable checkpoint (a damaged or foreign file)"
            ) from None
        # PyTorch's own text advises loading unsafely; it is never quoted. What it found is.
        raise CheckpointError(
            f"{path}: refused to load: it holds a pickled Python object ({', '.join(unsafe)}) "
            "besides tensors, numbers and strings, and loading it could run code; threedcal loads "
            "only plain checkpoints (as its training writes them)"
        ) from None
    except Exception as exc:  # truncated, corrupt, or not a torch.save file at all
        raise CheckpointError(
            f"{path}: refused to load: not a readable checkpoint ({_first_line(exc)})"
        ) from None


def _unsafe_globals(path: Path) -> list[str]:
    """The globals outside torch's allow-list that a torch.save file would unpickle (its last
    name part, e.g. `print`); none for a file torch cannot read as a checkpoint."""
    try:
        found = torch.serialization.get_unsafe_globals_in_checkpoint(path)
    except Exception:  # noqa: BLE001 - not a zip checkpoint: nothing torch can list
        return []
    return [name.rpartition(".")[2] for name in found]


def _check_keys(path: Path, data: dict) -> None:
    missing = [key for key in REQUIRED_KEYS if key not in data]
    if missing:
        raise CheckpointError(
            f"{path}: threedcal checkpoint without {', '.join(map(repr, missing))} "
            "(written by another version, or damaged); retrain it"
        )
    for key, kind in REQUIRED_KEYS.items():
        if not isinstance(data[key], kind):
            raise CheckpointError(
                f"{path}: {key!r} must be a {kind.__name__}, got {type(data[key]).__name__}"
            )
    if "resume_key" in data:
        return  # a training state (checkpoint.pt): what inference needs is not required
    if data["preset"] == RESKIN_PRESET:
        for key, names in RESKIN_KEYS.items():
            missing = [n for n in names if n not in (data.get(key) or {})]
            if missing:
                raise CheckpointError(f"{path}: ReSkin model without {key} {', '.join(missing)}")
        return
    sign = data["normalisation"].get("gradient_sign")
    if not isinstance(sign, int | float) or sign not in (1, -1):
        raise CheckpointError(f"{path}: normalisation.gradient_sign must be 1 or -1, got {sign!r}")
    problem = _inference_problem(data)
    if problem:
        raise CheckpointError(f"{path}: {problem}")


def _inference_problem(data: dict) -> str | None:
    """What inference would trip over in the optional keys (None: nothing)."""
    if not isinstance(data.get("preset_args", {}), dict):
        return f"'preset_args' must be a dict, got {type(data['preset_args']).__name__}"
    blank = data.get("blank")
    if blank is not None and not (
        isinstance(blank, torch.Tensor) and blank.ndim == 3 and blank.shape[2] == 3
    ):
        shape = tuple(blank.shape) if isinstance(blank, torch.Tensor) else type(blank).__name__
        return f"'blank' must be an (H, W, 3) tensor, got {shape}"
    scale = data.get("px_per_mm")
    if scale is not None and not (
        isinstance(scale, int | float) and not isinstance(scale, bool) and 0 < scale < float("inf")
    ):
        return f"'px_per_mm' must be a positive number, got {scale!r}"
    shape = data.get("image_shape")
    if shape is not None and not (
        isinstance(shape, list | tuple)
        and len(shape) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in shape)
    ):
        return f"'image_shape' must be [height, width] in pixels, got {shape!r}"
    registration = data.get("registration")
    if registration is not None:
        try:
            Registration.from_record(registration, "'registration'")
        except ConfigError as exc:
            return str(exc)
    dome = data.get("dome")
    if dome is not None and not (
        isinstance(dome, dict)
        and all(isinstance(dome.get(k), int | float) for k in ("kx_per_mm", "ky_per_mm"))
    ):
        return f"'dome' must be a dict with numbers kx_per_mm and ky_per_mm, got {dome!r}"
    camera = data.get("camera")
    if camera is not None:
        if not isinstance(camera, dict):
            return f"'camera' must be a dict, got {type(camera).__name__}"
        try:
            RadialLens.from_record(camera.get("lens"))
        except ConfigError as exc:
            return f"'camera': {exc}"
    return None


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def model_from_checkpoint(checkpoint: dict[str, Any]) -> torch.nn.Module:
    """The vision network a checkpoint holds, its weights loaded."""
    if checkpoint["preset"] == RESKIN_PRESET:
        raise CheckpointError(
            "a ReSkin model (magnetic readings in, contact out): it takes no images "
            "(threedcal.reskin.model.predict reads it)"
        )
    args = checkpoint.get("preset_args", {})
    if not isinstance(args, dict):
        raise CheckpointError(f"preset_args must be a dict, got {type(args).__name__}")
    try:
        model = build_model(checkpoint["preset"], **args)
    except TypeError as exc:
        raise CheckpointError(
            f"preset_args do not fit preset {checkpoint['preset']!r}: {_first_line(exc)}"
        ) from None
    try:
        model.load_state_dict(checkpoint["state_dict"])
    except (RuntimeError, TypeError, AttributeError, ValueError) as exc:
        raise CheckpointError(
            f"weights do not fit preset {checkpoint['preset']!r}: {_first_line(exc)}"
        ) from None
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
