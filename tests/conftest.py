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
