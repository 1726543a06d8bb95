import numpy as np
import pandas as pd
import pytest

from threedcal.collect.store import (
    PointRecord,
    RawStore,
    SettingsMismatch,
    StoreError,
    settings_digest,
    store_summary,
)
from threedcal.collect.store_read import open_checked, open_raw
from threedcal.errors import ConfigError

PLAN = pd.DataFrame(
    {
        "x_mm": [0.0, 1.0, 2.0],
        "y_mm": [0.0, 0.0, 1.0],
        "depth_mm": [1.0, 1.2, 1.4],
        "frames": [2, 1, 3],
    }
)
SHAPE = (6, 5, 3)


def record(point, k):
    return PointRecord(
        frames=np.full((k, *SHAPE), 10 * (point + 1), np.uint8),
        cmd_xyz=(100.0 + point, 50.0, 130.0),
        reported_xyz=(100.0 + point, 50.0, 130.01),
        t_s=np.arange(k, dtype=float),
        hardware_s=np.arange(k, dtype=float) + 100,
    )


def test_store_round_trip_through_xarray(tmp_path):
    store = RawStore.create(
        tmp_path / "raw.zarr",
        PLAN,
        SHAPE,
        n_blank=2,
        attrs={"seed": 3, "plan": PLAN.to_dict("list")},
    )
    store.write_blank(np.full((2, *SHAPE), 7, np.uint8))
    for p, k in enumerate(PLAN.frames):
        store.write_point(p, record(p, k))
    store.finalize({"duration_s": 1.5})
    ds = open_raw(tmp_path / "raw.zarr")
    assert ds.frames.shape == (6, *SHAPE) and ds.frames.dtype == np.uint8
    assert ds.point.values.tolist() == [0, 0, 1, 2, 2, 2]
    assert ds.rep.values.tolist() == [0, 1, 0, 0, 1, 2]
    np.testing.assert_allclose(ds.depth_mm.values, [1.0, 1.0, 1.2, 1.4, 1.4, 1.4])
    np.testing.assert_allclose(ds.reported_z_mm.values, 130.01)
    assert (ds.frames.where(ds.point == 2, drop=True) == 30).all()
    assert (ds.blank_frames == 7).all()
    assert ds.attrs["complete"] is True and ds.attrs["seed"] == 3 and ds.attrs["duration_s"] == 1.5


def test_existing_store_is_never_overwritten(tmp_path):
    RawStore.create(tmp_path / "raw.zarr", PLAN, SHAPE, 1, {})
    with pytest.raises(ConfigError, match="refusing to overwrite"):
        RawStore.create(tmp_path / "raw.zarr", PLAN, SHAPE, 1, {})


def test_resume_continues_at_first_uncaptured_point(tmp_path):
    store = RawStore.create(tmp_path / "raw.zarr", PLAN, SHAPE, 1, {})
    store.write_point(0, record(0, 2))
    resumed = RawStore.open_for_resume(tmp_path / "raw.zarr", PLAN)
    assert resumed.first_uncaptured() == 1
    with pytest.raises(RuntimeError, match="point 1 is not captured"):
        resumed.finalize()


def _files(root):
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())


def test_a_resumed_store_drops_the_temporary_files_of_an_interrupted_write(tmp_path):
    """A kill between zarr's write of `captured/zarr.<hex>.partial` and its rename (the run record
    is rewritten after every point) must not leave that file in the finished store."""
    whole = RawStore.create(tmp_path / "whole.zarr", PLAN, SHAPE, 1, {})
    killed = RawStore.create(tmp_path / "killed.zarr", PLAN, SHAPE, 1, {})
    for store in (whole, killed):
        store.write_blank(np.full((1, *SHAPE), 7, np.uint8))
        store.write_point(0, record(0, 2))
    leftover = tmp_path / "killed.zarr/captured/zarr.5a9a89e6217943449ad1e57db67f99b5.partial"
    leftover.write_bytes(b'{"zarr_format": 3, "node_ty')  # torn: the kill came mid-write
    ours = tmp_path / "killed.zarr/notes.partial"  # not zarr's pattern: not ours to remove
    ours.write_text("kept")
    resumed = RawStore.open_for_resume(tmp_path / "killed.zarr", PLAN)
    assert not leftover.exists() and ours.read_text() == "kept"
    for store in (whole, resumed):
        store.write_point(1, record(1, 1))
        store.write_point(2, record(2, 3))
        store.finalize()
    ours.unlink()
    assert _files(tmp_path / "killed.zarr") == _files(tmp_path / "whole.zarr")
    assert open_checked(tmp_path / "killed.zarr").frames.shape[0] == 6


def test_resume_with_another_plan_is_refused(tmp_path):
    RawStore.create(tmp_path / "raw.zarr", PLAN, SHAPE, 1, {})
    other = PLAN.assign(depth_mm=[1.0, 1.2, 1.5])
    with pytest.raises(ConfigError, match="different plan"):
        RawStore.open_for_resume(tmp_path / "raw.zarr", other)


def test_wrong_frame_count_is_refused(tmp_path):
    store = RawStore.create(tmp_path / "raw.zarr", PLAN, SHAPE, 1, {})
    with pytest.raises(ValueError, match="plan wants 2 frames, got 1"):
        store.write_point(0, record(0, 1))
    assert store.first_uncaptured() == 0


# ---- issue 22: stores read back whole or not at all; resumes only with the same settings ----

SETTINGS = {"plan": {"points": 3}, "probe": {"radius_mm": 2.0}, "seed": 1, "bench": {"x": 0.4}}


