"""`threedcal predict` (one image → depth, points), `threedcal live` (a stream → depth video,
frames/s, points; the blank re-taken on request) and `threedcal export`: their options (what they
do is in threedcal.cli.handlers.model)."""

from __future__ import annotations

import argparse

from threedcal.cli import Command, add_force_option
from threedcal.model import BACKGROUND_DRIFT_WARN_DN, CONTACT_DEPTH_MM, POINT_FRAMES


def _estimator_args(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("checkpoint options")
    group.add_argument(
        "--checkpoint", required=True, help="model.pt (or the authors' TouchNet .pth)"
    )
    group.add_argument("--blank", help="blank (no-contact) image; needed for the authors' weights")
    group.add_argument("--px-per-mm", type=float, help="needed for the authors' weights")
    group.add_argument("--device", help="cpu, cuda, ... (default: CUDA when present)")
    group.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    group.add_argument(
        "--registration",
        help="registration.json for --frame-of printer, where the checkpoint carries none",
    )


def _points_args(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--points", help=what)
    group = parser.add_argument_group("point options")
    group.add_argument(
        "--frame-of",
        choices=POINT_FRAMES,
        default="sensor",
        help="sensor (gel plane; x right, y down the image, z into the gel) or printer (G-code "
        "axes)",
    )
    group.add_argument(
        "--contact-mm",
        type=float,
        default=CONTACT_DEPTH_MM,
        help="depth (mm) above which a point is in contact",
    )


def _configure_predict(parser: argparse.ArgumentParser) -> None:
    _estimator_args(parser)
    parser.add_argument("--image", required=True, help="sensor image (PNG, RGB)")
    parser.add_argument("--out", required=True, help="depth map in mm, .npy")
    parser.add_argument("--png", help="colour map PNG (default: --out with .png)")
    _points_args(parser, "also write the depth as 3D points (mm) to this .ply")
    add_force_option(parser)


def _configure_live(parser: argparse.ArgumentParser) -> None:
    _estimator_args(parser)
    parser.add_argument(
        "--source",
        required=True,
        help="camera index (0) or device (/dev/video0; needs --sensor), video file, folder of "
        "images, or results/{scene}/dataset/trainset",
    )
    parser.add_argument(
        "--sensor",
        help="sensor profile (name or YAML) that crops, turns and sizes the camera's frames, as "
        "at collection",
    )
    parser.add_argument("--frames", type=int, default=0, help="stop after this many (0: all)")
    parser.add_argument("--out", help="write frame | depth side by side to a .gif or .mp4")
    parser.add_argument("--video-fps", type=float, default=10.0, help="playback rate of --out")
    add_force_option(parser)
    parser.add_argument("--max-depth-mm", type=float, default=None, help="colour scale top")
    parser.add_argument(
        "--show",
        action="store_true",
        help="show a window (needs a display); q quits, b re-takes the blank",
    )
    _points_args(parser, "write each frame's 3D points (mm) to FOLDER/frame_NNNNNN.ply")
    parser.add_argument(
        "--drift-warn-dn",
        type=float,
        default=BACKGROUND_DRIFT_WARN_DN,
        help="warn when the no-contact region drifts this far from the blank (RMS grey levels)",
    )
    parser.add_argument(
        "--probe-radius-mm",
        type=float,
        default=None,
        help="the pressing ball's radius: warn of a contact larger than it can make",
    )


def _configure_export(parser: argparse.ArgumentParser) -> None:
    _estimator_args(parser)
    parser.add_argument("--out", required=True, help="model.onnx; its sidecar is model.onnx.json")
    add_force_option(parser)


COMMANDS = [
    Command(
        ("predict",),
        "depth map (mm, .npy + PNG) of one sensor image",
        "model:run_predict",
        _configure_predict,
    ),
    Command(
        ("live",),
        "depth of a camera or image stream, with frames/s",
        "model:run_live",
        _configure_live,
    ),
    Command(
        ("export",),
        "a checkpoint as ONNX (frames -> gradients) with a JSON sidecar of its geometry",
        "model:run_export",
        _configure_export,
    ),
]
