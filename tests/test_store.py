import numpy as np
import pandas as pd
import pytest

from threedcal.collect.store import PointRecord, RawStore, open_raw
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
