"""A checkpoint → ONNX (for onnxruntime, C++ or a ROS 2 node) and a JSON sidecar with its geometry.

The graph takes what a camera gives after rectification — uint8 RGB frames (N, H, W, 3) of the
model's frame — and returns the gradients (N, H, W, 2): ∂z/∂x (columns), ∂z/∂y (rows), z in mm into
the gel. Everything between is inside it, as `DepthEstimator.gradients` does it: the blank
subtracted and scaled by 1/255, the lighting drift removed (the per-channel median of every 4th
pixel in both directions), the coordinate channels, the network and the gradients' sign. The
integration to depth (DST Poisson, depth 0 on the border ring) and the geometry stay outside: the
sidecar gives px/mm, the camera (lens, downscale), the registration and the first-touch height, the
gel's dome (docs/how-to/deploy.md).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from threedcal.errors import ConfigError
from threedcal.model.checkpoint import adapt_inputs
from threedcal.model.drift import STRIDE

OPSET = 17
SIDECAR_FORMAT = "threedcal-onnx"
SIDECAR_VERSION = 1


class FramesToGradients(nn.Module):
    """A DepthEstimator's `gradients` as one module of fixed frame size (what ONNX holds)."""

    def __init__(self, estimator) -> None:
        super().__init__()
        self.model = estimator.model.to("cpu", memory_format=torch.contiguous_format).eval()
        height, width = estimator.image_shape
        self.register_buffer("blank", estimator._blank.detach().cpu()[None].clone())
        coords = torch.zeros(1, 5, height, width)
        coords[:, 3:] = estimator._coords.detach().cpu()
        adapted = adapt_inputs(coords, estimator.normalisation, estimator.image_shape)
        self.register_buffer("coords", adapted[:, 3:].clone())
        self.sign = float(estimator.normalisation["gradient_sign"])
        self.drift = estimator.drift
        samples = len(range(0, height, STRIDE)) * len(range(0, width, STRIDE))
        self.median_index = (samples - 1) // 2  # torch.median's: the lower of the two middle values

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        x = frames.permute(0, 3, 1, 2).to(torch.float32)
        diff = (x - self.blank) / 255.0
        if self.drift == "median":
            sample = diff[:, :, ::STRIDE, ::STRIDE].reshape(diff.shape[0], 3, -1)
            # torch.median: the (n + 1) // 2-th smallest, i.e. the largest of that many smallest
            lowest = torch.topk(sample, self.median_index + 1, dim=2, largest=False, sorted=False)
            offset = lowest.values.amax(dim=2, keepdim=True)
            diff = diff - offset[..., None]
        coords = self.coords.expand(diff.shape[0], -1, -1, -1)
        out = self.model(torch.cat([diff, coords], 1)) * self.sign
        return out.permute(0, 2, 3, 1)


