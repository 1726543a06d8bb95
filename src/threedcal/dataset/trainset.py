"""The model-ready dataset: frames, blank and per-frame sphere parameters, laid out for fast reads.

On disk (``results/{scene}/dataset/``)::

    frames.npy    (N, H, W, 3) uint8, memory-mapped when read: no image decoding per epoch
    blank.npy     (H, W, 3) float32, mean of the no-contact frames
    samples.csv   one row per frame: frame, point, center_x_px, center_y_px, depth_mm,
                  eval_radius_px, split (train/val), min_p (and min_p_r1 ... for replicates
                  1 .. R-1, threedcal.dataset.splits) — parsed once, into arrays
    meta.json     px_per_mm, sphere_radius_mm, max_slope_deg (null: no clamp), downscale, source,
                  dome (the profile's gel.dome the labels are measured from; null: flat), sensor
    unit_blanks.npy  (U, H, W, 3) float32, only in a set of several sensor units (pretraining):
                  each unit's own blank, and samples.csv's `unit` column says whose each frame is

Labels are not stored: they are the exact sphere gradients (each pixel's mean slope) of
(centre, depth, radius; the dome's on a domed gel) computed on demand, once per frame over the box
its press can reach and kept in memory for every window of it (threedcal.dataset.labels), so a sub-pixel registration change never leaves
stale label images behind. Inputs are (frame − blank)/255 as three channels plus two coordinate
channels, x and y of each pixel normalised to [-1, 1] over the full image — the network learns
position-dependent illumination from them, also when it trains on patches.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from threedcal.dataset.labels import (
    DEFAULT_MAX_SLOPE_DEG,
    LocalDome,
    check_max_slope,
    local_dome,
    sphere_gradients,
)
from threedcal.errors import ConfigError, FrameSizeError

# pandas (the workflow extra) loads where a table is made or read: pool_to needs none
if TYPE_CHECKING:
    import pandas as pd

SAMPLE_COLUMNS = (
    "frame",
    "point",
    "center_x_px",
    "center_y_px",
    "depth_mm",
    "eval_radius_px",
    "split",
    "min_p",
)
INPUT_CHANNELS = 5


def coordinate_channels(
    height: int, width: int, window: tuple[slice, slice] | None = None
) -> np.ndarray:
    """(2, h, w) float32: x and y of each pixel of `window`, normalised to [-1, 1] over the full image.

    A read-only view of the image's grid, built once per image size: a training job cuts tens of
    thousands of windows, and building the grid for each would cost about 1 s of its 28 s
    (P = 80 %).
    """
    grid = _coordinate_grid(int(height), int(width))
    return grid if window is None else grid[:, window[0], window[1]]


@functools.lru_cache(maxsize=8)
def _coordinate_grid(height: int, width: int) -> np.ndarray:
    ys = np.linspace(-1.0, 1.0, height, dtype=np.float32) if height > 1 else np.zeros(1, np.float32)
    xs = np.linspace(-1.0, 1.0, width, dtype=np.float32) if width > 1 else np.zeros(1, np.float32)
    grid_y, grid_x = np.meshgrid(ys, xs, indexing="ij")
    grid = np.stack([grid_x, grid_y])
    grid.flags.writeable = False
    return grid


def model_inputs(
    frame: np.ndarray, blank: np.ndarray, window: tuple[slice, slice] | None = None
) -> np.ndarray:
    """(5, h, w) float32 network input of one RGB uint8 frame (or a window of it)."""
    height, width = frame.shape[:2]
    region = (slice(None), slice(None)) if window is None else window
    diff = (frame[region].astype(np.float32) - blank[region]) / 255.0
    return np.concatenate([diff.transpose(2, 0, 1), coordinate_channels(height, width, window)])


def samples_table(
    point, center_px, depth_mm, eval_radius_px, split, min_p, **replicate_columns
) -> pd.DataFrame:
    """samples.csv's table (SAMPLE_COLUMNS, then min_p_r1 ...): one row per frame, numbered 0.."""
    import pandas as pd  # optional (workflow extra); the inference core imports this module

    center_px = np.asarray(center_px, dtype=float)
    return pd.DataFrame(
        {
            "frame": np.arange(len(center_px)),
            "point": point,
            "center_x_px": center_px[:, 0],
            "center_y_px": center_px[:, 1],
            "depth_mm": depth_mm,
            "eval_radius_px": eval_radius_px,
            "split": split,
            "min_p": min_p,
            **replicate_columns,
        }
    )


