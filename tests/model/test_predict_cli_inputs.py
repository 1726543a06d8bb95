"""`threedcal predict` and `threedcal live` with a user's bad input: one clear line naming the file
or option, before anything is written, and never a traceback or an input overwritten."""

import cv2
import numpy as np
import pytest
import torch

from threedcal.cli import main
from threedcal.model.checkpoint import FORMAT, FORMAT_VERSION, OUR_NORMALISATION, save_checkpoint
from threedcal.model.presets import build_model

SHAPE = (40, 48)


def write_rgb(path, shape, value=100):
    cv2.imwrite(str(path), np.full((*shape, 3), value, np.uint8))
    return str(path)


@pytest.fixture
def model(tmp_path):
    """An untrained compact_tiny model for 40 x 48 px frames (inference only: milliseconds)."""
    torch.manual_seed(0)
    path = tmp_path / "model.pt"
    save_checkpoint(
        path,
        {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "preset": "compact_tiny",
            "preset_args": {},
            "state_dict": build_model("compact_tiny").state_dict(),
            "normalisation": dict(OUR_NORMALISATION),
            "blank": torch.full((*SHAPE, 3), 100.0),
            "px_per_mm": 8.0,
            "image_shape": list(SHAPE),
        },
    )
    return str(path)


def predict(model, image, out, *extra):
    args = ["--checkpoint", model, "--image", image, "--out", out, "--device", "cpu"]
    return main(["predict", *args, *extra])


@pytest.mark.parametrize("shape", [(30, 30), (48, 40), (80, 60)])
def test_an_image_of_another_size_names_the_file_and_both_sizes(tmp_path, capsys, model, shape):
    """Repro: an image that is not the model's frame size (or a whole multiple of it) gave
    cv2.error `!ssize.empty()` from deep inside OpenCV; a 48 x 40 (turned) or 80 x 60 frame was
    silently squashed or gave the same error."""
    image = write_rgb(tmp_path / "frame.png", shape)
    assert predict(model, image, str(tmp_path / "d.npy")) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"threedcal: error: {image}: a {shape[0]} x {shape[1]} px frame")
    assert "the model's 40 x 48 px frames" in err and "Traceback" not in err
    assert not (tmp_path / "d.npy").exists()


def test_an_image_twice_the_model_frame_is_pooled_to_it(tmp_path, model):
    image = write_rgb(tmp_path / "frame.png", (80, 96))
    assert predict(model, image, str(tmp_path / "d.npy")) == 0
    assert np.load(tmp_path / "d.npy").shape == SHAPE


def test_a_blank_of_another_size_names_the_blank(tmp_path, capsys, model):
    image = write_rgb(tmp_path / "frame.png", SHAPE)
    blank = write_rgb(tmp_path / "blank.png", (30, 30))
    assert predict(model, image, str(tmp_path / "d.npy"), "--blank", blank) == 1
    err = capsys.readouterr().err
    assert f"{blank} (--blank): a 30 x 30 px frame" in err and "Traceback" not in err