def export_onnx(estimator, path: str | Path, source: str | Path | None = None) -> dict:
    """Write `path` (.onnx) and its sidecar `path` + '.json'; returns the sidecar's record.

    `source`: the checkpoint file, named (with its SHA-256) in the sidecar."""
    path = Path(path)
    height, width = estimator.image_shape
    module = FramesToGradients(estimator).eval()
    example = torch.zeros(1, height, width, 3, dtype=torch.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    staging = path.with_name(path.name + ".tmp")
    try:
        torch.onnx.export(
            module,
            (example,),
            str(staging),
            # the TorchScript exporter (deprecated in torch 2.9, still in the pinned 2.13): opset
            # 17, no onnxscript, quiet; the torch.export one needs onnxscript and opset >= 18
            dynamo=False,
            opset_version=OPSET,
            input_names=["frames"],
            output_names=["gradients"],
            dynamic_axes={"frames": {0: "batch"}, "gradients": {0: "batch"}},
        )
    except Exception as exc:  # an operator ONNX lacks: say which preset
        staging.unlink(missing_ok=True)
        raise ConfigError(
            f"preset {estimator.preset!r} cannot be exported to ONNX opset {OPSET}: {exc}"
        ) from None
    staging.replace(path)
    record = sidecar(estimator, path, source)
    sidecar_path(path).write_text(json.dumps(record, indent=2) + "\n")
    return record


def sidecar_path(path: str | Path) -> Path:
    path = Path(path)
    return path.with_name(path.name + ".json")


def sidecar(estimator, path: Path, source: str | Path | None) -> dict:
    """What a consumer of the graph needs beside it (units: mm and pixels of the model's frame)."""
    geometry = estimator.geometry
    registration = geometry.registration
    return {
        "format": SIDECAR_FORMAT,
        "format_version": SIDECAR_VERSION,
        "onnx": path.name,
        "onnx_opset": OPSET,
        "input": {
            "name": "frames",
            "shape": ["batch", *estimator.image_shape, 3],
            "dtype": "uint8",
            "meaning": "RGB frames of the model's frame: the camera's, rectified through "
            "camera.lens and average-pooled by camera.downscale",
        },
        "output": {
            "name": "gradients",
            "shape": ["batch", *estimator.image_shape, 2],
            "dtype": "float32",
            "meaning": "dz/dx (along columns) and dz/dy (along rows) per pixel, z in mm into the "
            "gel, x and y in mm",
        },
        "baked_in": [
            "the blank frame (re-export with --blank to change it)",
            "(frame - blank) / 255",
            f"lighting drift: per-channel median of every {STRIDE}th pixel subtracted"
            if estimator.drift == "median"
            else "no lighting drift removal",
            "coordinate channels x, y in [-1, 1] over the frame"
            if estimator.normalisation.get("coords", "unit") == "unit"
            else "coordinate channels 1..W, 1..H (the authors' TouchNet)",
            "the gradients' sign (z into the gel)",
        ],
        "preset": estimator.preset,
        "image_shape": list(estimator.image_shape),
        "px_per_mm": estimator.px_per_mm,
        "depth": {
            "method": "poisson_dst",
            "boundary": "depth 0 on the outermost ring of pixels",
            "px_per_mm": estimator.px_per_mm,
            "python": "threedcal.depth.integrate(g[..., 0], g[..., 1], px_per_mm=px_per_mm)",
        },
        "camera": {
            "lens": None if estimator.lens is None else estimator.lens.record(),
            "downscale": geometry.downscale,
        },
        "registration": None if registration is None else registration.record(),
        "contact_z_mm": None if registration is None else registration.contact_z_mm,
        "dome": None if not geometry.dome else dict(geometry.dome),
        "frames": {
            "sensor": "origin under the centre pixel ((W-1)/2, (H-1)/2); x right, y down the "
            "image, z into the gel; z = the dome's sag below its apex + depth",
            "printer": "G-code X, Y from the inverse of registration.affine_px_per_mm applied to "
            "camera pixels ((c + 0.5) * downscale - 0.5); Z = contact_z_mm - sensor z",
        },
        "checkpoint": None
        if source is None
        else {"name": Path(source).name, "sha256": _sha256(Path(source))},
    }


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def onnx_session(path: str | Path, threads: int | None = None, spin: bool = True):
    """An onnxruntime session on the CPU (the `export` extra), `threads` intra-op threads.

    `spin`: idle workers spin for a while before sleeping (onnxruntime's default: the fastest
    alone, 93 against 72 frames/s for `multiscale` here); False when other work shares the cores
    right after each run (a spinning worker took torch from 150 to 7 frames/s in one process)."""
    try:
        import onnxruntime  # optional (export extra), named below when missing
    except ImportError:
        raise ConfigError("onnxruntime is not installed: pip install 'threedcal[export]'") from None
    options = onnxruntime.SessionOptions()
    options.add_session_config_entry("session.intra_op.allow_spinning", "1" if spin else "0")
    if threads:
        options.intra_op_num_threads = int(threads)
        options.inter_op_num_threads = 1
    return onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def onnx_gradients(session, frames: np.ndarray) -> np.ndarray:
    """Run an exported graph on uint8 frames (N, H, W, 3) → (N, H, W, 2) float32."""
    return session.run(["gradients"], {"frames": np.ascontiguousarray(frames, np.uint8)})[0]