@dataclass
class TrainingSet:
    frames: np.ndarray  # (N, H, W, 3) uint8
    blank: np.ndarray  # (H, W, 3) float32
    samples: pd.DataFrame  # SAMPLE_COLUMNS
    px_per_mm: float
    sphere_radius_mm: float
    max_slope_deg: float | None = DEFAULT_MAX_SLOPE_DEG  # None: physical labels, no clamp
    meta: dict | None = None
    unit_blanks: np.ndarray | None = None  # (U, H, W, 3) float32: frames of several units

    def __post_init__(self) -> None:
        # sample i is frame i (training and scoring index frames by the sample's row): a set
        # whose `frame` column says otherwise would pair frames with other frames' labels
        if "frame" in self.samples.columns and not np.array_equal(
            self.samples["frame"].to_numpy(), np.arange(len(self.samples))
        ):
            raise ConfigError(
                "samples' `frame` column must number the rows 0..N-1 (sample i is frame i); "
                "take the frames in the samples' order and renumber them"
            )
        if len(self.samples) != len(self.frames):
            raise ConfigError(
                f"{len(self.samples)} samples for {len(self.frames)} frames: one sample per frame"
            )
        self.center_px = self.samples[["center_x_px", "center_y_px"]].to_numpy(float)
        self.depth_mm = self.samples["depth_mm"].to_numpy(float)
        self.eval_radius_px = self.samples["eval_radius_px"].to_numpy(float)
        self.split = self.samples["split"].to_numpy(str)
        self.min_p = self.samples["min_p"].to_numpy(int)
        self.point = self.samples["point"].to_numpy(int)
        self.replicate_columns = ["min_p"] + sorted(
            (c for c in self.samples.columns if c.startswith("min_p_r")),
            key=lambda c: int(c.removeprefix("min_p_r")),
        )
        self._label_boxes: dict[int, tuple[int, int, np.ndarray]] = {}
        self.unit = None
        if self.unit_blanks is not None:
            if "unit" not in self.samples.columns:
                raise ConfigError("a set with unit_blanks needs samples' `unit` column")
            self.unit = self.samples["unit"].to_numpy(int)
            if self.unit.size and not 0 <= self.unit.min() <= self.unit.max() < len(
                self.unit_blanks
            ):
                raise ConfigError(
                    f"samples' `unit` must lie in 0..{len(self.unit_blanks) - 1}, "
                    f"got {self.unit.min()}..{self.unit.max()}"
                )

    @property
    def replicates(self) -> int:
        """Replicates whose subsets this set holds (min_p, min_p_r1, ...)."""
        return len(self.replicate_columns)

    @property
    def image_shape(self) -> tuple[int, int]:
        return tuple(self.frames.shape[1:3])

    def indices(self, split: str, percent: int | None = None, replicate: int = 0) -> np.ndarray:
        """Frames of a split; for 'train' with `percent`, only replicate r's P=percent subset."""
        chosen = self.split == split
        if split == "train" and percent is not None:
            if not 0 <= replicate < self.replicates:
                raise ConfigError(
                    f"this dataset holds the subsets of replicates 0..{self.replicates - 1}, "
                    f"not {replicate}; rebuild it with the study's ablation.replicates"
                )
            min_p = self.samples[self.replicate_columns[replicate]].to_numpy(int)
            chosen &= (min_p > 0) & (min_p <= percent)
        return np.flatnonzero(chosen)

    def blank_of(self, i: int) -> np.ndarray:
        """Frame i's blank: its unit's in a set of several units, else the set's."""
        return self.blank if self.unit is None else self.unit_blanks[self.unit[i]]

    def inputs(self, i: int, window: tuple[slice, slice] | None = None) -> np.ndarray:
        return model_inputs(self.frames[i], self.blank_of(i), window)

    def labels(self, i: int, window: tuple[slice, slice] | None = None) -> np.ndarray:
        """(2, h, w) float32 gradient labels (∂z/∂x, ∂z/∂y) of frame i in `window`.

        A frame's labels are computed once, over the box its press can reach, and kept: training
        asks for a dozen windows of every frame, and a domed gel's labels cost 0.4 ms a window."""
        height, width = self.image_shape
        if window is None:
            window = (slice(0, height), slice(0, width))
        rows, cols = window
        r0, r1, _ = rows.indices(height)
        c0, c1, _ = cols.indices(width)
        top, left, box = self._label_box(i)
        out = np.zeros((2, r1 - r0, c1 - c0), dtype=np.float32)
        y0, y1 = max(r0, top), min(r1, top + box.shape[1])
        x0, x1 = max(c0, left), min(c1, left + box.shape[2])
        if y1 > y0 and x1 > x0:
            out[:, y0 - r0 : y1 - r0, x0 - c0 : x1 - c0] = box[
                :, y0 - top : y1 - top, x0 - left : x1 - left
            ]
        return out

    def _label_box(self, i: int) -> tuple[int, int, np.ndarray]:
        """(top, left, labels) of frame i over every pixel its press can reach (R plus 2 px)."""
        cached = self._label_boxes.get(i)
        if cached is None:
            height, width = self.image_shape
            cx, cy = self.center_px[i]
            reach = self.sphere_radius_mm * self.px_per_mm + 2.0
            top, left = max(int(np.floor(cy - reach)), 0), max(int(np.floor(cx - reach)), 0)
            bottom = min(max(int(np.ceil(cy + reach)) + 1, top), height)
            right = min(max(int(np.ceil(cx + reach)) + 1, left), width)
            g = sphere_gradients(
                (bottom - top, right - left),
                (cx - left, cy - top),
                self.sphere_radius_mm,
                float(self.depth_mm[i]),
                self.px_per_mm,
                self.max_slope_deg,
                dome=self.dome_at(i),
            )
            cached = self._label_boxes[i] = (top, left, np.ascontiguousarray(g.transpose(2, 0, 1)))
        return cached

    def dome_at(self, i: int) -> LocalDome | None:
        """The gel's dome around frame i's press (meta `dome`: the profile's gel.dome; None: flat)."""
        dome = (self.meta or {}).get("dome")
        return (
            None
            if not dome
            else local_dome(dome, self.center_px[i], self.image_shape, self.px_per_mm)
        )

    def eval_mask(self, i: int, window: tuple[slice, slice] | None = None) -> np.ndarray:
        """Pixels whose label is trusted for evaluation (inside eval_radius_px of the centre)."""
        height, width = self.image_shape
        rows = np.arange(height)[:, None]
        cols = np.arange(width)[None, :]
        cx, cy = self.center_px[i]
        mask = (cols - cx) ** 2 + (rows - cy) ** 2 <= self.eval_radius_px[i] ** 2
        return mask if window is None else mask[window]

    def save(self, directory: str | Path) -> None:
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        np.save(directory / "frames.npy", np.ascontiguousarray(self.frames, dtype=np.uint8))
        np.save(directory / "blank.npy", self.blank.astype(np.float32))
        columns = list(SAMPLE_COLUMNS) + self.replicate_columns[1:]
        if self.unit_blanks is not None:
            columns.append("unit")
            np.save(directory / "unit_blanks.npy", self.unit_blanks.astype(np.float32))
        self.samples.loc[:, columns].to_csv(directory / "samples.csv", index=False)
        meta = {
            **(self.meta or {}),
            "px_per_mm": self.px_per_mm,
            "sphere_radius_mm": self.sphere_radius_mm,
            "max_slope_deg": self.max_slope_deg,
        }
        (directory / "meta.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")

    @classmethod
    def load(cls, directory: str | Path, mmap: bool = True) -> TrainingSet:
        directory = Path(directory)
        for name in ("frames.npy", "blank.npy", "samples.csv", "meta.json"):
            if not (directory / name).is_file():
                raise ConfigError(
                    f"{directory / name}: missing (not a threedcal model-ready dataset)"
                )
        meta = json.loads((directory / "meta.json").read_text())
        import pandas as pd  # optional (workflow extra); the inference core imports this module

        samples = pd.read_csv(directory / "samples.csv")
        frames = np.load(directory / "frames.npy", mmap_mode="r" if mmap else None)
        if len(samples) != len(frames):
            raise ConfigError(
                f"{directory}: samples.csv has {len(samples)} rows for {len(frames)} frames"
            )
        return cls(
            frames=frames,
            blank=np.load(directory / "blank.npy"),
            samples=samples,
            px_per_mm=float(meta["px_per_mm"]),
            sphere_radius_mm=float(meta["sphere_radius_mm"]),
            max_slope_deg=check_max_slope(meta.get("max_slope_deg", DEFAULT_MAX_SLOPE_DEG)),
            meta=meta,
            unit_blanks=np.load(units)
            if (units := directory / "unit_blanks.npy").is_file()
            else None,
        )


