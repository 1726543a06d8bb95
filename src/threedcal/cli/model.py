"""`threedcal predict` (one image → depth) and `threedcal live` (a stream → depth video + frames/s)."""

from __future__ import annotations

import argparse
from pathlib import Path

from threedcal.cli import Command, add_force_option, refuse_existing_outputs, refuse_file_on_path
from threedcal.errors import ConfigError, FrameSizeError


def _estimator_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--checkpoint", required=True, help="model.pt (or the authors' TouchNet .pth)"
    )
    parser.add_argument("--blank", help="blank (no-contact) image; needed for the authors' weights")
    parser.add_argument("--px-per-mm", type=float, help="needed for the authors' weights")
    parser.add_argument("--device", help="cpu, cuda, ... (default: CUDA when present)")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")


def _estimator(args: argparse.Namespace):
    if args.threads is not None and args.threads < 1:
        raise ConfigError(f"--threads must be a whole number >= 1, got {args.threads}")
    if args.px_per_mm is not None and not args.px_per_mm > 0:
        raise ConfigError(f"--px-per-mm must be a number > 0, got {args.px_per_mm}")
    import torch

    from threedcal.dataset.importers import read_rgb
    from threedcal.model.inference import DepthEstimator

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
    """uint8 RGB image of a depth map (viridis; 0 mm dark, vmax bright)."""
    import matplotlib
    import numpy as np

    top = vmax or max(float(np.percentile(depth_mm, 99.5)), 1e-6)
    rgba = matplotlib.colormaps["viridis"](np.clip(depth_mm / top, 0.0, 1.0))
    return (rgba[..., :3] * 255).astype(np.uint8)


def _predict(args: argparse.Namespace) -> int:
    import cv2
    import numpy as np

    from threedcal.dataset.importers import read_rgb

    out = Path(args.out)
    if out.suffix.lower() != ".npy":
        raise ConfigError(f"--out {out}: the depth map is a NumPy file: give a path ending in .npy")
    png = Path(args.png) if args.png else out.with_suffix(".png")
    png_option = "--png" if args.png else "the colour map (--out with .png)"
    if not cv2.haveImageWriter(str(png)):
        raise ConfigError(f"{png_option} {png}: not an image type OpenCV writes (use .png)")
    outputs = {"--out": out, png_option: png}
    _refuse_overwriting_inputs(
        outputs, {"--image": args.image, "--blank": args.blank, "--checkpoint": args.checkpoint}
    )
    refuse_existing_outputs(outputs, args.force)
    estimator = _estimator(args)
    depth = estimator.depth(_model_frames(estimator, read_rgb(Path(args.image)), args.image))
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("wb") as fh:  # np.save(path) would add .npy to a name ending in .NPY
        np.save(fh, depth)
    if not cv2.imwrite(str(png), cv2.cvtColor(colour_map(depth), cv2.COLOR_RGB2BGR)):
        raise ConfigError(f"{png_option} {png}: OpenCV could not write the colour map")
    print(f"{out}: depth {depth.shape} mm, max {float(depth.max()):.3f} mm; colour map {png}")
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


def _live(args: argparse.Namespace) -> int:
    import time

    import cv2
    import numpy as np
    from tqdm import tqdm

    from threedcal.model.sources import open_source

    if args.frames < 0:
        raise ConfigError(f"--frames must be >= 0 (0: all), got {args.frames}")
    if args.out:
        if not (args.video_fps > 0 and np.isfinite(args.video_fps)):
            raise ConfigError(f"--video-fps must be a number > 0, got {args.video_fps}")
        if Path(args.out).suffix.lower() not in VIDEO_SUFFIXES:
            raise ConfigError(
                f"--out {args.out}: give a {' or '.join(VIDEO_SUFFIXES)} file (the video is "
                "written after the last frame)"
            )
        _refuse_overwriting_inputs(
            {"--out": Path(args.out)},
            {"--source": args.source, "--blank": args.blank, "--checkpoint": args.checkpoint},
        )
        refuse_existing_outputs({"--out": Path(args.out)}, args.force)
    estimator = _estimator(args)
    frames_out, times = [], []
    source = open_source(args.source)
    for count, frame in enumerate(tqdm(source, desc="live", unit="frame", total=args.frames)):
        if args.frames and count >= args.frames:
            break
        began = time.perf_counter()
        model_frame = _model_frames(estimator, frame, f"live source {args.source}, frame {count}")
        depth = estimator.depth(model_frame)
        times.append(time.perf_counter() - began)
        fps = len(times) / sum(times)
        view = np.concatenate([model_frame, colour_map(depth, args.max_depth_mm)], axis=1)
        cv2.putText(
            view, f"{fps:5.1f} fps", (5, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1
        )
        if args.out:
            frames_out.append(view)
        if args.show:
            cv2.imshow("threedcal live", cv2.cvtColor(view, cv2.COLOR_RGB2BGR))
            if cv2.waitKey(1) & 0xFF == ord("q"):
                break
    if not times:
        print("no frames")
        return 1
    print(
        f"{len(times)} frames, depth at {len(times) / sum(times):.1f} frames/s ({estimator.preset})"
    )
    if args.out:
        _write_video(Path(args.out), frames_out, args.video_fps)
        print(f"wrote {args.out}")
    return 0


VIDEO_SUFFIXES = (".gif", ".mp4")


def _write_video(path: Path, frames, fps: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        from PIL import Image

        images = [Image.fromarray(f) for f in frames]
        images[0].save(
            path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0
        )
        return
    import cv2

    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    if not writer.isOpened():
        raise ConfigError(f"--out {path}: OpenCV could not open an MP4 video for writing")
    for frame in frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()


def _configure_predict(parser: argparse.ArgumentParser) -> None:
    _estimator_args(parser)
    parser.add_argument("--image", required=True, help="sensor image (PNG, RGB)")
    parser.add_argument("--out", required=True, help="depth map in mm, .npy")
    parser.add_argument("--png", help="colour map PNG (default: --out with .png)")
    add_force_option(parser)


def _configure_live(parser: argparse.ArgumentParser) -> None:
    _estimator_args(parser)
    parser.add_argument(
        "--source",
        required=True,
        help="camera index (0), folder of images, video file, or results/{scene}/dataset/trainset",
    )
    parser.add_argument("--frames", type=int, default=0, help="stop after this many (0: all)")
    parser.add_argument("--out", help="write frame | depth side by side to a .gif or .mp4")
    parser.add_argument("--video-fps", type=float, default=10.0, help="playback rate of --out")
    add_force_option(parser)
    parser.add_argument("--max-depth-mm", type=float, default=None, help="colour scale top")
    parser.add_argument("--show", action="store_true", help="show a window (needs a display)")


COMMANDS = [
    Command(
        ("predict",), "depth map (mm, .npy + PNG) of one sensor image", _predict, _configure_predict
    ),
    Command(("live",), "depth of a camera or image stream, with frames/s", _live, _configure_live),
]
