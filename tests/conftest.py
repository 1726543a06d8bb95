"""Shared fixtures: paths, the shared real data, and a Snakemake runner for workflow tests."""

from __future__ import annotations

import fcntl
import os
import pickle
import re
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "data"
SNAKEMAKE = Path(sys.executable).with_name("snakemake")
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def share_the_cores_between_workers() -> int | None:
    """Under pytest-xdist, each worker's BLAS and OpenMP (torch) pools get its share of the cores
    (the thread variables, where not set already), as Snakemake gives each job its threads, and
    OpenMP's idle threads sleep rather than spin (OMP_WAIT_POLICY=PASSIVE; the arithmetic is the
    same). Unlimited, each worker's pools start a thread per core: `make test`'s 2 workers on 2
    cores ran 4 busy-waiting threads, and a BLAS-bound test took twice the time and twice the CPU
    (two realism fits side by side: 18 s of CPU each, 9.5 s on one thread). A training keeps its
    torch_threads (2 by default: CPU results depend on it); spinning, two such trainings side by
    side took 8 times the CPU they take with PASSIVE. NumPy has loaded its BLAS before this file,
    so its pool is limited in place too. Returns the share (None: not a worker)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT") or 1)
    if workers <= 1:
        return None
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    share = max(1, (cores or 1) // workers)
    for name in THREAD_VARIABLES:
        os.environ.setdefault(name, str(share))
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=int(os.environ["OPENBLAS_NUM_THREADS"]), user_api="blas")
    return share


share_the_cores_between_workers()


def remove_tree(path, ignore_errors: bool = False, **kwargs) -> None:
    """shutil.rmtree, removing the folders of each depth in parallel (deepest first): where each
    removal waits on the disk (this machine's ext4, mounted with `discard`: ~2 ms a folder), one at a
    time took ~6 s for two tests' tmp_path (1400 folders of zarr chunks) and ~0.5 s on 8 threads.
    Every folder is emptied by shutil.rmtree itself, which never follows a symlink (the docs
    tests' workspaces link the repository's folders); what is left (a top-level file or link, a
    folder that could not go) goes through shutil.rmtree as before, with the caller's options."""
    if not os.path.islink(path) and os.path.isdir(path):
        levels: dict[int, list[str]] = {}
        for folder, _, _ in os.walk(path):  # real folders only: links are not walked into
            levels.setdefault(folder.count(os.sep), []).append(folder)
        with ThreadPoolExecutor(8) as pool:
            for depth in sorted(levels, reverse=True):
                list(pool.map(lambda f: shutil.rmtree(f, ignore_errors=True), levels[depth]))
    if os.path.lexists(path):
        shutil.rmtree(path, ignore_errors=ignore_errors, **kwargs)


def pytest_configure(config):
    """pytest removes each passed test's tmp_path (tmp_path_retention_policy = "failed") and, after
    a passing run, the whole base folder, with shutil.rmtree: remove_tree does the same, faster.
    (pytest's tmpdir plugin calls `rmtree` by that module-level name; if a later pytest does not,
    this changes nothing.)"""
    from _pytest import tmpdir

    if getattr(tmpdir, "rmtree", None) is shutil.rmtree:
        tmpdir.rmtree = remove_tree


def pytest_collection_modifyitems(config, items):
    """Start the long tests first: the end-to-end run, then the rest of its file (quick dry runs:
    the one test xdist queues behind it on the same worker), then every file holding `slow` tests,
    slow ones first. `make test` hands tests out one at a time in this order (`--maxschedchunk 1`),
    so the other worker works through everything else while the end-to-end run goes, and both
    finish together instead of one starting a two-minute test when the other is done. A file's
    tests stay together, so a module fixture is built at most once per worker."""
    first = {  # the end-to-end runs: `make test`'s, and `make test-long`'s of the imported scene
        "test_end_to_end_run_then_reruns_only_what_a_change_touches",
        "test_end_to_end_run_of_an_imported_scene_and_the_realism_check",
    }
    first_files = {item.path for item in items if item.name in first}
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}
    files: dict[Path, int] = {}
    for item in items:
        files.setdefault(item.path, len(files))

    def rank(pair):
        position, item = pair
        if item.name in first:
            group = 0
        elif item.path in first_files:
            group = 1
        elif item.path in slow_files:
            group = 2
        else:
            group = 3
        slow_first = group == 2 and not item.get_closest_marker("slow")
        return (group, files[item.path], slow_first, position)

    items[:] = [item for _, item in sorted(enumerate(items), key=rank)]


