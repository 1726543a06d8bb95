"""Issue 22 with real Snakemake runs: no Snakemake action deletes or overwrites a collection store.

A small scene (616 probe points, a few seconds: long enough that the collection writes a batch to
the store before it ends, see threedcal.collect.run.FLUSH_EVERY_S) collected through the workflow,
then: reordered config keys, a
`--forcerun collect`, a changed seed, Ctrl-C while collecting, Ctrl-C while the figures are drawn
and `--rerun-incomplete` — the store is never touched, and a real change stops naming the key.
"""

import copy
import os
import signal
import subprocess
import time

import pytest
import yaml
import zarr
from conftest import assert_same_array, snakemake, snakemake_command, snapshot

from threedcal.collect.store_read import open_raw
from threedcal.study.config import validate_config
from threedcal.study.session import collect_scene

SUMMARY = "results/t/collect/summary.json"
STORE = "results/t/raw.zarr"
CONFIG = {
    "seed": 1,
    "torch_threads": 1,
    "scenes": {
        "t": {
            "sensor": "gelsight_mini",
            "printer": "ender3",
            # one touch-search place (26 frames), not three: the store's protection, not the search;
            # 616 points, so that Ctrl-C can come after the first batch is written, before the last
            "plan": {
                "spacing_mm": 0.7,
                "depth_mm": 1.0,
                "frames": 1,
                "touch_search": {"points": 1},
            },
            "probe": {"radius_mm": 2.0},
        }
    },
}


def write(workdir, config):
    path = workdir / "config.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def captured(store) -> int:
    try:
        return int(zarr.open_group(str(store), mode="r")["captured"][:].sum())
    except Exception:  # not created yet, or caught mid-write
        return 0


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def interrupt(workdir, configfile, ready, *args, timeout=120.0):
    """Run Snakemake in its own process group and press Ctrl-C (SIGINT to the group, as a
    terminal does) as soon as `ready()` holds; returns Snakemake's exit code."""
    cmd = snakemake_command(workdir, configfile, SUMMARY, *args, cores=1)
    process = subprocess.Popen(
        cmd,
        cwd=workdir,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        # A child inherits an ignored or blocked SIGINT from the test process (whatever ran in this
        # worker before): give Snakemake a terminal's Ctrl-C back, or it and its job would carry on
        # through the interrupt (five tries in a row exited 0 inside the whole suite, never alone).
        preexec_fn=_default_sigint,
    )
    deadline = time.monotonic() + timeout
    while process.poll() is None and time.monotonic() < deadline and not ready():
        time.sleep(0.02)
    assert process.poll() is None, "the job finished before the interrupt: make the plan longer"
    # Freeze the group first, so the Ctrl-C reaches Snakemake and its job at the moment `ready()`
    # saw (the job cannot run on while a loaded machine delivers the signal); then let it go on.
    os.killpg(process.pid, signal.SIGSTOP)
    os.killpg(process.pid, signal.SIGINT)
    os.killpg(process.pid, signal.SIGCONT)
    return process.wait(timeout=120)


@pytest.mark.long
@pytest.mark.slow
def test_no_snakemake_action_deletes_or_overwrites_the_store(tmp_path):
    configfile = write(tmp_path, CONFIG)
    store, summary = tmp_path / STORE, tmp_path / SUMMARY

    # Ctrl-C while collecting, then --rerun-incomplete: the partial store is resumed, and the
    # result is the store of an uninterrupted collection.
    partial = tmp_path / "results/t/.partial/raw.zarr"
    assert interrupt(tmp_path, configfile, lambda: captured(partial) >= 3) != 0
    assert captured(partial) >= 3 and not store.exists()
    snakemake(tmp_path, configfile, SUMMARY, "--rerun-incomplete")
    scene = validate_config(CONFIG)["scenes"]["t"]
    collect_scene("t", scene, tmp_path / "reference.zarr", progress=False)
    a, b = open_raw(tmp_path / "reference.zarr"), open_raw(store)
    assert_same_array(a.frames.values, b.frames.values)
    assert_same_array(a.cmd_z_mm.values, b.cmd_z_mm.values)
    kept = snapshot(store)

    # Repro: swapping spacing_mm and depth_mm (same values) made Snakemake delete and recollect.
    reordered = copy.deepcopy(CONFIG)
    plan = reordered["scenes"]["t"]["plan"]
    reordered["scenes"]["t"]["plan"] = {
        k: plan[k] for k in ("touch_search", "depth_mm", "frames", "spacing_mm")
    }
    reordered["scenes"]["t"] = dict(reversed(list(reordered["scenes"]["t"].items())))
    result = snakemake(tmp_path, write(tmp_path, reordered), SUMMARY)
    assert "Nothing to be done" in result.stdout + result.stderr
    assert snapshot(store) == kept

    # --forcerun collect: the job runs and writes its summary again; the store is left alone.
    # Repro: Ctrl-C just after the store was in place (the figures being drawn), then
    # --rerun-incomplete, deleted the finished store and recollected from zero. Now it is kept.
    # Snakemake removes a forced job's outputs before it starts; the summary coming back (newer
    # than the one before) means the forced job has written it again and is drawing the figures.
    # Should the job still end before the Ctrl-C (Snakemake then exits 0), only the timing is
    # retried; each try must keep the store. The rerun then runs the same job to its end.
    before = summary.stat().st_mtime_ns
    rewritten = []
    for _ in range(5):
        seen_gone = []

        def drawing_figures(seen_gone=seen_gone) -> bool:
            if not summary.exists():
                seen_gone.append(True)
                return False
            if seen_gone:
                rewritten.append(summary.stat().st_mtime_ns)
            return bool(seen_gone)

        if interrupt(tmp_path, configfile, drawing_figures, "--forcerun", "collect") != 0:
            break
        assert snapshot(store) == kept
    else:
        pytest.fail("five Ctrl-Cs all landed after the collect job had ended")
    assert rewritten and rewritten[-1] > before, "the forced job did not write its summary again"
    assert snapshot(store) == kept
    snakemake(tmp_path, configfile, SUMMARY, "--rerun-incomplete")
    assert snapshot(store) == kept and summary.is_file()

    # Repro: a changed top-level seed deleted the store. Now: stop, name the key, say how.
    result = snakemake(tmp_path, write(tmp_path, {**CONFIG, "seed": 2}), SUMMARY, check=False)
    output = result.stdout + result.stderr
    assert result.returncode != 0
    assert "seed: 1 → 2" in output and f"mv {STORE} {STORE}.old" in output
    assert snapshot(store) == kept
