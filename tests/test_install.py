"""The package installs like a library: a wheel built from this tree, installed into a fresh venv
with none of the workflow's dependencies, runs `threedcal --version`, `predict` and `live` on real
frames (data/), and `export` says which extra it needs."""

import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import DATA, REPO, write_untrained_model

from threedcal.images import read_rgb

WHEELS = Path("/opt/wheels")  # the CPU torch wheel on our machines, as the Makefile uses it
WORKFLOW_ONLY = (
    "zarr",
    "snakemake",
    "xarray",
    "pandas",
    "matplotlib",
    "statsmodels",
    "serial",
    "onnx",
)


# The fresh venv's own processes may write their bytecode (into the venv, under tmp_path): with
# PYTHONDONTWRITEBYTECODE set (as on our machines) each of its five processes compiled torch's
# modules from source anew, 1.3 s of CPU apiece.
FRESH_VENV_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def run(*command, cwd=None, env=None):
    done = subprocess.run(command, capture_output=True, text=True, cwd=cwd, timeout=300, env=env)
    assert done.returncode == 0, f"{' '.join(map(str, command))}\n{done.stdout}\n{done.stderr}"
    return done.stdout


@pytest.mark.long
@pytest.mark.slow  # a wheel build and a fresh venv: 21-35 s with uv's cache warm
def test_a_wheel_in_a_fresh_venv_runs_predict_and_live_without_the_workflow(tmp_path):
    # the wheel, built from a copy of what it packages (the tree itself stays clean)
    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, source / name)
    shutil.copytree(REPO / "src", source / "src", ignore=shutil.ignore_patterns("__pycache__"))
    run(sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
        "--wheel-dir", str(tmp_path / "dist"), str(source))  # fmt: skip
    (wheel,) = (tmp_path / "dist").glob("threedcal-*.whl")

    # a fresh venv: the wheel and its own dependencies only (uv, as the Makefile installs; pip
    # where uv is missing)
    venv = tmp_path / "venv"
    run(sys.executable, "-m", "venv", "--without-pip", str(venv))
    python = venv / "bin" / "python"
    links = ["--find-links", str(WHEELS)] if WHEELS.is_dir() else []
    if importlib.util.find_spec("uv") is not None:
        installer = [sys.executable, "-m", "uv", "pip", "install", "--python", str(python)]
    else:
        installer = [sys.executable, "-m", "pip", "--python", str(python), "install"]
    # the torch this suite runs on (the CPU build here): never another one from the registry
    constraint = tmp_path / "constraints.txt"
    constraint.write_text(f"torch=={torch.__version__}\n")
    run(*installer, "--quiet", *links, "--constraint", str(constraint), str(wheel))
    lines = run(
        python,
        "-c",
        "import importlib.util as u, threedcal, torch; print(torch.__version__); "
        f"print([m for m in {WORKFLOW_ONLY!r} if u.find_spec(m) is None])",
        env=FRESH_VENV_ENV,
    ).splitlines()
    assert lines[0] == torch.__version__
    assert lines[1] == str(list(WORKFLOW_ONLY))  # none of the workflow's packages came along
    threedcal = venv / "bin" / "threedcal"
    assert run(threedcal, "--version", env=FRESH_VENV_ENV).strip().startswith("threedcal ")

    # predict and live on real DIGIT frames (a freshly initialised model on the real blank)
    blank = read_rgb(DATA / "digit_frames_fots" / "background.png")
    write_untrained_model(tmp_path / "model.pt", "compact_tiny", blank)
    frame = DATA / "digit_frames_fots" / "0010.png"
    out = run(threedcal, "predict", "--checkpoint", "model.pt", "--image", str(frame),
              "--out", "depth.npy", "--points", "points.ply", cwd=tmp_path, env=FRESH_VENV_ENV)  # fmt: skip
    assert "76800 points (sensor frame, mm)" in out
    assert np.load(tmp_path / "depth.npy").shape == (320, 240)
    (tmp_path / "frames").mkdir()
    for name in ("0010.png", "0021.png"):
        shutil.copy(DATA / "digit_frames_fots" / name, tmp_path / "frames" / name)
    out = run(threedcal, "live", "--checkpoint", "model.pt", "--source", "frames",
              "--out", "live.gif", cwd=tmp_path, env=FRESH_VENV_ENV)  # fmt: skip
    assert "2 frames, depth at" in out and (tmp_path / "live.gif").stat().st_size > 0
    # export needs its extra, and says so
    done = subprocess.run(
        [threedcal, "export", "--checkpoint", "model.pt", "--out", "m.onnx"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**FRESH_VENV_ENV, "PYTHONWARNINGS": "ignore"},
    )
    assert done.returncode == 1 and "pip install 'threedcal[export]'" in done.stderr
