"""The raw collection store: one Zarr v3 group per scene, readable with ``xr.open_zarr``.

Layout::

    frames   (frame, y, x, channel) uint8   one chunk per frame; coordinates per frame:
             point, rep, x_mm, y_mm, depth_mm (plan-relative, commanded),
             cmd_{x,y,z}_mm (printer frame), reported_{x,y,z}_mm (M114), t_s, hardware_s
    blank_frames (blank, y, x, channel) uint8   no-contact frames
    captured (plan_point,) bool             set only after a point's frames and labels are written;
                                            its attrs["runs"]: one record per collection run, kept
                                            up to date after every point (so a killed run counts)
    attrs                                   profiles, plan, seeds, versions, run metadata;
                                            frame_settings (what the frames depend on, canonical)
                                            and frame_digest (its sha256): a resume with other
                                            settings is refused, naming the keys that differ

A sensor that is not a camera stores its samples under another `SampleLayout`: a ReSkin store holds
``readings (frame, value) float32`` and ``blank_readings (blank, value)`` with the same per-frame
coordinates, plus a ``value`` coordinate naming each value (``bx0``, ``by0``, ...). The attribute
``sample_variable`` says which variable holds the samples.

The store is preallocated from the plan (chunks are written only when filled), so a crash or kill
loses at most the point being captured: a resumed run starts at the first point not `captured`.
Every chunk is written, even one that equals the fill value (``write_empty_chunks``), so a chunk
missing from a finished store is data lost, never a black frame: threedcal.collect.store_read reads a
store back whole (every record and every chunk) or raises an error naming the store and the point.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import shutil
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import zarr

from threedcal.errors import ConfigError, ThreedcalError
from threedcal.schema import canonical_json, plain

# 2: every chunk written (write_empty_chunks), frame settings recorded. 1 (no attribute): older stores.
STORE_FORMAT = 2
# Zarr writes every file to `<name>.<32 hex>.partial` and renames it into place; a process killed in
# between leaves that temporary file, never a torn `<name>`.
INTERRUPTED_WRITE = re.compile(r"\.[0-9a-f]{32}\.partial$")
WRITE_EVERY_CHUNK = {"array.write_empty_chunks": True}

PLAN_COORDS = {
    "point": "int32",
    "rep": "int32",
    "x_mm": "float64",
    "y_mm": "float64",
    "depth_mm": "float64",
}
MEASURED_COORDS = {
    "cmd_x_mm": "float64",
    "cmd_y_mm": "float64",
    "cmd_z_mm": "float64",
    "reported_x_mm": "float64",
    "reported_y_mm": "float64",
    "reported_z_mm": "float64",
    "t_s": "float64",
    "hardware_s": "float64",
}
FRAME_COORDS = {**PLAN_COORDS, **MEASURED_COORDS}


def plan_digest(plan: pd.DataFrame) -> str:
    """Identity of a plan, so a resume never mixes frames of two different plans in one store."""
    table = plan[["x_mm", "y_mm", "depth_mm", "frames"]].to_numpy(dtype=float)
    return hashlib.sha256(np.ascontiguousarray(table).tobytes()).hexdigest()[:16]


def frame_offsets(plan: pd.DataFrame) -> np.ndarray:
    """First frame index of each point (and the total as the last entry)."""
    return np.concatenate([[0], np.cumsum(plan["frames"].to_numpy(dtype=np.int64))])


@dataclass(frozen=True)
class SampleLayout:
    """How one sample (a frame, a magnetometer reading) is stored: names, dims, dtype, chunking."""

    variable: str = "frames"
    blank_variable: str = "blank_frames"
    dims: tuple[str, ...] = ("y", "x", "channel")
    dtype: str = "uint8"
    # Frames per chunk; a divisor of every point's frame count keeps each point in its own chunks.
    chunk_frames: int = 1
    value_names: tuple[str, ...] | None = None  # labels of the last dim, stored as a coordinate


IMAGE_LAYOUT = SampleLayout()


def readings_layout(value_names, plan: pd.DataFrame) -> SampleLayout:
    """Layout of a vector sensor (ReSkin): ``readings (frame, value) float32``, chunks aligned to points."""
    chunk = int(np.gcd.reduce(plan["frames"].to_numpy(dtype=np.int64)))
    return SampleLayout(
        variable="readings",
        blank_variable="blank_readings",
        dims=("value",),
        dtype="float32",
        chunk_frames=max(chunk, 1),
        value_names=tuple(value_names),
    )


@dataclass
class PointRecord:
    """What one probe point produced: K frames and their measured labels."""

    frames: np.ndarray  # (K, *sample_shape): frames (K, H, W, C) uint8 or readings (K, V)
    cmd_xyz: tuple[float, float, float]
    reported_xyz: tuple[float, float, float]
    t_s: np.ndarray  # (K,) capture times, seconds since the run started
    hardware_s: (
        np.ndarray
    )  # (K,) printer clock at capture (the motion model's, on the simulated bench)
    # the depth commanded when the run chose it (a bisecting touch search's); None: the plan's
    depth_mm: float | None = None


class StoreError(ThreedcalError):
    """A collection store is missing, incomplete, damaged or holds other settings than expected."""


class SettingsMismatch(ConfigError):
    """A store was collected with other settings than the config asks for now."""


def settings_digest(settings: Mapping[str, Any]) -> str:
    return hashlib.sha256(canonical_json(settings).encode()).hexdigest()[:16]


def flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """{"a": {"b": 1}} → {"a.b": 1}: the keys a message can name."""
    if isinstance(value, Mapping) and value:
        out: dict[str, Any] = {}
        for key in sorted(value):
            out.update(flatten(value[key], f"{prefix}.{key}" if prefix else str(key)))
        return out
    return {prefix: value}


def describe_changes(old: Mapping[str, Any], new: Mapping[str, Any], limit: int = 12) -> list[str]:
    """`key: old → new` for every setting that differs (at most `limit`, then a count)."""
    before, after = (
        flatten(json.loads(canonical_json(old))),
        flatten(json.loads(canonical_json(new))),
    )
    lines = []
    for key in sorted(set(before) | set(after)):
        a, b = before.get(key, "(absent)"), after.get(key, "(absent)")
        if a != b:
            lines.append(f"{key}: {_short(a)} → {_short(b)}")
    if len(lines) > limit:
        lines = lines[:limit] + [f"... and {len(lines) - limit} more"]
    return lines


def _short(value: Any) -> str:
    text = json.dumps(value) if not isinstance(value, str) else value
    return text if len(text) <= 60 else text[:57] + "..."


class RawStore:
    """Create, resume and fill a collection store."""

    def __init__(self, path: str | Path, group: zarr.Group, plan: pd.DataFrame):
        self.path = Path(path)
        self.group = group
        self.plan = plan
        self.offsets = frame_offsets(plan)
        self.variable = group.attrs.get("sample_variable", "frames")
        self.blank_variable = group.attrs.get("blank_variable", "blank_frames")
        self._arrays: dict[str, zarr.Array] = {}

    def _array(self, name: str) -> zarr.Array:
        """An array of the group, opened once (opening reads its metadata: ms per call), set to
        write every chunk (a frame equal to the fill value must still be on disk)."""
        if name not in self._arrays:
            with zarr.config.set(WRITE_EVERY_CHUNK):
                self._arrays[name] = self.group[name]
        return self._arrays[name]

    @classmethod
    def create(
        cls,
        path: str | Path,
        plan: pd.DataFrame,
        sample_shape: tuple[int, ...],
        n_blank: int,
        attrs: Mapping[str, Any],
        layout: SampleLayout = IMAGE_LAYOUT,
        settings: Mapping[str, Any] | None = None,
    ) -> RawStore:
        """A new, empty store. `settings`: what the frames depend on (recorded with its digest)."""
        path = Path(path)
        if path.exists():
            raise ConfigError(f"{path}: already exists; refusing to overwrite collected data")
        # Build the empty store beside its place and rename it there: a kill during creation
        # leaves no half-made store for a resume to trip over (the leftover holds no data).
        building = path.with_name(path.name + ".creating")
        if building.exists():
            shutil.rmtree(building)
        record = dict(attrs)
        if settings is not None:
            record["frame_settings"] = json.loads(canonical_json(settings))
            record["frame_digest"] = settings_digest(settings)
        with zarr.config.set(WRITE_EVERY_CHUNK):
            cls._build(building, plan, tuple(sample_shape), n_blank, record, layout)
        os.replace(building, path)
        return cls(path, zarr.open_group(str(path), mode="r+"), plan)

    @staticmethod
    def _build(path: Path, plan, sample_shape, n_blank: int, attrs, layout: SampleLayout) -> None:
        offsets = frame_offsets(plan)
        n_frames = int(offsets[-1])
        if len(sample_shape) != len(layout.dims):
            raise ValueError(f"sample shape {sample_shape} does not match the dims {layout.dims}")
        if layout.value_names is not None and len(layout.value_names) != sample_shape[-1]:
            raise ValueError(
                f"{len(layout.value_names)} value names for {sample_shape[-1]} values per sample"
            )
        group = zarr.open_group(str(path), mode="w-", zarr_format=3)
        layout_attrs = {
            "sample_variable": layout.variable,
            "blank_variable": layout.blank_variable,
            "store_format": STORE_FORMAT,
        }
        group.attrs.update(
            json.loads(
                json.dumps(
                    {**attrs, **layout_attrs, "plan_digest": plan_digest(plan), "complete": False}
                )
            )
        )
        chunk = max(1, min(layout.chunk_frames, n_frames))
        samples = group.create_array(
            layout.variable,
            shape=(n_frames, *sample_shape),
            dtype=layout.dtype,
            chunks=(chunk, *sample_shape),
            fill_value=0,
            dimension_names=["frame", *layout.dims],
        )
        samples.attrs["coordinates"] = " ".join(FRAME_COORDS)
        group.create_array(
            layout.blank_variable,
            shape=(n_blank, *sample_shape),
            dtype=layout.dtype,
            chunks=(max(1, min(layout.chunk_frames, n_blank)), *sample_shape),
            fill_value=0,
            dimension_names=["blank", *layout.dims],
        )
        if layout.value_names is not None:
            # Variable-length UTF-8: the string type Zarr v3 specifies (fixed-width ones warn).
            names = group.create_array(
                layout.dims[-1],
                shape=(len(layout.value_names),),
                dtype=str,
                dimension_names=[layout.dims[-1]],
            )
            names[:] = np.asarray(layout.value_names, dtype=object)
        point_of_frame = np.repeat(np.arange(len(plan)), plan["frames"].to_numpy())
        rep = np.arange(n_frames) - offsets[:-1][point_of_frame]
        plan_values = {
            "point": point_of_frame,
            "rep": rep,
            "x_mm": plan["x_mm"].to_numpy(float)[point_of_frame],
            "y_mm": plan["y_mm"].to_numpy(float)[point_of_frame],
            "depth_mm": plan["depth_mm"].to_numpy(float)[point_of_frame],
        }
        for name, dtype in FRAME_COORDS.items():
            data = plan_values.get(name, np.full(n_frames, np.nan))
            group.create_array(name, data=np.asarray(data, dtype=dtype), dimension_names=["frame"])
        captured = group.create_array(
            "captured", data=np.zeros(len(plan), dtype=bool), dimension_names=["plan_point"]
        )
        captured.attrs["runs"] = []

    @classmethod
    def open_for_resume(
        cls, path: str | Path, plan: pd.DataFrame, settings: Mapping[str, Any] | None = None
    ) -> RawStore:
        """An existing store, to be completed. With `settings` (what the frames depend on now),
        a store recorded with other settings is refused, naming every key that differs."""
        path = Path(path)
        try:
            group = zarr.open_group(str(path), mode="r+")
        except (FileNotFoundError, NotADirectoryError, zarr.errors.GroupNotFoundError) as exc:
            raise ConfigError(f"{path}: not a threedcal collection store") from exc
        except (OSError, ValueError, json.JSONDecodeError) as exc:
            raise ConfigError(f"{path}: not a readable collection store ({exc})") from exc
        store = cls(path, group, plan)
        discard_interrupted_writes(path)
        if settings is not None:
            check_settings(path, group.attrs, settings, store.progress())
        stored = group.attrs.get("plan_digest")
        if stored != plan_digest(plan):
            raise SettingsMismatch(
                f"{path}: this store was collected with a different plan (digest {stored}, now "
                f"{plan_digest(plan)}); move it away or choose another output — it is never overwritten"
            )
        return store

    @property
    def captured(self) -> np.ndarray:
        return self._array("captured")[:]

    def progress(self) -> str:
        """`21 of 90 points captured` (for messages)."""
        try:
            done = int(self.captured.sum())
        except Exception:  # noqa: BLE001 - a message must not fail on a damaged store
            return "its progress unreadable"
        return f"{done} of {len(self.plan)} points captured"

    def first_uncaptured(self) -> int | None:
        missing = np.flatnonzero(~self.captured)
        return int(missing[0]) if missing.size else None

    def has_blank(self) -> bool:
        return bool(self.group.attrs.get("blank_captured", False))

    def write_blank(self, frames: np.ndarray) -> None:
        self._array(self.blank_variable)[: len(frames)] = frames
        self.group.attrs["blank_captured"] = True

    @property
    def complete(self) -> bool:
        return bool(self.group.attrs.get("complete", False))

    # ---- run records: kept on the small `captured` array, rewritten after every point -------
    @property
    def runs(self) -> list[dict[str, Any]]:
        captured = self._array("captured")
        if "runs" in captured.attrs:
            return list(captured.attrs["runs"])
        return list(self.group.attrs.get("runs", []))  # stores written before run records moved

    def record_run(self, record: Mapping[str, Any], new: bool = False) -> None:
        """Start (`new`) or update the record of the current run."""
        runs = self.runs
        entry = json.loads(json.dumps(dict(record), default=plain))
        if new or not runs:
            runs.append(entry)
        else:
            runs[-1] = entry
        self._array("captured").attrs["runs"] = runs

    def write_point(self, point: int, record: PointRecord) -> None:
        """Frames, then labels, then the `captured` flag: a crash in between redoes this point."""
        self.write_points(point, [record])

    def write_points(self, first: int, records: Sequence[PointRecord]) -> None:
        """Consecutive points from `first`, one write per array: frames, then labels, then their
        `captured` flags. A crash in between redoes them all. Each zarr write costs about a
        millisecond whatever its size, so the collection loop hands over several points at a time
        (`threedcal.collect.run`)."""
        if not records:
            return
        stop_point = first + len(records)
        start, stop = int(self.offsets[first]), int(self.offsets[stop_point])
        counts = np.diff(self.offsets[first : stop_point + 1]).astype(int)
        for point, record, count in zip(range(first, stop_point), records, counts, strict=True):
            if record.frames.shape[0] != count:
                raise ValueError(
                    f"point {point}: plan wants {count} frames, got {record.frames.shape[0]}"
                )
        frames = (
            records[0].frames if len(records) == 1 else np.concatenate([r.frames for r in records])
        )
        self._array(self.variable)[start:stop] = frames
        measured = {
            "cmd_x_mm": [r.cmd_xyz[0] for r in records],
            "cmd_y_mm": [r.cmd_xyz[1] for r in records],
            "cmd_z_mm": [r.cmd_xyz[2] for r in records],
            "reported_x_mm": [r.reported_xyz[0] for r in records],
            "reported_y_mm": [r.reported_xyz[1] for r in records],
            "reported_z_mm": [r.reported_xyz[2] for r in records],
        }
        for name, per_point in measured.items():
            self._array(name)[start:stop] = np.repeat(np.asarray(per_point, dtype=float), counts)
        chosen = [r.depth_mm is not None for r in records]
        if any(chosen):  # depths the run chose: stored where the plan's placeholder was
            depth = self._array("depth_mm")[start:stop]
            for k, (record, count) in enumerate(zip(records, counts, strict=True)):
                if record.depth_mm is not None:
                    at = int(self.offsets[first + k]) - start
                    depth[at : at + count] = record.depth_mm
            self._array("depth_mm")[start:stop] = depth
        for name in ("t_s", "hardware_s"):
            per_frame = [
                np.broadcast_to(np.asarray(getattr(r, name), dtype=float), (c,))
                for r, c in zip(records, counts, strict=True)
            ]
            self._array(name)[start:stop] = np.concatenate(per_frame)
        self._array("captured")[first:stop_point] = True

    def read_point(self, point: int) -> np.ndarray:
        """The samples stored for one point (a replayed run compares against them)."""
        start, stop = int(self.offsets[point]), int(self.offsets[point + 1])
        return self._array(self.variable)[start:stop]

    def read_depth(self, point: int) -> float:
        """The depth stored for one point: the plan's, or the one the run chose for it."""
        return float(self._array("depth_mm")[int(self.offsets[point])])

    def read_blank(self) -> np.ndarray:
        return self._array(self.blank_variable)[:]

    def finalize(
        self, extra_attrs: Mapping[str, Any] | None = None, rows: int | None = None
    ) -> None:
        """Mark the store complete: every plan row captured, or with `rows` (a quick calibration
        that stopped early) its first `rows`, recorded as `captured_rows` (readers stop there)."""
        missing = self.first_uncaptured()
        if missing is not None and (rows is None or missing < rows):
            raise RuntimeError(f"{self.path}: cannot finalize, point {missing} is not captured")
        extra = {**(extra_attrs or {}), "runs": self.runs, "complete": True}
        if rows is not None:
            extra["captured_rows"] = int(rows)
        self.group.attrs.update(json.loads(json.dumps(extra, default=plain)))
        self.consolidate()

    def consolidate(self) -> None:
        """Write the consolidated metadata (what xarray opens the store by). `finalize` ends with
        it; a run killed between marking the store complete and this step leaves it without, so a
        resume that finds a complete store writes it again (it is the same every time)."""
        with (
            warnings.catch_warnings()
        ):  # "consolidated metadata is not in the v3 spec" — xarray reads it
            warnings.simplefilter("ignore", category=UserWarning)
            zarr.consolidate_metadata(str(self.path))


