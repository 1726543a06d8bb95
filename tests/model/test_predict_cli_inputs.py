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
    return main(
        ["predict", "--checkpoint", model, "--image", image, "--out", out, "--device", "cpu", *extra]
    )


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