def pool_to(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """`image` average-pooled to a model's frame `shape` (H, W), as `downscale` pools a trainset.

    Only a frame a whole number of times the model's in both directions pools to it; any other
    (a camera in another mode, a portrait/landscape mix-up) is a FrameSizeError giving both sizes."""
    if image.shape[:2] == tuple(shape):
        return image

    height, width = shape
    factor = image.shape[0] // height
    if factor < 1 or image.shape[1] // width != factor:
        raise FrameSizeError(
            f"a {image.shape[0]} x {image.shape[1]} px frame (H x W) does not fit the model's "
            f"{height} x {width} px frames: give frames of that size or a whole multiple of it "
            f"(e.g. {2 * height} x {2 * width} px), as the sensor streamed them for calibration"
        )
    cropped = np.ascontiguousarray(image[: height * factor, : width * factor])
    return cv2.resize(cropped, (width, height), interpolation=cv2.INTER_AREA)


def downscale(trainset: TrainingSet, factor: int) -> TrainingSet:
    """Average-pool frames by an integer factor; centres and px/mm follow (pixel-centre convention)."""
    if factor == 1:
        return trainset
    if factor < 1:
        raise ConfigError(f"downscale factor must be a whole number >= 1, got {factor}")

    n, height, width, _ = trainset.frames.shape
    h, w = height // factor, width // factor

    def pooled(image: np.ndarray) -> np.ndarray:
        return cv2.resize(
            np.asarray(image[: h * factor, : w * factor]), (w, h), interpolation=cv2.INTER_AREA
        )

    frames = np.stack([pooled(f) for f in trainset.frames])
    blank = pooled(trainset.blank)
    units = trainset.unit_blanks
    units = None if units is None else np.stack([pooled(b) for b in units]).astype(np.float32)
    samples = trainset.samples.copy()
    # A pixel centre c in the full image maps to (c + 0.5) / f − 0.5 in the pooled one.
    for column in ("center_x_px", "center_y_px"):
        samples[column] = (samples[column] + 0.5) / factor - 0.5
    samples["eval_radius_px"] = samples["eval_radius_px"] / factor
    return TrainingSet(
        frames=frames,
        blank=blank.astype(np.float32),
        samples=samples,
        px_per_mm=trainset.px_per_mm / factor,
        sphere_radius_mm=trainset.sphere_radius_mm,
        max_slope_deg=trainset.max_slope_deg,
        meta={
            **(trainset.meta or {}),
            "downscale": factor * (trainset.meta or {}).get("downscale", 1),
        },
        unit_blanks=units,
    )


def from_imported(
    data,
    seed: int,
    validation_fraction: float = 0.2,
    fractions: tuple[int, ...] = (80,),
    replicates: int = 1,
) -> TrainingSet:
    """An imported dataset → TrainingSet with a seeded split by probe coordinate (by image for ball folders)."""
    import pandas as pd  # optional (workflow extra); the inference core imports this module

    from threedcal.dataset.splits import min_p_column, split_points  # pandas, as above

    points = (
        pd.DataFrame({"point": data.point, "x_mm": data.xy_mm[:, 0], "y_mm": data.xy_mm[:, 1]})
        .drop_duplicates("point")
        .fillna(0.0)
    )
    table = split_points(
        points,
        list(fractions),
        seed=seed,
        validation_fraction=validation_fraction,
        replicates=replicates,
    ).set_index("point")
    replicate_columns = {
        min_p_column(r): table.loc[data.point, min_p_column(r)].to_numpy()
        for r in range(1, replicates)
    }
    samples = samples_table(
        data.point,
        data.center_px,
        data.depth_mm,
        data.eval_radius_px,
        table.loc[data.point, "split"].to_numpy(),
        table.loc[data.point, "min_p"].to_numpy(),
        **replicate_columns,
    )
    return TrainingSet(
        frames=data.frames,
        blank=data.blank.astype(np.float32),
        samples=samples,
        px_per_mm=data.px_per_mm,
        sphere_radius_mm=data.sphere_radius_mm,
        meta={"source": "import", "names": list(data.names), **data.metadata},
    )