def discard_interrupted_writes(path: Path) -> list[Path]:
    """Remove the temporary files of writes a kill interrupted, so that a resumed store finishes
    with the same files as one never interrupted. Their targets are intact (the rename never
    happened), so nothing is lost: the point being written is redone, being not yet `captured`."""
    leftovers = sorted(p for p in Path(path).rglob("*.partial") if INTERRUPTED_WRITE.search(p.name))
    for leftover in leftovers:
        leftover.unlink()
    if leftovers:
        logging.getLogger("threedcal").info(
            "%s: removed %d temporary file(s) of a write the last run's end interrupted (%s)",
            path,
            len(leftovers),
            ", ".join(str(p.relative_to(path)) for p in leftovers[:3]),
        )
    return leftovers


def check_settings(
    path: Path,
    attrs: Mapping[str, Any],
    settings: Mapping[str, Any],
    progress: str = "",
    *,
    finished: bool = False,
) -> None:
    """Refuse a store whose recorded frame settings differ from `settings`, naming each key
    (old → new) and saying how to go on. A store never records them if an older threedcal made
    it: a partial one is then refused, a finished one accepted on its plan (checked by the caller)."""
    recorded = attrs.get("frame_settings")
    if recorded is None:
        if finished:
            return
        raise SettingsMismatch(
            f"{path}: made by an older threedcal that did not record what its frames depend on "
            f"({progress or 'progress unknown'}), so it cannot be resumed safely; move it away to "
            "start over (it is never deleted)"
        )
    if attrs.get("frame_digest") == settings_digest(settings):
        return
    changes = describe_changes(recorded, settings)
    keep = (
        "To use it, restore those settings. To collect anew, move it away first"
        if finished
        else "Restore those settings to resume it, or move it away to start over"
    )
    raise SettingsMismatch(
        f"{path} ({progress}) was collected with other settings than the config has now "
        "(recorded → config):\n  "
        + "\n  ".join(changes)
        + f"\n{keep} (e.g. `mv {path} {path}.old`); it is never deleted or overwritten"
    )


def store_summary(store: RawStore) -> dict[str, Any]:
    """summary.json's counts for the whole store, every run included (interrupted ones too):
    points and frames captured, wall time spent, frames written per second, and the printer time
    of the plan — the last run's own for a replayed simulated run (it went through all of it), the
    sum of runs since the last start from scratch otherwise."""
    runs = store.runs
    captured = np.asarray(store.captured, dtype=bool)
    per_point = np.diff(store.offsets)
    duration = float(sum(r.get("duration_s", 0.0) for r in runs))
    written = int(sum(r.get("frames", 0) for r in runs))
    starts = [i for i, r in enumerate(runs) if r.get("replayed", i == 0)]
    hardware = float(sum(r.get("hardware_s", 0.0) for r in runs[max(starts or [0]) :]))
    return {
        "points": int(captured.sum()),
        "frames": int(per_point[captured].sum()),
        "duration_s": round(duration, 3),
        "frames_per_s": round(written / duration, 2) if duration > 0 else None,
        "estimated_hardware_s": round(hardware, 1),
        "runs": len(runs),
    }
