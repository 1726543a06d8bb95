"""Property-based fuzzing of every input a user hands threedcal (issue 22): configs, ball-image
folders, py3DCal folders and checkpoints. Whatever is generated, the answer is a result or a
ThreedcalError with a message — never another exception (a traceback), and never a write."""

from __future__ import annotations

import contextlib
import copy
import json
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import torch
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from threedcal.cli import main
from threedcal.dataset.importers import load_ball_folder, load_py3dcal_folder
from threedcal.errors import ThreedcalError
from threedcal.model.checkpoint import FORMAT, FORMAT_VERSION, read_checkpoint
from threedcal.model.inference import DepthEstimator

FAST = settings(
    max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None
)

# ---- values of every kind, including the awkward ones -----------------------------------------
numbers = st.one_of(
    st.integers(-5, 400),
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.sampled_from([0, 0.0001, -1, 1e9, float("nan")]),
)
texts = st.one_of(
    st.text(max_size=12),
    st.sampled_from(["", "all", "../x", "/etc", "checksum,bogus", "digit", "ender3", "x.yaml"]),
)
scalars = st.one_of(st.none(), st.booleans(), numbers, texts)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=6,
)


@contextlib.contextmanager
def sandbox():
    """A fresh working directory; yields it, restores the old one."""
    old = os.getcwd()
    with tempfile.TemporaryDirectory() as folder:
        os.chdir(folder)
        try:
            yield Path(folder)
        finally:
            os.chdir(old)


def listing(folder: Path) -> dict[str, tuple[int, int]]:
    return {
        str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
    }


def answers_or_names_the_problem(call) -> None:
    """`call()` returns, or raises a ThreedcalError with a message; nothing else."""
    try:
        call()
    except ThreedcalError as exc:
        assert str(exc).strip(), "an error without a message"


# ---- configs -------------------------------------------------------------------------------------
BASE = {
    "seed": 1,
    "scenes": {
        "a": {
            "sensor": "digit",
            "printer": "ender3",
            "plan": {"spacing_mm": 4.0, "depth_mm": 1.0, "frames": 1},
            "bench": {"faults": "checksum", "fault_rate": 0.1},
        },
        "b": {"sensor": "gelsight_mini", "import": {"format": "ball_folder", "path": "data"}},
    },
}
KEY_PATHS = [
    ("seed",),
    ("torch_threads",),
    ("scenes",),
    ("scenes", "a"),
    ("scenes", "a", "sensor"),
    ("scenes", "a", "printer"),
    ("scenes", "a", "plan"),
    ("scenes", "a", "plan", "spacing_mm"),
    ("scenes", "a", "plan", "depth_mm"),
    ("scenes", "a", "plan", "depths_mm"),
    ("scenes", "a", "plan", "frames"),
    ("scenes", "a", "plan", "pattern"),
    ("scenes", "a", "plan", "csv"),
    ("scenes", "a", "probe"),
    ("scenes", "a", "probe", "radius_mm"),
    ("scenes", "a", "bench", "faults"),
    ("scenes", "a", "bench", "fault_rate"),
    ("scenes", "a", "port"),
    ("scenes", "a", "ablation"),
    ("scenes", "b", "import", "path"),
    ("scenes", "b", "import", "format"),
    ("scenes", "b", "model"),
    ("scenes", "zz"),
]


@st.composite
def configs(draw):
    config = copy.deepcopy(BASE)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(KEY_PATHS))
        node = config
        for key in path[:-1]:
            if not isinstance(node, dict):
                break
            node = node.setdefault(key, {})
        if isinstance(node, dict):
            if draw(st.booleans()) and path[-1] in node:
                del node[path[-1]]
            else:
                node[path[-1]] = draw(values)
    return config


@settings(FAST, max_examples=20)
@given(config=configs())
def test_fuzzed_configs_are_valid_or_named_and_nothing_is_written(config):
    with sandbox() as folder:
        path = folder / "c.yaml"
        path.write_text(yaml.safe_dump(config))
        before = listing(folder)
        assert main(["config", "check", str(path)]) in (0, 1)  # main turns ThreedcalError into 1
        assert listing(folder) == before


@FAST
@given(text=st.text(max_size=200) | st.sampled_from(["a: 1\na: 2\n", "scenes: [", "- 1\n- 2", "{"]))
def test_fuzzed_yaml_text_is_valid_or_named(text):
    with sandbox() as folder:
        path = folder / "c.yaml"
        path.write_text(text)
        before = listing(folder)
        assert main(["config", "check", str(path)]) in (0, 1)
        assert listing(folder) == before


# ---- images and folders ------------------------------------------------------------------------
@st.composite
def image_files(draw):
    """Bytes of an image file: a PNG of some shape, depth and channel count, or junk."""
    kind = draw(st.sampled_from(["rgb", "rgb", "grey", "16bit", "rgba", "junk", "size"]))
    if kind == "junk":
        return draw(st.binary(max_size=40))
    height, width = (8, 6) if kind != "size" else (draw(st.integers(1, 9)), draw(st.integers(1, 9)))
    rng = np.random.default_rng(draw(st.integers(0, 9)))
    channels = {"grey": 1, "rgba": 4}.get(kind, 3)
    dtype = np.uint16 if kind == "16bit" else np.uint8
    image = rng.integers(0, np.iinfo(dtype).max, (height, width, channels), dtype=dtype)
    if kind == "rgba" and draw(st.booleans()):
        image[..., 3] = 255
    ok, data = cv2.imencode(".png", image[..., 0] if channels == 1 else image)
    assert ok
    return data.tobytes()


