"""Issue 22 on the simulated bench: resumes continue only what matches and come out
byte-identical; a bad fault name leaves nothing behind; the dataset stage reads a store whole."""

import shutil

import numpy as np
import pytest
from test_collect_bench import LABELS as BENCH_LABELS

from threedcal.collect.store import RawStore, SettingsMismatch, StoreError
from threedcal.collect.store_read import open_raw
from threedcal.dataset.build import build_collected
from threedcal.errors import ConfigError
from threedcal.study.config import validate_config
from threedcal.study.scene import dataset_settings
from threedcal.study.session import collect_scene

LABELS = (*BENCH_LABELS, "t_s", "hardware_s")  # a replayed resume keeps the timeline too


def scene(sensor="gelsight_mini", seed=4, **overrides):
    plan = (
        {"pattern": "cross", "spacing_mm": 2.0, "depths_mm": [1.0], "frames": 2}
        if sensor == "reskin"
        else {"spacing_mm": 4.0, "depth_mm": 1.0, "frames": 2, "touch_search": {"points": 1}}
    )
    raw = {"sensor": sensor, "printer": "ender3", "plan": plan, **overrides}
    return validate_config({"seed": seed, "scenes": {"s": raw}})["scenes"]["s"]


def interrupted(monkeypatch, config, path, after=4):
    """Collect `after` points, then Ctrl-C (KeyboardInterrupt) while the next one is pressed. No
    point is flushed before the stop (FLUSH_EVERY_S made huge): the stop must write them all."""
    from threedcal.collect import run

    probe = run._Run.probe

    def probe_then_stop(self, bar):
        capture = self.camera.capture

        def capture_or_stop(count):
            if self.pending and self.pending_from + len(self.pending) >= after:
                raise KeyboardInterrupt
            return capture(count)

        self.camera.capture = capture_or_stop
        try:
            probe(self, bar)
        finally:
            self.camera.capture = capture

    with monkeypatch.context() as patch:
        patch.setattr(run._Run, "probe", probe_then_stop)
        patch.setattr(run, "FLUSH_EVERY_S", 1e9)
        with pytest.raises(KeyboardInterrupt):
            collect_scene("s", config, path, progress=False)


def assert_identical(one, two, variable):
    a, b = open_raw(one), open_raw(two)
    np.testing.assert_array_equal(a[variable].values, b[variable].values)
    np.testing.assert_array_equal(a[f"blank_{variable}"].values, b[f"blank_{variable}"].values)
    for name in LABELS:
        np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)


@pytest.mark.parametrize("sensor, variable", [("gelsight_mini", "frames"), ("reskin", "readings")])
def test_resume_is_byte_identical_and_the_summary_counts_every_run(
    tmp_path, monkeypatch, sensor, variable
):
    """Repro: ReSkin resumes were not byte-identical; summary.json counted only the last run."""
    config = scene(sensor)
    whole = collect_scene("s", config, tmp_path / "whole.zarr", progress=False)
    interrupted(monkeypatch, config, tmp_path / "resumed.zarr")
    assert (
        RawStore.open_for_resume(tmp_path / "resumed.zarr", _plan(config)).first_uncaptured() == 4
    )
    resumed = collect_scene("s", config, tmp_path / "resumed.zarr", progress=False)
    assert_identical(tmp_path / "whole.zarr", tmp_path / "resumed.zarr", variable)
    assert resumed["points"] == whole["points"] and resumed["frames"] == whole["frames"]
    assert resumed["runs"] == 2 and whole["runs"] == 1
    # the interrupted run's time counts; the printer time is the whole plan's, once
    runs = open_raw(tmp_path / "resumed.zarr").attrs["runs"]
    assert runs[0]["points"] == 4 and runs[0]["stopped"].startswith("KeyboardInterrupt")
    assert resumed["duration_s"] == pytest.approx(sum(r["duration_s"] for r in runs), abs=0.01)
    assert resumed["estimated_hardware_s"] == pytest.approx(whole["estimated_hardware_s"], abs=0.1)


def _plan(config):
    from threedcal.study.session import prepare

    return prepare(config).plan


