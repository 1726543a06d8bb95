"""`threedcal export`: the ONNX graph matches DepthEstimator.gradients on real frames, its sidecar
carries the geometry, and bad input is refused before anything is written."""

import json

import numpy as np
import onnx
import pytest
import torch
from conftest import DATA, write_untrained_model
from PIL import Image

from threedcal.cli import main
from threedcal.depth import integrate
from threedcal.images import read_rgb
from threedcal.model.checkpoint import (
    AUTHORS_NORMALISATION,
    OUR_NORMALISATION,
)
from threedcal.model.export import OPSET, export_onnx, onnx_gradients, onnx_session
from threedcal.model.inference import DepthEstimator
from threedcal.model.presets import build_model

REGISTRATION = {
    "affine_px_per_mm": [[19.5, 0.4, -2250.0], [0.4, -19.5, 2457.0]],
    "contact_z_mm": 134.96,
}
DOME = {"kx_per_mm": 0.013, "ky_per_mm": 0.0043}


@pytest.fixture(scope="module")
def real_frames():
    """Real DIGIT frames (data/digit_frames_fots, 320 x 240) and their no-contact frame."""
    folder = DATA / "digit_frames_fots"
    frames = np.stack([read_rgb(folder / n) for n in ["0003.png", "0010.png", "0021.png"]])
    return frames, read_rgb(folder / "background.png")


def write_model(path, preset, blank, normalisation=OUR_NORMALISATION):
    """A freshly initialised model (seeded) on the real blank, with a registration and a dome."""
    torch.manual_seed(0)
    model = build_model(preset)
    with torch.no_grad():  # weights far from their initialisation, so every layer matters
        for parameter in model.parameters():
            parameter.add_(0.05 * torch.randn_like(parameter))
    write_untrained_model(
        path,
        preset,
        blank,
        model,
        normalisation=dict(normalisation),
        camera={"lens": None, "downscale": 1},
        registration=REGISTRATION,
        dome=DOME,
    )
    return path


@pytest.mark.parametrize("preset", ["compact", "context", "multiscale"])
def test_onnx_matches_torch_within_1e4_on_real_frames(tmp_path, real_frames, preset):
    """Every preset the study trains, on three real frames in one batch: onnxruntime's gradients
    within 1e-4 of DepthEstimator.gradients (measured: 2e-7), and so the integrated depth."""
    frames, blank = real_frames
    model = write_model(tmp_path / "model.pt", preset, blank)
    estimator = DepthEstimator.from_checkpoint(model, device="cpu")
    export_onnx(estimator, tmp_path / "model.onnx", model)
    onnx.checker.check_model(str(tmp_path / "model.onnx"))
    exported = onnx_gradients(onnx_session(tmp_path / "model.onnx", threads=2), frames)
    expected = estimator.gradients(frames)
    assert exported.shape == expected.shape == (3, 320, 240, 2)
    assert np.abs(expected).max() > 0.05  # not a degenerate all-zero comparison
    assert np.abs(exported - expected).max() < 1e-4
    depth = integrate(exported[1, ..., 0], exported[1, ..., 1], px_per_mm=estimator.px_per_mm)
    np.testing.assert_allclose(depth, estimator.depth(frames[1]), atol=1e-4)


def test_the_authors_normalisation_is_baked_in_too(tmp_path, real_frames):
    """Pixel-index coordinates, no drift step, the opposite sign (the authors' TouchNet
    convention, on compact weights for speed): still within 1e-4."""
    frames, blank = real_frames
    model = write_model(tmp_path / "model.pt", "compact", blank, AUTHORS_NORMALISATION)
    estimator = DepthEstimator.from_checkpoint(model, device="cpu")
    export_onnx(estimator, tmp_path / "model.onnx")
    exported = onnx_gradients(onnx_session(tmp_path / "model.onnx"), frames[:1])
    assert np.abs(exported - estimator.gradients(frames[:1])).max() < 1e-4


def test_export_cli_writes_the_graph_and_its_sidecar(tmp_path, real_frames, capsys):
    frames, blank = real_frames
    model = write_model(tmp_path / "model.pt", "compact_tiny", blank)
    out = tmp_path / "deploy" / "digit.onnx"
    assert main(["export", "--checkpoint", str(model), "--out", str(out)]) == 0
    assert f"ONNX opset {OPSET}" in capsys.readouterr().out
    graph = onnx.load(str(out))
    assert {o.version for o in graph.opset_import if o.domain in ("", "ai.onnx")} == {OPSET}
    assert [i.name for i in graph.graph.input] == ["frames"]
    sidecar = json.loads((tmp_path / "deploy" / "digit.onnx.json").read_text())
    assert sidecar["onnx_opset"] == OPSET and sidecar["onnx"] == "digit.onnx"
    assert sidecar["px_per_mm"] == 19.58 and sidecar["image_shape"] == [320, 240]
    assert sidecar["registration"] == REGISTRATION and sidecar["contact_z_mm"] == 134.96
    assert sidecar["camera"] == {"lens": None, "downscale": 1} and sidecar["dome"] == DOME
    assert sidecar["input"]["dtype"] == "uint8" and sidecar["output"]["name"] == "gradients"
    assert len(sidecar["checkpoint"]["sha256"]) == 64
    # a new blank is a re-export: the graph then compares frames with it

    Image.fromarray(frames[0]).save(tmp_path / "new_blank.png")
    args = ["export", "--checkpoint", str(model), "--out", str(out)]
    assert main(args) == 1  # never replaced silently
    assert "digit.onnx: already exists" in capsys.readouterr().err
    assert main([*args, "--blank", str(tmp_path / "new_blank.png"), "--force"]) == 0
    zero = onnx_gradients(onnx_session(out), frames[:1])
    reference = DepthEstimator.from_checkpoint(model, device="cpu", blank=frames[0])
    assert np.abs(zero - reference.gradients(frames[:1])).max() < 1e-4


@pytest.mark.parametrize(
    ("out", "message"),
    [("model.pt", "end it in .onnx"), ("model.onnx", "is the --checkpoint file")],
)
def test_export_refuses_bad_outputs_before_writing(tmp_path, real_frames, capsys, out, message):
    _, blank = real_frames
    model = write_model(
        tmp_path / "model.onnx" if out == "model.onnx" else tmp_path / "m.pt", "compact_tiny", blank
    )
    before = model.read_bytes()
    assert (
        main(["export", "--checkpoint", str(model), "--out", str(tmp_path / out), "--force"]) == 1
    )
    assert message in capsys.readouterr().err
    assert model.read_bytes() == before and not (tmp_path / "model.onnx.json").exists()
