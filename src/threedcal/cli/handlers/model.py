"""`threedcal predict` (one image → depth, points), `threedcal live` (a stream → depth video,
frames/s, points; the blank re-taken on request) and `threedcal export` (a checkpoint as ONNX)."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from PIL import Image
from tqdm import tqdm

from threedcal.cli import refuse_existing_outputs, refuse_file_on_path
from threedcal.errors import ConfigError, FrameSizeError
from threedcal.images import read_rgb
from threedcal.model.contact_guard import contact_figures, oversized_message
from threedcal.model.drift import background_drift_dn
from threedcal.model.export import OPSET, export_onnx, sidecar_path
from threedcal.model.inference import DepthEstimator
from threedcal.model.points import write_ply
from threedcal.model.sources import is_camera, open_source
from threedcal.profiles import load_profile


def _estimator(args: argparse.Namespace):
    if args.threads is not None and args.threads < 1:
        raise ConfigError(f"--threads must be a whole number >= 1, got {args.threads}")
    if args.px_per_mm is not None and not args.px_per_mm > 0:
        raise ConfigError(f"--px-per-mm must be a number > 0, got {args.px_per_mm}")
    contact_mm = getattr(args, "contact_mm", 0.0)
    if not (contact_mm >= 0 and contact_mm < float("inf")):
        raise ConfigError(f"--contact-mm must be a number >= 0, got {contact_mm}")

    if args.threads:
        torch.set_num_threads(args.threads)
    blank = read_rgb(Path(args.blank)) if args.blank else None
    try:
        return DepthEstimator.from_checkpoint(
            args.checkpoint,
            device=args.device,
            blank=blank,
            px_per_mm=args.px_per_mm,
            camera_blank=True,  # the user's blank comes from the camera, like the frames
            registration=args.registration,
        )
    except FrameSizeError as exc:  # only the user's blank is pooled here
        raise ConfigError(f"{args.blank} (--blank): {exc}") from None


def _model_frames(estimator, frames, where: str):
    """`estimator.rectify(frames)`; a frame the model cannot take is an error naming `where`."""
    try:
        return estimator.rectify(frames)
    except FrameSizeError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def colour_map(depth_mm, vmax: float | None = None):
    """uint8 RGB image of a depth map (viridis, OpenCV's table; 0 mm dark, vmax bright; NaN dark)."""
    top = vmax or max(float(np.nanpercentile(depth_mm, 99.5)), 1e-6)
    levels = np.nan_to_num(np.clip(np.asarray(depth_mm, np.float64) / top, 0.0, 1.0), nan=0.0)
    bgr = cv2.applyColorMap(np.round(levels * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def run_predict(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.suffix.lower() != ".npy":
        raise ConfigError(f"--out {out}: the depth map is a NumPy file: give a path ending in .npy")
    png = Path(args.png) if args.png else out.with_suffix(".png")
    png_option = "--png" if args.png else "the colour map (--out with .png)"
    if not cv2.haveImageWriter(str(png)):
        raise ConfigError(f"{png_option} {png}: not an image type OpenCV writes (use .png)")
    outputs = {"--out": out, png_option: png}
    if args.points:
        if Path(args.points).suffix.lower() != ".ply":
            raise ConfigError(
                f"--points {args.points}: the point cloud is a PLY file: end it in .ply"
            )
        outputs["--points"] = Path(args.points)
    _refuse_overwriting_inputs(
        outputs,
        {
            "--image": args.image,
            "--blank": args.blank,
            "--checkpoint": args.checkpoint,
            "--registration": args.registration,
        },
    )
    refuse_existing_outputs(outputs, args.force)
    estimator = _estimator(args)
    if args.points:
        estimator.geometry.check_frame(args.frame_of)  # before any output is written
    depth = estimator.depth(_model_frames(estimator, read_rgb(Path(args.image)), args.image))
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("wb") as fh:  # np.save(path) would add .npy to a name ending in .NPY
        np.save(fh, depth)
    if not cv2.imwrite(str(png), cv2.cvtColor(colour_map(depth), cv2.COLOR_RGB2BGR)):
        raise ConfigError(f"{png_option} {png}: OpenCV could not write the colour map")
    print(f"{out}: depth {depth.shape} mm, max {float(depth.max()):.3f} mm; colour map {png}")
    if args.points:
        cloud = estimator.points_of_depth(depth, args.frame_of, args.contact_mm)
        write_ply(args.points, cloud)
        print(
            f"{args.points}: {len(cloud.points)} points ({args.frame_of} frame, mm), "
            f"{int(cloud.contact.sum())} in contact"
        )
    return 0


def _refuse_overwriting_inputs(outputs: dict[str, Path], inputs: dict[str, str | None]) -> None:
    """Checked before anything runs: no output is a folder or one of the command's input files
    (`predict --image x.png --out x.npy` would otherwise replace the image with its colour map)."""
    for out_option, path in outputs.items():
        if path.is_dir():
            raise ConfigError(f"{out_option} {path}: is a folder; give a file name")
        refuse_file_on_path(out_option, path, path.parent)
        for in_option, given in inputs.items():
            if given and path.exists() and Path(given).exists() and path.samefile(given):
                raise ConfigError(
                    f"{out_option} {path}: is the {in_option} file; writing there would overwrite "
                    f"it: choose another {out_option if out_option.startswith('--') else '--png'}"
                )


def run_live(args: argparse.Namespace) -> int:
    _check_live_args(args)
    estimator = _estimator(args)
    if args.points:
        estimator.geometry.check_frame(args.frame_of)
    source = open_source(args.source, _live_sensor(args))
    frames_out, times = [], []
    retake = _BlankRequest()
    warned = oversized = False
    print(f"live: press b in the window, or kill -USR1 {os.getpid()}, to re-take the blank")
    with retake.on_signal():
        for count, frame in enumerate(tqdm(source, desc="live", unit="frame", total=args.frames)):
            if args.frames and count >= args.frames:
                break
            began = time.perf_counter()
            model_frame = _model_frames(
                estimator, frame, f"live source {args.source}, frame {count}"
            )
            if retake.pending:
                estimator.retake_blank(frame)
                retake.pending, warned = False, False
                tqdm.write(f"live: frame {count} is the blank from now on")
            depth = estimator.depth(model_frame)
            times.append(time.perf_counter() - began)
            drift = background_drift_dn(model_frame, estimator.blank, depth > args.contact_mm)
            if drift > args.drift_warn_dn and not warned:
                tqdm.write(
                    f"live: warning: frame {count}: the no-contact region has drifted {drift:.1f} "
                    f"grey levels (RMS) from the blank (> --drift-warn-dn {args.drift_warn_dn:g}): "
                    "depth there may read as contact; with nothing touching the gel, press b or "
                    "send SIGUSR1 to re-take the blank"
                )
            warned = drift > args.drift_warn_dn  # warned again only after it settled
            if args.probe_radius_mm:
                message = _oversized(estimator, depth, args)
                if message and not oversized:
                    tqdm.write(f"live: warning: frame {count}: {message}")
                oversized = bool(message)  # warned again only after it came back within
            if args.points:
                cloud = estimator.points_of_depth(depth, args.frame_of, args.contact_mm)
                write_ply(Path(args.points) / f"frame_{count:06d}.ply", cloud)
            view = _live_view(model_frame, depth, len(times) / sum(times), drift, warned, args)
            if args.out:
                frames_out.append(view)
            if args.show:
                cv2.imshow("threedcal live", cv2.cvtColor(view, cv2.COLOR_RGB2BGR))
                key = cv2.waitKey(1) & 0xFF
                if key == ord("q"):
                    break
                if key == ord("b"):
                    retake.pending = True
    return _live_done(args, estimator, times, frames_out)


def _check_live_args(args: argparse.Namespace) -> None:
    """Everything `live` can refuse, before the model is loaded or any output written."""
    if args.frames < 0:
        raise ConfigError(f"--frames must be >= 0 (0: all), got {args.frames}")
    if not args.drift_warn_dn > 0:
        raise ConfigError(f"--drift-warn-dn must be a number > 0, got {args.drift_warn_dn}")
    radius = args.probe_radius_mm
    if radius is not None and not (np.isfinite(radius) and radius > 0):
        raise ConfigError(f"--probe-radius-mm must be a number > 0 (mm), got {radius}")
    inputs = {"--source": args.source, "--blank": args.blank, "--checkpoint": args.checkpoint}
    if args.out:
        if not (args.video_fps > 0 and np.isfinite(args.video_fps)):
            raise ConfigError(f"--video-fps must be a number > 0, got {args.video_fps}")
        if Path(args.out).suffix.lower() not in VIDEO_SUFFIXES:
            raise ConfigError(
                f"--out {args.out}: give a {' or '.join(VIDEO_SUFFIXES)} file (the video is "
                "written after the last frame)"
            )
        _refuse_overwriting_inputs({"--out": Path(args.out)}, inputs)
        refuse_existing_outputs({"--out": Path(args.out)}, args.force)
    if args.points:
        _refuse_points_folder(Path(args.points), args.force)

    if is_camera(args.source) and not args.sensor:
        raise ConfigError(
            f"--source {args.source} is a camera: give --sensor (the sensor profile says how its "
            "frames are cropped, turned and sized, as at collection)"
        )


def _oversized(estimator, depth, args: argparse.Namespace) -> str | None:
    """The warning for a frame whose contact covers more than the stated probe can touch."""
    figures = contact_figures(depth, args.probe_radius_mm, estimator.px_per_mm, args.contact_mm)
    unit = f"sensor {args.sensor}" if args.sensor else f"--source {args.source}"
    return oversized_message(f"{unit} with {args.checkpoint}", figures, args.probe_radius_mm)


def _live_sensor(args: argparse.Namespace):
    """--sensor's profile (a camera's frames are converted by it), or None."""
    if not args.sensor:
        return None
    sensor = load_profile("sensor", args.sensor)
    if sensor.get("type") != "vision":
        raise ConfigError(
            f"--sensor {args.sensor}: not a camera sensor (type {sensor.get('type')})"
        )
    return sensor


def _live_view(model_frame, depth, fps: float, drift: float, warned: bool, args):
    """Frame | depth side by side, frames/s and the background's drift written on it."""
    view = np.concatenate([model_frame, colour_map(depth, args.max_depth_mm)], axis=1)
    white, red = (255, 255, 255), (255, 64, 64)
    cv2.putText(view, f"{fps:5.1f} fps", (5, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, white, 1)
    label = f"drift {drift:.1f}" + (": b = new blank" if warned else "")
    colour = red if warned else white
    cv2.putText(view, label, (5, 36), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1)
    return view


def _live_done(args: argparse.Namespace, estimator, times, frames_out) -> int:
    if not times:
        print("no frames")
        return 1
    print(
        f"{len(times)} frames, depth at {len(times) / sum(times):.1f} frames/s ({estimator.preset}, "
        f"{estimator.describe_runtime()})"
    )
    if args.points:
        print(f"wrote {len(times)} point clouds ({args.frame_of} frame) to {args.points}")
    if args.out:
        _write_video(Path(args.out), frames_out, args.video_fps)
        print(f"wrote {args.out}")
    return 0


class _BlankRequest:
    """Set when the user asks `live` to re-take the blank: the window's b key, or SIGUSR1 (the
    headless way: `kill -USR1 PID`, where the platform has the signal)."""

    def __init__(self) -> None:
        self.pending = False

    @contextlib.contextmanager
    def on_signal(self):
        number = getattr(signal, "SIGUSR1", None)
        if number is None:  # Windows
            yield
            return
        before = signal.signal(number, lambda *_: setattr(self, "pending", True))
        try:
            yield
        finally:
            signal.signal(number, before)


def _refuse_points_folder(folder: Path, force: bool) -> None:
    """`live --points DIR`: a folder (made when missing) without earlier point clouds, unless
    --force; checked before anything runs."""
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"--points {folder}: is a file; give a folder for the .ply files")
    refuse_file_on_path("--points", folder, folder.parent)
    earlier = sorted(folder.glob("frame_*.ply")) if folder.is_dir() else []
    if earlier and not force:
        raise ConfigError(
            f"--points {folder}: holds {len(earlier)} point clouds of an earlier run "
            f"({earlier[0].name}, ...); refusing to overwrite them (choose another folder, or add "
            "--force to replace them)"
        )


def run_export(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.suffix.lower() != ".onnx":
        raise ConfigError(f"--out {out}: the model is an ONNX file: end it in .onnx")
    outputs = {"--out": out, "the sidecar (--out + .json)": sidecar_path(out)}
    _refuse_overwriting_inputs(
        outputs,
        {
            "--checkpoint": args.checkpoint,
            "--blank": args.blank,
            "--registration": args.registration,
        },
    )
    refuse_existing_outputs(outputs, args.force)
    try:
        import onnx  # noqa: F401  # local: the export extra, sought at export
    except ImportError:
        raise ConfigError(
            "export needs the onnx package: pip install 'threedcal[export]'"
        ) from None
    estimator = _estimator(args)
    record = export_onnx(estimator, out, args.checkpoint)
    height, width = estimator.image_shape
    print(
        f"{out}: ONNX opset {OPSET}, frames (N, {height}, {width}, 3) uint8 -> gradients "
        f"(N, {height}, {width}, 2); {sidecar_path(out)}: px/mm {record['px_per_mm']:.4g}, "
        f"touch height {record['contact_z_mm']} mm"
    )
    return 0


VIDEO_SUFFIXES = (".gif", ".mp4")


def _write_video(path: Path, frames, fps: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        images = [Image.fromarray(f) for f in frames]
        images[0].save(
            path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0
        )
        return

    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    if not writer.isOpened():
        raise ConfigError(f"--out {path}: OpenCV could not open an MP4 video for writing")
    for frame in frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()