@pytest.mark.parametrize(
    "change, expected",
    [
        ({"probe": {"radius_mm": 3.0}}, "probe.radius_mm: 2.0 → 3.0"),
        ({"bench": {"seating_offset_mm": 0.2}}, "bench.seating_offset_mm: 0.4 → 0.2"),
        ("seed", "seed: 4 → 5"),
    ],
    ids=["probe", "seating", "seed"],
)
def test_a_partial_store_resumes_only_with_its_own_settings(
    tmp_path, monkeypatch, change, expected
):
    """Repro: a resume accepted points 0-21 from a 2 mm probe and the rest from a 3 mm one, or
    another seed or bench seating, while the store's attributes described the first."""
    path = tmp_path / "raw.zarr"
    interrupted(monkeypatch, scene(), path, after=2)
    before = sorted((p, p.stat().st_mtime_ns) for p in path.rglob("*") if p.is_file())
    other = scene(seed=5) if change == "seed" else scene(**change)
    with pytest.raises(SettingsMismatch) as exc:
        collect_scene("s", other, path, progress=False)
    assert expected in str(exc.value) and "2 of" in str(exc.value)
    assert sorted((p, p.stat().st_mtime_ns) for p in path.rglob("*") if p.is_file()) == before


def test_a_bad_fault_name_leaves_no_store(tmp_path):
    """Repro: a bad bench.faults name failed only after an empty store was created."""
    config = scene()
    config["bench"]["faults"] = "checksum,bogus"
    with pytest.raises(ConfigError, match="bench.faults: unknown fault kind.*'bogus'"):
        collect_scene("s", config, tmp_path / "raw.zarr", progress=False)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("out", ["file", "folder"])
def test_collect_cli_out_onto_something_else_is_refused(tmp_path, out, capsys):
    """Repro: `threedcal collect --out` onto an existing file gave a traceback."""
    import yaml

    from threedcal.cli import main

    config = tmp_path / "c.yaml"
    config.write_text(yaml.safe_dump({"scenes": {"s": {"sensor": "digit", "printer": "ender3"}}}))
    target = tmp_path / "target"
    if out == "file":
        target.write_text("precious")
    else:
        target.mkdir()
        (target / "notes.txt").write_text("precious")
    assert main(["collect", "--config", str(config), "--scene", "s", "--out", str(target)]) == 1
    err = capsys.readouterr().err
    assert f"{target}: exists and is" in err and "not a collection store" in err
    assert "Traceback" not in err
    assert (
        target.read_text() if out == "file" else (target / "notes.txt").read_text()
    ) == "precious"


@pytest.fixture(scope="module")
def small_store(tmp_path_factory):
    path = tmp_path_factory.mktemp("small") / "raw.zarr"
    config = scene(seed=2)
    collect_scene("s", config, path, progress=False)
    return path, config


# frame 6 is the seventh touch-search step (one frame each) ahead of the grid
@pytest.mark.parametrize(
    "array, words", [("frames", "point 6 (frames, frame 6)"), ("cmd_x_mm", "cmd_x_mm")]
)
def test_the_dataset_stage_refuses_a_store_with_a_missing_chunk(
    tmp_path, small_store, array, words
):
    """Repro: a missing frames chunk became a black training frame; a missing cmd_x_mm chunk ended
    in "registration needs >= 3 contacts". Both now stop before registration, naming the point."""
    source, config = small_store
    path = tmp_path / "raw.zarr"
    shutil.copytree(source, path)
    chunks = sorted((path / array / "c").rglob("*"), key=str)
    victim = (
        path / "frames/c/6/0/0/0" if array == "frames" else next(c for c in chunks if c.is_file())
    )
    victim.unlink()
    outputs = [tmp_path / n for n in ("ts", "splits.csv", "reg.json", "reg.png")]
    with pytest.raises(StoreError) as exc:
        build_collected(dataset_settings(config), path, *outputs, progress=False)
    assert str(path) in str(exc.value) and words in str(exc.value) and "missing" in str(exc.value)
    assert not any(o.exists() for o in outputs)


def test_a_store_killed_before_its_metadata_was_consolidated_is_consolidated_on_resume(
    tmp_path, monkeypatch
):
    """Repro: a kill between `finalize` marking the store complete and consolidating its metadata
    left a complete staging store that the resume moved into place unconsolidated (xarray then
    warned and read every array's metadata)."""
    import json
    import warnings

    config = scene()
    staging, final = tmp_path / ".partial" / "raw.zarr", tmp_path / "raw.zarr"

    def killed(self):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(RawStore, "consolidate", killed)
        with pytest.raises(KeyboardInterrupt):
            collect_scene("s", config, final, staging_path=staging, progress=False)
    assert not final.exists()
    assert json.loads((staging / "zarr.json").read_text()).get("consolidated_metadata") is None
    collect_scene("s", config, final, staging_path=staging, progress=False)
    assert json.loads((final / "zarr.json").read_text()).get("consolidated_metadata")
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert bool(open_raw(final).captured.all())
