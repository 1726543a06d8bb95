"""Shared fixtures: paths, the shared real data, and a Snakemake runner for workflow tests."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "data"
SNAKEMAKE = Path(sys.executable).with_name("snakemake")


@pytest.fixture
def sim_firmware():
    """A fault-free fake Marlin (no pacing) behind a fresh simmarlin:// name: (url, firmware)."""
    import uuid

    from threedcal.sim.marlin import SimMarlin, forget, register

    name = f"f{uuid.uuid4().hex[:8]}"
    firmware = register(name, SimMarlin("ender3", speedup=float("inf")))
    yield f"simmarlin://{name}", firmware
    forget(name)


@pytest.fixture
def repo() -> Path:
    return REPO


@pytest.fixture
def real_data() -> Path:
    """The real sensor data vendored in the repository (data/, each folder with its licence)."""
    if not DATA.is_dir():
        pytest.fail(f"{DATA} is missing: the vendored real data belongs in the repository")
    return DATA


def write_config(directory: Path, config: dict, name: str = "config.yaml") -> Path:
    path = directory / name
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def tiny_study_config(tmp_path: Path) -> dict:
    """tests/config/test.yaml with its relative data paths made absolute (it runs in a temp dir)."""
    config = yaml.safe_load((REPO / "tests/config/test.yaml").read_text())
    if "realism" in config:
        config["realism"]["real"] = str((REPO / config["realism"]["real"]).resolve())
    for scene in config["scenes"].values():
        if "import" in scene:
            scene["import"]["path"] = str((REPO / scene["import"]["path"]).resolve())
    return config


def snakemake_command(workdir: Path, configfile: Path, *args: str, cores: int = 2) -> list[str]:
    return [
        str(SNAKEMAKE),
        "-s",
        str(REPO / "Snakefile"),
        "-d",
        str(workdir),
        "--configfile",
        str(configfile),
        "--cores",
        str(cores),
        *args,
    ]


def snapshot(path: Path) -> dict[str, tuple[int, int, str]]:
    """Every file under `path` with its size, mtime and content hash: a store left untouched."""
    import hashlib

    return {
        str(p.relative_to(path)): (
            p.stat().st_size,
            p.stat().st_mtime_ns,
            hashlib.sha1(p.read_bytes()).hexdigest(),
        )
        for p in sorted(path.rglob("*"))
        if p.is_file()
    }


def snakemake(
    workdir: Path, configfile: Path, *args: str, check: bool = True, env: dict | None = None
) -> subprocess.CompletedProcess:
    cmd = snakemake_command(workdir, configfile, *args)
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=workdir, env=env)
    if check and result.returncode != 0:
        raise AssertionError(
            f"snakemake failed ({' '.join(cmd)}):\n{result.stdout}\n{result.stderr}"
        )
    return result


def scheduled_jobs(workdir: Path, configfile: Path, *args: str) -> list[tuple[str, dict[str, str]]]:
    """The (rule, wildcards) of every job a dry run would execute."""
    result = snakemake(workdir, configfile, "--dry-run", *args)
    jobs: list[tuple[str, dict[str, str]]] = []
    for block in re.split(r"\n(?=(?:local)?rule \w+:)", result.stdout + result.stderr):
        match = re.match(r"(?:local)?rule (\w+):", block.strip())
        if not match:
            continue
        wildcards = re.search(r"^\s+wildcards: (.*)$", block, re.MULTILINE)
        values = (
            dict(kv.split("=", 1) for kv in wildcards.group(1).split(", ")) if wildcards else {}
        )
        jobs.append((match.group(1), values))
    return jobs


def bench_scene(sensor, plan, seed, bench=None):
    """A validated scene on the simulated bench (hidden touch height up to ±0.1 mm by default)."""
    from threedcal.config import validate_config

    scene = {"sensor": sensor, "printer": "ender3", "plan": plan}
    scene["bench"] = bench or {"touch_offset_mm": 0.1}
    return validate_config({"seed": seed, "scenes": {"s": scene}})["scenes"]["s"]


def collect_on_bench(folder, sensor, plan, seed, bench=None):
    """Collect a scene on the simulated bench into folder/raw.zarr (its truth beside it)."""
    from threedcal.collect.session import collect_scene

    scene = bench_scene(sensor, plan, seed, bench)
    collect_scene("s", scene, folder / "raw.zarr", truth_path=folder / "truth.json", progress=False)
    return scene


def collect_and_register(folder, sensor, plan, seed):
    """collect_on_bench, then the dataset stage (folder/reg.json, ts/, ...): its record."""
    from threedcal.dataset.build import build_collected

    scene = collect_on_bench(folder, sensor, plan, seed)
    paths = [folder / n for n in ("ts", "splits.csv", "reg.json", "reg.png", "truth.json")]
    return build_collected(scene, folder / "raw.zarr", *paths, progress=False)


@pytest.fixture(scope="session")
def paper_digit_calibration(tmp_path_factory):
    """A DIGIT calibrated on the bench at config/paper.yaml's depth (d = 2.0 mm = R: a vertical
    contact rim), the default first-contact search first, a coarse grid (3 mm, one frame a point):
    (scene, folder with raw.zarr, truth.json, reg.json, ..., the dataset stage's record)."""
    folder = tmp_path_factory.mktemp("paper_digit")
    plan = {"spacing_mm": 3.0, "depth_mm": 2.0, "frames": 1}
    record = collect_and_register(folder, "digit", plan, 3)
    return bench_scene("digit", plan, 3), folder, record
