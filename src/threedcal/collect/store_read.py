"""Reading a collection store back: whole and checked (every record and every chunk present and
decodable, or an error naming the store and the point), or lazily for a look."""

from __future__ import annotations

import json
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import zarr

from threedcal.collect.store import STORE_FORMAT, StoreError
from threedcal.errors import ConfigError


def collected_store(summary_path: str | Path) -> tuple[Path, str | None]:
    """The store a `collect` summary.json names, and the frame-settings digest it records."""
    summary_path = Path(summary_path)
    try:
        summary = json.loads(summary_path.read_text())
        return Path(summary["store"]), summary.get("frame_digest")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise StoreError(
            f"{summary_path}: not a collection summary naming its store ({_first_line(exc)}); "
            "rerun the `collect` stage"
        ) from None


def open_raw(path: str | Path):
    """The store as a lazy xarray Dataset (frames or readings with their per-frame label
    coordinates), for a look; the stages that use its data read it with `open_checked`."""
    import xarray as xr  # optional (the workflow extra): only reading a store back needs it

    path = Path(path)
    if not (path / "zarr.json").exists():
        raise ConfigError(f"{path}: not a Zarr store")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", category=UserWarning)
        return xr.open_zarr(path, consolidated=None)


def open_checked(path: str | Path, expect_digest: str | None = None, rows: int | None = None):
    """The whole store read into memory, or a StoreError naming the store and the point.

    `rows`: only the first that many plan rows (a quick calibration reads its store between
    rounds, before it is complete); a store finished early (`captured_rows`) is read that far.

    Checks, in order: a Zarr store, marked complete, holding the frame settings `expect_digest`
    (the digest summary.json recorded, when the store records one), every point captured, and every
    chunk of every array present and decodable. A store from an older threedcal (before every
    chunk was written) is checked the same way except that a missing chunk of a label array
    (which may just have equalled the fill value) is not an error.
    """
    import xarray as xr  # optional (the workflow extra): only reading a store back needs it

    path = Path(path)
    if not (path / "zarr.json").is_file():
        raise StoreError(
            f"{path}: no collection store there (no zarr.json); run the `collect` stage, or put "
            "the store back if it was moved"
        )
    try:
        group = zarr.open_group(str(path), mode="r")
        attrs = dict(group.attrs)
        names = sorted(group.array_keys())
    except Exception as exc:  # noqa: BLE001 - any failure to open is one message naming the store
        raise StoreError(f"{path}: not a readable collection store ({_first_line(exc)})") from None
    if rows is None and not attrs.get("complete", False):
        raise StoreError(
            f"{path}: the collection is not complete (complete=false); run `collect` again to finish it"
        )
    if rows is None and attrs.get("captured_rows") is not None:
        rows = int(attrs["captured_rows"])
    recorded = attrs.get("frame_digest")
    if expect_digest is not None and recorded is not None and recorded != expect_digest:
        raise StoreError(
            f"{path}: holds frames collected with settings digest {recorded}, but "
            f"collect/summary.json records {expect_digest}: the store was replaced after the summary "
            "was written; rerun the `collect` stage (it checks the store against the config)"
        )
    offsets = _stored_offsets(attrs)
    strict = int(attrs.get("store_format", 1)) >= STORE_FORMAT
    samples = {attrs.get("sample_variable", "frames"), attrs.get("blank_variable", "blank_frames")}
    if "captured" not in names:
        raise StoreError(
            f"{path}: has no `captured` record; it is not a threedcal collection store"
        )
    frame_stop = None if rows is None or offsets is None else int(offsets[rows])
    arrays = {
        name: _read_array(path, name, group[name], offsets, strict or name in samples, frame_stop)
        for name in names
    }
    captured = np.asarray(arrays["captured"], dtype=bool)
    missing = np.flatnonzero(~(captured if rows is None else captured[:rows]))
    if missing.size:
        raise StoreError(
            f"{path}: marked complete, but point(s) {_ranges(missing)} are not captured "
            f"({missing.size} of {arrays['captured'].size}); the store is damaged: recollect"
        )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", category=UserWarning)
        # a store still being collected has no consolidated metadata yet
        lazy = xr.open_zarr(path, consolidated=None if attrs.get("complete") else False)
    if frame_stop is not None:
        lazy = lazy.isel(frame=slice(0, frame_stop))
    variables = {
        name: variable.copy(deep=False, data=arrays[name])
        for name, variable in lazy.variables.items()
    }
    return xr.Dataset(
        {name: variables[name] for name in lazy.data_vars},
        coords={name: variables[name] for name in lazy.coords},
        attrs=lazy.attrs,
    )


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def _stored_offsets(attrs: Mapping[str, Any]) -> np.ndarray | None:
    frames = attrs.get("plan", {}).get("frames") if isinstance(attrs.get("plan"), Mapping) else None
    if not frames:
        return None
    return np.concatenate([[0], np.cumsum(np.asarray(frames, dtype=np.int64))])