def test_live_names_the_source_of_a_frame_of_another_size(tmp_path, capsys, model):
    (tmp_path / "frames").mkdir()
    write_rgb(tmp_path / "frames" / "0000.png", (30, 30))
    args = ["live", "--checkpoint", model, "--source", str(tmp_path / "frames"), "--device", "cpu"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert f"live source {tmp_path / 'frames'}, frame 0: a 30 x 30 px frame" in err


def test_predict_never_overwrites_its_input_image_with_the_colour_map(tmp_path, capsys, model):
    """Repro: `predict --image x.png --out x.npy` wrote the colour map over x.png (the default
    --png is --out with .png): the user's sensor image was lost."""
    image = write_rgb(tmp_path / "x.png", SHAPE, value=123)
    before = (tmp_path / "x.png").read_bytes()
    assert predict(model, image, str(tmp_path / "x.npy")) == 1
    err = capsys.readouterr().err
    assert f"the colour map (--out with .png) {image}: is the --image file" in err
    assert "choose another --png" in err
    assert (tmp_path / "x.png").read_bytes() == before and not (tmp_path / "x.npy").exists()
    assert predict(model, image, str(tmp_path / "d.npy"), "--png", image) == 1
    assert f"--png {image}: is the --image file" in capsys.readouterr().err
    assert (tmp_path / "x.png").read_bytes() == before
    # with another --png it runs
    assert predict(model, image, str(tmp_path / "x.npy"), "--png", str(tmp_path / "xd.png")) == 0
    assert (tmp_path / "x.png").read_bytes() == before and (tmp_path / "xd.png").is_file()


@pytest.mark.parametrize(
    ("out", "png", "message"),
    [
        ("d.txt", None, "--out {tmp}/d.txt: the depth map is a NumPy file: give a path ending"),
        ("d.npy", "d.foo", "--png {tmp}/d.foo: not an image type OpenCV writes (use .png)"),
        ("sub.npy", None, "--out {tmp}/sub.npy: is a folder; give a file name"),
    ],
)
def test_predict_checks_its_output_paths_before_running(tmp_path, capsys, model, out, png, message):
    """Repro: --out d.txt wrote d.txt.npy but printed d.txt; --png d.foo raised cv2.error after
    the depth map was written; an --out folder named *.npy gave IsADirectoryError."""
    (tmp_path / "sub.npy").mkdir()
    image = write_rgb(tmp_path / "frame.png", SHAPE)
    extra = ["--png", str(tmp_path / png)] if png else []
    assert predict(model, image, str(tmp_path / out), *extra) == 1
    err = capsys.readouterr().err
    assert message.format(tmp=tmp_path) in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame.png", "model.pt", "sub.npy"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--out", "v.gif", "--video-fps", "0"], "--video-fps must be a number > 0, got 0.0"),
        (["--out", "v.avi"], "--out v.avi: give a .gif or .mp4 file"),
        (["--out", "frames/0000.png"], "--out frames/0000.png: give a .gif or .mp4 file"),
        (["--threads", "-1"], "--threads must be a whole number >= 1, got -1"),
        (["--frames", "-2"], "--frames must be >= 0 (0: all), got -2"),
        (["--px-per-mm", "-3"], "--px-per-mm must be a number > 0, got -3.0"),
    ],
)
def test_live_checks_its_options_before_the_first_frame(
    tmp_path, monkeypatch, capsys, model, extra, message
):
    """Repro: --video-fps 0 raised ZeroDivisionError after every frame was processed; --out v.avi
    printed `wrote v.avi` and wrote nothing; --threads -1 raised torch's RuntimeError; --frames -2
    ran nothing and said only `no frames`; --px-per-mm -3 said the checkpoint had no px_per_mm."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "frames").mkdir()
    write_rgb(tmp_path / "frames" / "0000.png", SHAPE)
    args = ["live", "--checkpoint", model, "--source", "frames", "--device", "cpu", *extra]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"threedcal: error: {message}") and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames", "model.pt"]


def test_live_never_writes_its_video_over_the_source_video(tmp_path, capsys, model):
    video = tmp_path / "press.mp4"
    video.write_bytes(b"a recorded press")
    args = ["live", "--checkpoint", model, "--source", str(video), "--out", str(video)]
    assert main(args) == 1
    assert f"--out {video}: is the --source file" in capsys.readouterr().err
    assert video.read_bytes() == b"a recorded press"


def test_predict_never_replaces_an_earlier_result_without_force(tmp_path, capsys, model):
    """Repro: a second `predict --out depth.npy` (another image, another model) replaced the first
    depth map and its colour map without a word."""
    image = write_rgb(tmp_path / "frame.png", SHAPE)
    out = tmp_path / "depth.npy"
    assert predict(model, image, str(out)) == 0
    first = out.read_bytes()
    out.with_suffix(".png").write_bytes(b"kept")  # the colour map alone is guarded too
    out.unlink()
    assert predict(model, image, str(out)) == 1
    err = capsys.readouterr().err
    assert "depth.png: already exists; refusing to overwrite it" in err and "--force" in err
    assert not out.exists() and out.with_suffix(".png").read_bytes() == b"kept"
    assert predict(model, image, str(out), "--force") == 0
    assert out.read_bytes() == first and out.with_suffix(".png").read_bytes() != b"kept"


def test_live_never_replaces_an_earlier_video_without_force(tmp_path, capsys, model):
    video = tmp_path / "live.gif"
    video.write_bytes(b"an earlier run")
    folder = tmp_path / "frames"
    folder.mkdir()
    write_rgb(folder / "0.png", SHAPE)
    args = ["live", "--checkpoint", model, "--source", str(folder), "--out", str(video)]
    assert main([*args, "--device", "cpu"]) == 1
    assert "live.gif: already exists" in capsys.readouterr().err
    assert video.read_bytes() == b"an earlier run"
    assert main([*args, "--device", "cpu", "--force"]) == 0
    assert video.read_bytes() != b"an earlier run"


def test_predict_writes_the_depth_map_under_the_name_given_even_in_capitals(
    tmp_path, capsys, model
):
    """Repro: `--out depth.NPY` wrote depth.NPY.npy (np.save appends .npy unless the name ends in
    lowercase .npy), so the overwrite guard checked a file that was never written and a second run
    replaced depth.NPY.npy without --force."""
    image = write_rgb(tmp_path / "frame.png", SHAPE)
    out = tmp_path / "depth.NPY"
    assert predict(model, image, str(out)) == 0
    assert out.is_file() and not (tmp_path / "depth.NPY.npy").exists()
    assert np.load(out).shape == SHAPE
    first = out.read_bytes()
    assert predict(model, image, str(out)) == 1
    assert "depth.NPY: already exists" in capsys.readouterr().err
    assert out.read_bytes() == first