def finished(tmp_path, settings=SETTINGS):
    store = RawStore.create(
        tmp_path / "raw.zarr", PLAN, SHAPE, 2, {"plan": PLAN.to_dict("list")}, settings=settings
    )
    store.write_blank(np.full((2, *SHAPE), 7, np.uint8))
    for p, k in enumerate(PLAN.frames):
        store.write_point(p, record(p, k))
    store.finalize()
    return tmp_path / "raw.zarr"


def test_checked_store_reads_back_whole(tmp_path):
    path = finished(tmp_path)
    ds = open_checked(path, expect_digest=settings_digest(SETTINGS))
    assert (
        ds.frames.shape == (6, *SHAPE) and (ds.frames.where(ds.point == 2, drop=True) == 30).all()
    )
    np.testing.assert_allclose(ds.cmd_x_mm.values, [100, 100, 101, 102, 102, 102])


def test_a_black_frame_is_stored_as_a_chunk_not_left_as_fill(tmp_path):
    store = RawStore.create(tmp_path / "raw.zarr", PLAN, SHAPE, 1, {}, settings=SETTINGS)
    black = record(0, 2)
    black.frames[:] = 0  # equal to the fill value: zarr would skip writing it by default
    store.write_point(0, black)
    assert (tmp_path / "raw.zarr/frames/c/0/0/0/0").is_file()
    assert (tmp_path / "raw.zarr/frames/c/1/0/0/0").is_file()


def test_missing_frames_chunk_is_an_error_naming_store_and_point(tmp_path):
    """Repro: a missing `frames` chunk read as an all-black frame and went into the training set."""
    path = finished(tmp_path)
    (path / "frames/c/4/0/0/0").unlink()  # frame 4 belongs to point 2
    with pytest.raises(StoreError) as exc:
        open_checked(path)
    message = str(exc.value)
    assert str(path) in message and "point 2 (frames, frame 4)" in message and "missing" in message


def test_corrupt_chunk_is_one_line_naming_store_and_point(tmp_path):
    """Repro: a truncated chunk gave a ~390-line codec traceback that did not name the file."""
    path = finished(tmp_path)
    chunk = path / "frames/c/2/0/0/0"
    chunk.write_bytes(chunk.read_bytes()[:5])
    with pytest.raises(StoreError) as exc:
        open_checked(path)
    message = str(exc.value)
    assert str(path) in message and "point 1 (frames, frame 2)" in message
    assert "corrupt or truncated" in message and "\n" not in message


def test_missing_label_chunk_is_named_not_read_as_fill(tmp_path):
    """Repro: a missing cmd_x_mm chunk ended in a misleading "registration needs >= 3 contacts"."""
    path = finished(tmp_path)
    for chunk in (path / "cmd_x_mm").rglob("c/*"):
        chunk.unlink()
    with pytest.raises(StoreError, match=r"cmd_x_mm.*is missing"):
        open_checked(path)


def test_incomplete_or_replaced_store_is_refused(tmp_path):
    store = RawStore.create(tmp_path / "raw.zarr", PLAN, SHAPE, 1, {}, settings=SETTINGS)
    store.write_point(0, record(0, 2))
    with pytest.raises(StoreError, match="not complete"):
        open_checked(tmp_path / "raw.zarr")
    path = finished(tmp_path / "b")
    with pytest.raises(StoreError, match="summary.json records 0123"):
        open_checked(path, expect_digest="0123")
    with pytest.raises(StoreError, match="no collection store there"):
        open_checked(tmp_path / "nowhere.zarr")


def test_resume_with_other_settings_is_refused_naming_each_key(tmp_path):
    """Repro: a resume accepted points from a 2 mm probe and then a 3 mm one, another seed, another
    bench seating — and the attributes still described the first."""
    store = RawStore.create(tmp_path / "raw.zarr", PLAN, SHAPE, 1, {}, settings=SETTINGS)
    store.write_point(0, record(0, 2))
    other = {**SETTINGS, "probe": {"radius_mm": 3.0}, "seed": 2, "bench": {"x": 0.5}}
    with pytest.raises(SettingsMismatch) as exc:
        RawStore.open_for_resume(tmp_path / "raw.zarr", PLAN, other)
    message = str(exc.value)
    for change in ("probe.radius_mm: 2.0 → 3.0", "seed: 1 → 2", "bench.x: 0.4 → 0.5"):
        assert change in message
    assert "1 of 3 points captured" in message and "mv " in message
    # key order is no difference
    same = {key: SETTINGS[key] for key in reversed(list(SETTINGS))}
    assert RawStore.open_for_resume(tmp_path / "raw.zarr", PLAN, same).first_uncaptured() == 1


def test_run_records_survive_a_kill_and_the_summary_counts_every_run(tmp_path):
    store = RawStore.create(tmp_path / "raw.zarr", PLAN, SHAPE, 1, {}, settings=SETTINGS)
    store.record_run({"points": 1, "frames": 2, "duration_s": 3.0, "hardware_s": 10.0}, new=True)
    store.write_point(0, record(0, 2))
    # the process dies here; the next run resumes (on hardware: no replay)
    again = RawStore.open_for_resume(tmp_path / "raw.zarr", PLAN, SETTINGS)
    again.record_run(
        {"points": 2, "frames": 4, "duration_s": 1.0, "hardware_s": 5.0, "replayed": False},
        new=True,
    )
    for p in (1, 2):
        again.write_point(p, record(p, PLAN.frames[p]))
    summary = store_summary(again)
    assert summary == {
        "points": 3,
        "frames": 6,
        "duration_s": 4.0,
        "frames_per_s": 1.5,
        "estimated_hardware_s": 15.0,
        "runs": 2,
    }
