"""Issue 22: every unusable checkpoint is a CheckpointError naming the file, never a traceback."""

import pickle

import pytest
import torch

from threedcal.model.checkpoint import FORMAT, FORMAT_VERSION, CheckpointError, read_checkpoint
from threedcal.model.inference import DepthEstimator


def test_zero_byte_checkpoint_is_named(tmp_path):
    """Repro: a 0-byte model.pt gave an IndexError inside the error handler."""
    path = tmp_path / "model.pt"
    path.write_bytes(b"")
    with pytest.raises(CheckpointError, match=r"model.pt: is empty \(0 bytes\)"):
        read_checkpoint(path)


@pytest.mark.parametrize("data", [b"\x00", b"PK\x03\x04 truncated", b"not a checkpoint at all"])
def test_corrupt_checkpoint_is_named(tmp_path, data):
    path = tmp_path / "model.pt"
    path.write_bytes(data)
    with pytest.raises(
        CheckpointError, match=r"model.pt: refused to load: not a readable checkpoint"
    ):
        read_checkpoint(path)


def test_checkpoint_without_preset_is_named(tmp_path):
    """Repro: a checkpoint missing `preset` gave a KeyError."""
    path = tmp_path / "model.pt"
    torch.save({"format": FORMAT, "format_version": FORMAT_VERSION, "state_dict": {}}, path)
    with pytest.raises(
        CheckpointError, match=r"model.pt: threedcal checkpoint without 'preset', 'normalisation'"
    ):
        read_checkpoint(path)
    with pytest.raises(CheckpointError, match="without 'preset'"):
        DepthEstimator.from_checkpoint(path)


def test_checkpoint_with_keys_of_the_wrong_type_is_named(tmp_path):
    path = tmp_path / "model.pt"
    bad = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "preset": 3,
        "state_dict": {},
        "normalisation": {},
    }
    torch.save(bad, path)
    with pytest.raises(CheckpointError, match="'preset' must be a str, got int"):
        read_checkpoint(path)


class _Payload:
    def __reduce__(self):
        return (print, ("never",))


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")
def test_unsafe_checkpoint_refusal_does_not_advise_unsafe_loading(tmp_path):
    """Repro: the refusal quoted PyTorch's advice to load with weights_only=False."""
    path = tmp_path / "model.pt"
    torch.save({"format": FORMAT, "payload": _Payload()}, path)
    with pytest.raises(CheckpointError) as exc:
        read_checkpoint(path)
    message = str(exc.value)
    assert "model.pt: refused to load: it holds a pickled Python object (print)" in message
    assert "weights_only" not in message and "trust" not in message
    with open(tmp_path / "plain.pt", "wb") as handle:
        pickle.dump({"payload": _Payload()}, handle)
    with pytest.raises(CheckpointError, match="refused to load"):
        read_checkpoint(tmp_path / "plain.pt")


def test_checkpoint_with_a_malformed_lens_is_named(tmp_path):
    """A checkpoint whose camera lens record lacks κ₁ is refused on reading, naming the key."""
    path = tmp_path / "model.pt"
    torch.save(
        {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "preset": "compact_tiny",
            "state_dict": {},
            "normalisation": {"gradient_sign": 1},
            "camera": {"lens": {"centre_px": [1.0, 2.0]}},
        },
        path,
    )
    with pytest.raises(
        CheckpointError,
        match=r"model.pt: 'camera': lens record .* is malformed \('kappa1_per_px2'\)",
    ):
        read_checkpoint(path)