def _ranges(values) -> str:
    """[1, 2, 3, 7] → '1–3, 7' (at most five runs, then a count)."""
    values = sorted(int(v) for v in values)
    runs: list[list[int]] = []
    for v in values:
        if runs and v == runs[-1][1] + 1:
            runs[-1][1] = v
        else:
            runs.append([v, v])
    text = [f"{a}" if a == b else f"{a}–{b}" for a, b in runs[:5]]
    if len(runs) > 5:
        text.append(f"... ({len(values)} in all)")
    return ", ".join(text)


def _chunk_place(name: str, array: zarr.Array, coords: tuple[int, ...], offsets) -> str:
    """Which frames and probe points a chunk holds, in words."""
    dims = array.metadata.dimension_names or ()
    if not dims or not array.shape:
        return f"array {name}"
    size = array.chunks[0]
    first = coords[0] * size
    last = min(first + size, array.shape[0]) - 1
    span = f"{first}" if first == last else f"{first}–{last}"
    if dims[0] == "frame":
        if offsets is not None:
            points = np.searchsorted(offsets, [first, last], side="right") - 1
            point = (
                f"point {points[0]}"
                if points[0] == points[1]
                else f"points {points[0]}–{points[1]}"
            )
            return f"{point} ({name}, frame {span})"
        return f"{name}, frame {span}"
    if dims[0] == "blank":
        return f"the blank (no-contact) frames ({name} {span})"
    if dims[0] == "plan_point":
        return f"points {span} ({name})"
    return f"{name} {span}"


def _read_array(
    path: Path, name: str, array: zarr.Array, offsets, check_missing: bool, frame_stop=None
):
    """Every chunk of `array`: present (when `check_missing`) and decodable, or a StoreError.
    `frame_stop`: a per-frame array is read only up to that frame."""
    grid = array.cdata_shape if array.size else ()
    per_frame = bool(array.shape) and tuple(array.metadata.dimension_names or ())[:1] == ("frame",)
    if frame_stop is not None and per_frame:
        grid = (-(-frame_stop // array.chunks[0]), *grid[1:])
    if check_missing:
        for coords in np.ndindex(*grid):
            key = array.metadata.encode_chunk_key(coords)
            if not (path / array.path / key).is_file():
                raise StoreError(
                    f"{path}: {_chunk_place(name, array, coords, offsets)}: chunk "
                    f"{array.path}/{key} is missing — the data was lost after it was written "
                    "(never read as black); restore the store from a backup or recollect"
                )
    try:
        return array[:frame_stop] if frame_stop is not None and per_frame else array[...]
    except Exception as whole:  # noqa: BLE001 - find the chunk that fails, to name it
        for coords in np.ndindex(*grid):
            try:
                array.get_block_selection(coords)
            except Exception as exc:  # noqa: BLE001 - a codec error of any kind
                key = array.metadata.encode_chunk_key(coords)
                raise StoreError(
                    f"{path}: {_chunk_place(name, array, coords, offsets)}: chunk "
                    f"{array.path}/{key} is corrupt or truncated ({_first_line(exc)}); restore "
                    "the store from a backup or recollect"
                ) from None
        raise StoreError(f"{path}: array {name} cannot be read ({_first_line(whole)})") from None