def shared_across_workers(tmp_path_factory, name: str, build):
    """`build(folder)` run once for the whole test session, even across pytest-xdist workers
    (the first worker builds under a file lock; the others wait, then read its result): for
    expensive read-only fixtures that several test files use. Returns (folder, build's result)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # shared by the workers of this run
    folder = base / f"shared-{name}"
    with open(base / f"shared-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        done = folder / ".result.pickle"
        if not done.is_file():
            folder.mkdir(exist_ok=True)
            result = build(folder)
            done.write_bytes(pickle.dumps(result))
        return folder, pickle.loads(done.read_bytes())


@pytest.fixture
def sim_firmware():
    """A fault-free fake Marlin (no pacing) behind a fresh simmarlin:// name: (url, firmware)."""
    import uuid

    from threedcal.sim.marlin import FIRMWARES, SimMarlin

    name = f"f{uuid.uuid4().hex[:8]}"
    firmware = FIRMWARES.serve(name, SimMarlin("ender3", speedup=float("inf")))
    yield f"simmarlin://{name}", firmware
    FIRMWARES.withdraw(name)


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


def assert_same_array(actual, desired, err_msg: str = "") -> None:
    """np.testing.assert_array_equal, but quick when the arrays are equal: it compares element by
    element through several temporaries (5.5 s for a 600-frame store's 150 MB of frames, against
    0.03 s for np.array_equal); only arrays that differ go through it, for its report."""
    if not np.array_equal(actual, desired):
        np.testing.assert_array_equal(actual, desired, err_msg=err_msg)


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
    return dry_run_jobs(result.stdout + result.stderr)


def dry_run_jobs(text: str) -> list[tuple[str, dict[str, str]]]:
    """The (rule, wildcards) of every job in a dry run's output."""
    jobs: list[tuple[str, dict[str, str]]] = []
    for block in re.split(r"\n(?=(?:local)?rule \w+:)", text):
        match = re.match(r"(?:local)?rule (\w+):", block.strip())
        if not match:
            continue
        wildcards = re.search(r"^\s+wildcards: (.*)$", block, re.MULTILINE)
        values = (
            dict(kv.split("=", 1) for kv in wildcards.group(1).split(", ")) if wildcards else {}
        )
        jobs.append((match.group(1), values))
    return jobs


@pytest.fixture(scope="session")
def tiny_study_dry_run(tmp_path_factory) -> tuple[dict, str]:
    """tests/config/test.yaml (paths absolute) and the output of one `snakemake --dry-run` of it,
    shared by the tests that read what the tiny study schedules: (config, stdout + stderr)."""

    def dry_run(folder):
        config = tiny_study_config(folder)
        result = snakemake(folder, write_config(folder, config), "--dry-run")
        return config, result.stdout + result.stderr

    return shared_across_workers(tmp_path_factory, "tiny_study_dry_run", dry_run)[1]


def lens_free(sensor: str) -> str:
    """A built-in sensor profile without its lens, as a YAML path: for plans too coarse to fit the
    lens (registration then keeps the affine alone, which the lens bends by up to a pixel at the
    frame's edge; tests/dataset/test_lens_registration.py checks the lens)."""
    return _profile_variant(sensor, "lens-free", lambda profile: profile.update(lens=None))


def elastic_gel(sensor: str) -> str:
    """A built-in sensor profile with the elastic gel (gel.mechanics: elastic), as a YAML path."""
    return _profile_variant(
        sensor, "elastic", lambda profile: profile["gel"].update(mechanics="elastic")
    )


def _profile_variant(sensor: str, name: str, change) -> str:
    import tempfile

    from threedcal.profiles import load_profile

    profile = {k: v for k, v in load_profile("sensor", sensor).items() if k != "source"}
    change(profile)
    folder = Path(tempfile.gettempdir()) / "threedcal-tests"
    folder.mkdir(exist_ok=True)
    path = folder / f"{sensor}-{name}.yaml"
    staging = path.with_suffix(f".{os.getpid()}.tmp")
    staging.write_text(yaml.safe_dump(profile, sort_keys=False))
    os.replace(staging, path)  # every worker writes the same text: whichever lands is right
    return str(path)


