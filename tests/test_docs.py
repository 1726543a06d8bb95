"""Every Python and shell example in README.md and docs/**/*.md runs, so an example that breaks fails CI.

Blocks run in page order in a scratch workspace that links the repository's files (`.venv`,
`Snakefile`, `config/`, `data/`, ...); a page's Python blocks share one namespace, and a YAML block
whose first line is `# name.yaml` is that file: the repository's copy must equal it, or, where the
repository has none, it is written for the commands after it. A comment on
the line before a fence changes how its block runs:

    <!-- docs-test: skip: REASON -->      not run (real hardware, a 45-minute study); REASON required
    <!-- docs-test: setup: CODE -->       Python run first, unseen by the reader (e.g. `frame = ...`)
    <!-- docs-test: dry-run -->           each `snakemake` and `make` line runs with `-n` (what it
                                          would do: the default study takes 20 minutes)
    <!-- docs-test: serve: URL -->        the block's one command is a server (`threedcal rig`):
                                          started in the background, waited for until URL answers,
                                          used by the blocks after it, stopped with Ctrl-C (SIGINT)
                                          at the end of the page, where it must exit 0

Helpers a setup line may call: `tiny_checkpoint(path)` trains a tiny model there (seconds) and
`sim_frame()` renders a DIGIT ball press.
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
LINKED = ("Snakefile", "rules", "scripts", "workflow", "config", "config.yaml", "data", "src")
LINKED += ("benchmarks", "tests", "Makefile", "pyproject.toml")
FENCE = re.compile(
    r"(?:<!-- docs-test: (?P<directive>.*?) -->\n)?```(?P<lang>\w*)\n(?P<body>.*?)```", re.S
)


def blocks(page: Path) -> list[dict]:
    text = page.read_text()
    out = []
    for m in FENCE.finditer(text):
        directive = (m.group("directive") or "").strip()
        kind, _, arg = directive.partition(":")
        out.append(
            {
                "lang": m.group("lang"),
                "body": m.group("body"),
                "line": text[: m.start("lang")].count("\n") + 1,
                "directive": kind.strip(),
                "arg": arg.strip(),
            }
        )
    return out


def tiny_checkpoint(path: str) -> None:
    """A DIGIT model trained for one epoch on six simulated ball presses (seconds, CPU)."""
    import pandas as pd

    from threedcal.dataset.trainset import TrainingSet
    from threedcal.model.train import train
    from threedcal.model.train_settings import TrainSettings
    from threedcal.profiles import load_profile
    from threedcal.sim.bench import nominal_affine
    from threedcal.sim.indenters import Sphere
    from threedcal.sim.optics import GelSimulator

    sim = GelSimulator(load_profile("sensor", "digit"), seed=0)
    centres = [(80, 110), (160, 110), (120, 160), (80, 210), (160, 210), (120, 250)]
    frames = [
        sim.render(Sphere(2.0), center_px=c, rotation_deg=0, depth_mm=0.8, frame_index=i + 1)
        for i, c in enumerate(centres)
    ]
    n = len(centres)
    samples = pd.DataFrame(
        {
            "frame": range(n),
            "point": range(n),
            "center_x_px": [c[0] for c in centres],
            "center_y_px": [c[1] for c in centres],
            "depth_mm": [0.8] * n,
            "eval_radius_px": [30.0] * n,
            "split": ["train"] * (n - 2) + ["val"] * 2,
            "min_p": [20] * (n - 2) + [0, 0],
        }
    )
    blank = sim.blank(frame_index=0)
    px_per_mm = sim.px_per_mm
    profile = load_profile("sensor", "digit")
    # what a collected scene's dataset stage records: the gel's dome and the registration (here the
    # nominal seating), so the docs' printer-frame examples run
    meta = {
        "dome": profile["gel"]["dome"],
        "registration": {
            "affine_px_per_mm": nominal_affine(profile).tolist(),
            "contact_z_mm": float(profile["mount"]["z_touch_mm"]),
        },
    }
    trainset = TrainingSet(
        np.stack(frames), blank, samples, px_per_mm=px_per_mm, sphere_radius_mm=2.0, meta=meta
    )
    settings = TrainSettings.of(
        preset="compact_tiny",
        epochs_base=1,
        patch_px=32,
        contact_patches=2,
        background_patches=1,
        torch_threads=1,
    )
    out = Path(path).parent
    train(trainset, out, 80, settings, progress=False)
    assert (out / "model.pt").is_file()


def sim_frame() -> np.ndarray:
    from threedcal.profiles import load_profile
    from threedcal.sim.indenters import Sphere
    from threedcal.sim.optics import GelSimulator

    sim = GelSimulator(load_profile("sensor", "digit"), seed=1)
    return sim.render(
        Sphere(2.0), center_px=(120, 160), rotation_deg=0, depth_mm=1.0, frame_index=1
    )


@pytest.fixture
def workspace(tmp_path, monkeypatch):
    for name in (".venv", *LINKED):
        if (REPO / name).exists():
            (tmp_path / name).symlink_to(REPO / name)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def run_shell(block: dict, page: Path, workspace: Path) -> None:
    for line in block["body"].splitlines():
        command = line.split(" #", 1)[0].strip()
        if not command or command.startswith("#"):
            continue
        words = shlex.split(command)
        if block["directive"] == "dry-run" and "snakemake" in words[0]:
            words.append("-n")
        elif words[0] == "make":
            # a real `make` here would set up .venv through the scratch dir's link to it
            assert block["directive"] == "dry-run", (
                f"{page.name}:{block['line']}: make, not dry-run"
            )
            words.insert(1, "-n")
        done = subprocess.run(
            words,
            cwd=workspace,
            capture_output=True,
            text=True,
            timeout=240,
            env={**os.environ, "PYTHONHASHSEED": "0"},
        )
        where = f"{page.relative_to(REPO)}:{block['line']}: {command}"
        assert done.returncode == 0, f"{where}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"


def start_server(block: dict, page: Path, workspace: Path) -> subprocess.Popen:
    """The block's one command, started in the background; returned once `arg` (a URL) answers."""
    lines = [line.split(" #", 1)[0].strip() for line in block["body"].splitlines()]
    lines = [line for line in lines if line and not line.startswith("#")]
    where = f"{page.relative_to(REPO)}:{block['line']}"
    assert len(lines) == 1, f"{where}: a served block holds one command"
    log = (workspace / f"server-{block['line']}.log").open("w")
    server = subprocess.Popen(
        shlex.split(lines[0]), cwd=workspace, stdout=log, stderr=subprocess.STDOUT, text=True
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        assert server.poll() is None, f"{where}: exited\n{Path(log.name).read_text()[-2000:]}"
        try:
            with urllib.request.urlopen(block["arg"], timeout=5):
                return server
        except (urllib.error.URLError, ConnectionError):
            time.sleep(0.2)
    server.kill()
    raise AssertionError(f"{where}: {block['arg']} did not answer in 120 s")


def stop_server(server: subprocess.Popen) -> None:
    """Ctrl-C, as a user stops it; it must then exit cleanly."""
    server.send_signal(signal.SIGINT)
    try:
        code = server.wait(timeout=60)
    except subprocess.TimeoutExpired:
        server.kill()
        raise AssertionError(f"{server.args}: still running 60 s after Ctrl-C") from None
    assert code == 0, f"{server.args}: exited {code} after Ctrl-C"


# pages whose examples run whole stages (several seconds each): `make test-long`
LONG_PAGES = {
    f"docs/{name}.md"
    for name in (
        "tutorials/real-sensor",
        "how-to/import-data",
        "how-to/deploy",
        "how-to/rerun-a-stage",
        "how-to/slurm",
        "how-to/calibrate-quickly",
        "how-to/add-a-profile",
        "explanation/objects",
        "explanation/real-data",
        "explanation/reskin",
    )
}


@pytest.mark.slow  # a page dry-runs the default study: tens of seconds
@pytest.mark.parametrize(
    "page",
    [
        pytest.param(page, marks=[pytest.mark.long] * (str(page.relative_to(REPO)) in LONG_PAGES))
        for page in PAGES
    ],
    ids=lambda p: str(p.relative_to(REPO)),
)
def test_page_examples_run(page, workspace):
    servers: list[subprocess.Popen] = []
    try:
        run_page(page, workspace, servers)
    finally:
        for server in servers:
            if server.poll() is None:
                stop_server(server)


def run_page(page: Path, workspace: Path, servers: list) -> None:
    namespace: dict = {"tiny_checkpoint": tiny_checkpoint, "sim_frame": sim_frame}
    for block in blocks(page):
        where = f"{page.relative_to(REPO)}:{block['line']}"
        if block["directive"] == "skip":
            assert block["arg"], f"{where}: a skipped example must say why"
            continue
        assert block["directive"] in ("", "setup", "dry-run", "serve"), (
            f"{where}: {block['directive']!r}"
        )
        if block["directive"] == "serve":
            servers.append(start_server(block, page, workspace))
            continue
        if block["lang"] == "yaml":
            first = block["body"].splitlines()[0]
            data = yaml.safe_load(block["body"])  # every YAML example parses
            name = re.match(r"#\s*(\S+\.ya?ml)\b", first.strip())
            if name and (REPO / name.group(1)).is_file():
                assert (REPO / name.group(1)).read_text() == block["body"], f"{where}: differs"
            elif name:
                (workspace / name.group(1)).write_text(block["body"])
            assert data is not None, where
            continue
        if block["directive"] == "setup":
            exec(compile(block["arg"], f"{where} (setup)", "exec"), namespace)  # noqa: S102
        if block["lang"] == "python":
            exec(compile(block["body"], where, "exec"), namespace)  # noqa: S102
        elif block["lang"] == "sh":
            run_shell(block, page, workspace)


def test_every_runnable_language_is_covered():
    """A fence in another language would silently escape this test: only these are allowed."""
    for page in PAGES:
        for block in blocks(page):
            assert block["lang"] in ("", "python", "sh", "yaml", "text"), (
                f"{page.relative_to(REPO)}:{block['line']}: ```{block['lang']}"
            )