def descriptions(*keys):
    """A dataset description: the keys it needs with odd values, or anything at all."""
    return st.one_of(st.fixed_dictionaries({k: st.one_of(numbers, texts) for k in keys}), values)


NAMES = st.sampled_from(["0.png", "1.png", "2.png", "../0.png", "/etc/hosts", "missing.png", ""])
cells = st.one_of(numbers, texts)


@st.composite
def ball_folders(draw):
    files: dict[str, bytes] = {}
    meta = draw(descriptions("px_per_mm", "ball_radius_mm"))
    files["dataset.yaml"] = yaml.safe_dump(meta).encode()
    files["background.png"] = draw(image_files())
    for name in ("0.png", "1.png", "2.png"):
        if draw(st.booleans()):
            files[name] = draw(image_files())
    rows = draw(st.lists(st.tuples(NAMES, cells, cells, cells), max_size=4))
    table = pd.DataFrame(rows, columns=["image", "center_x_px", "center_y_px", "radius_px"])
    if draw(st.booleans()):
        table = table.drop(columns=[draw(st.sampled_from(list(table.columns)))])
    files["labels.csv"] = table.to_csv(index=False).encode()
    return files


@st.composite
def py3dcal_folders(draw):
    files: dict[str, bytes] = {}
    meta = draw(descriptions("px_per_mm", "probe_radius_mm"))
    files["annotations/metadata.json"] = json.dumps(meta).encode()
    files["blank_images/blank.png"] = draw(image_files())
    for name in ("0.png", "1.png"):
        if draw(st.booleans()):
            files[f"probe_images/{name}"] = draw(image_files())
    rows = draw(
        st.lists(st.tuples(NAMES | st.just("---"), cells, cells, cells, cells, cells), max_size=4)
    )
    columns = ["img_name", "x_mm", "y_mm", "penetration_depth_mm", "x_px", "y_px"]
    files["annotations/annotations.csv"] = (
        pd.DataFrame(rows, columns=columns).to_csv(index=False).encode()
    )
    return files


def loads_or_names_without_writing(files: dict[str, bytes], loader) -> None:
    """Write the generated folder, load it, and check nothing else was written."""
    with sandbox() as root:
        folder = root / "set"
        for name, data in files.items():
            (folder / name).parent.mkdir(parents=True, exist_ok=True)
            (folder / name).write_bytes(data)
        before = listing(root)
        answers_or_names_the_problem(lambda: loader(folder))
        assert listing(root) == before


@FAST
@given(files=ball_folders())
def test_fuzzed_ball_folders_load_or_are_named_and_nothing_is_written(files):
    loads_or_names_without_writing(files, load_ball_folder)


@FAST
@given(files=py3dcal_folders())
def test_fuzzed_py3dcal_folders_load_or_are_named_and_nothing_is_written(files):
    loads_or_names_without_writing(files, load_py3dcal_folder)


# ---- checkpoints -------------------------------------------------------------------------------
tensors = st.one_of(
    st.builds(torch.zeros, st.sampled_from([(2,), (4, 3, 3), (8, 6, 3), (3, 8, 6)])),
    st.just(torch.tensor(float("nan"))),
)
checkpoint_values = st.one_of(
    scalars, tensors, st.dictionaries(st.text(max_size=8), tensors, max_size=2)
)


@st.composite
def checkpoints(draw):
    kind = draw(st.sampled_from(["bytes", "dict", "ours", "ours", "authors"]))
    if kind == "bytes":
        return draw(st.binary(max_size=64))
    if kind == "dict":
        data = draw(st.dictionaries(st.text(max_size=8), checkpoint_values, max_size=4))
    elif kind == "authors":
        data = {f"conv{i}.weight": draw(tensors) for i in (1, 9)}
    else:
        data = {
            "format": FORMAT,
            "format_version": draw(st.sampled_from([FORMAT_VERSION, FORMAT_VERSION, 0, "1"])),
            "preset": draw(st.sampled_from(["compact_tiny", "touchnet", "nope", 3])),
            "preset_args": draw(st.one_of(st.just({}), values)),
            "state_dict": draw(
                st.one_of(st.just({}), st.dictionaries(st.text(max_size=6), tensors, max_size=2))
            ),
            "normalisation": draw(
                st.one_of(
                    st.just({"coords": "unit", "gradient_sign": 1.0, "drift": "median"}), values
                )
            ),
            "blank": draw(st.one_of(st.none(), tensors, scalars)),
            "px_per_mm": draw(st.one_of(st.none(), numbers, texts)),
            "image_shape": draw(st.one_of(st.none(), st.just([8, 6]), values)),
        }
        for key in draw(st.lists(st.sampled_from(sorted(data)), max_size=2)):
            data.pop(key, None)
    buffer = tempfile.SpooledTemporaryFile()
    torch.save(data, buffer)
    buffer.seek(0)
    return buffer.read()


@FAST
@given(data=checkpoints())
def test_fuzzed_checkpoints_load_or_are_named_and_nothing_is_written(data):
    with sandbox() as root:
        path = root / "model.pt"
        path.write_bytes(data)
        before = listing(root)
        answers_or_names_the_problem(lambda: read_checkpoint(path))
        answers_or_names_the_problem(
            lambda: DepthEstimator.from_checkpoint(path, device="cpu", px_per_mm=10.0)
        )
        assert listing(root) == before