def bench_scene(sensor, plan, seed, bench=None, dataset=None):
    """A validated scene on the simulated bench (hidden touch height up to ±0.1 mm by default)."""
    from threedcal.study.config import validate_config

    scene = {"sensor": sensor, "printer": "ender3", "plan": plan}
    scene["bench"] = bench or {"touch_offset_mm": 0.1}
    if dataset is not None:
        scene["dataset"] = dataset
    return validate_config({"seed": seed, "scenes": {"s": scene}})["scenes"]["s"]


def collect_on_bench(folder, sensor, plan, seed, bench=None, dataset=None):
    """Collect a scene on the simulated bench into folder/raw.zarr (its truth beside it)."""
    from threedcal.study.session import collect_scene

    scene = bench_scene(sensor, plan, seed, bench, dataset)
    collect_scene("s", scene, folder / "raw.zarr", truth_path=folder / "truth.json", progress=False)
    return scene


def collect_and_register(folder, sensor, plan, seed, dataset=None):
    """collect_on_bench, then the dataset stage (folder/reg.json, ts/, ...): its record."""
    from threedcal.dataset.build import build_collected
    from threedcal.study.scene import dataset_settings

    scene = collect_on_bench(folder, sensor, plan, seed, dataset=dataset)
    paths = [folder / n for n in ("ts", "splits.csv", "reg.json", "reg.png", "truth.json")]
    return build_collected(dataset_settings(scene), folder / "raw.zarr", *paths, progress=False)


# config/paper.yaml trains on its d = R presses (the paper's data), as every press of its plan is one
PAPER_DATASET = {"max_depth_over_radius": None}


@pytest.fixture(scope="session")
def paper_digit_calibration(tmp_path_factory):
    """A DIGIT calibrated on the bench at config/paper.yaml's depth (d = 2.0 mm = R: a vertical
    contact rim), the default first-contact search first, a coarse grid (3 mm, one frame a point):
    (scene, folder with raw.zarr, truth.json, reg.json, ..., the dataset stage's record)."""
    plan = {"spacing_mm": 3.0, "depth_mm": 2.0, "frames": 1}
    folder, record = shared_across_workers(
        tmp_path_factory,
        "paper_digit",
        lambda folder: collect_and_register(folder, lens_free("digit"), plan, 3, PAPER_DATASET),
    )
    return bench_scene(lens_free("digit"), plan, 3, dataset=PAPER_DATASET), folder, record


@pytest.fixture(scope="session")
def paper_mini_calibration(tmp_path_factory):
    """paper_digit_calibration's GelSight Mini (flat gel, landscape): d = 2.0 mm = R, the default
    first-contact search, the same coarse grid."""
    plan = {"spacing_mm": 3.0, "depth_mm": 2.0, "frames": 1}
    sensor = lens_free("gelsight_mini")
    folder, record = shared_across_workers(
        tmp_path_factory,
        "paper_mini",
        lambda folder: collect_and_register(folder, sensor, plan, 3, PAPER_DATASET),
    )
    return bench_scene(sensor, plan, 3, dataset=PAPER_DATASET), folder, record


def write_untrained_model(path, preset, blank, model=None, px_per_mm=19.58, **keys) -> str:
    """A model.pt of `model` (default: `preset` freshly built, seeded) on `blank` (H, W, 3): what
    inference needs and `keys` beside (a registration, a dome, ...). Returns the path as a string."""
    import numpy as np
    import torch

    from threedcal.model.checkpoint import (
        FORMAT,
        FORMAT_VERSION,
        OUR_NORMALISATION,
        save_checkpoint,
    )
    from threedcal.model.presets import build_model, preset_args

    torch.manual_seed(0)
    model = build_model(preset) if model is None else model
    checkpoint = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "preset": preset,
        "preset_args": preset_args(preset),
        "state_dict": model.state_dict(),
        "normalisation": dict(OUR_NORMALISATION),
        "blank": torch.from_numpy(np.asarray(blank, np.float32)),
        "px_per_mm": px_per_mm,
        "image_shape": list(np.shape(blank)[:2]),
    }
    save_checkpoint(path, {**checkpoint, **keys})
    return str(path)


def load_file_module(relative: str, name: str):
    """A repository script that is not a package module (workflow/cluster/*.py)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, REPO / relative)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
