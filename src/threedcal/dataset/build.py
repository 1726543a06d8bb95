"""The `dataset` stage: a scene's raw data (or imported folder) → splits.csv + the model-ready set."""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from threedcal.collect.plan import (
    WHOLE_CONTACT_MARGIN_PX,
    dome_sag_at_px,
    dome_sag_mm,
    touch_search_range,
)
from threedcal.collect.scene_plan import plan_phases
from threedcal.collect.store_read import open_checked
from threedcal.dataset.camera_fit import MIN_FIRST_CONTACTS, AffineFit
from threedcal.dataset.dome_contacts import DomedContacts
from threedcal.dataset.importers import load_imported
from threedcal.dataset.labels import check_max_slope, contact_radius_mm
from threedcal.dataset.refine import refine_labels
from threedcal.dataset.registration import CameraRegistration, register_camera
from threedcal.dataset.settings import DatasetSettings
from threedcal.dataset.splits import in_field_of_view, min_p_column, split_points
from threedcal.dataset.touch import (
    TOUCH_FIT_SPAN_MM,
    estimate_touch,
    measure_touch_search,
    planned_touch_search,
)
from threedcal.dataset.trainset import TrainingSet, downscale, from_imported
from threedcal.errors import ConfigError, RegistrationError
from threedcal.lens import RadialLens, profile_focal_px, rectify_if
from threedcal.plotting import pyplot
from threedcal.profiles import with_gel_mechanics
from threedcal.sim.bench import BenchTruth
from threedcal.sim.elastic import GelMaterial


def write_splits(trainset: TrainingSet, path: str | Path, xy_mm=None) -> None:
    samples = trainset.samples.drop_duplicates("point").sort_values("point")
    table = samples[["point", "split", *trainset.replicate_columns]].copy()
    if xy_mm is not None:
        table.insert(1, "x_mm", xy_mm[table["point"].to_numpy(), 0])
        table.insert(2, "y_mm", xy_mm[table["point"].to_numpy(), 1])
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(path, index=False)


def build_imported(
    data_format: str,
    data_path: str | Path,
    settings: DatasetSettings,
    trainset_dir: str | Path,
    splits_path: str | Path,
) -> TrainingSet:
    orientation = settings.sensor["image"].get("orientation") if settings.sensor else None
    data = load_imported(data_format, data_path, orientation)

    trainset = from_imported(
        data,
        seed=settings.seed,
        fractions=settings.fractions,
        replicates=settings.replicates,
    )
    trainset.max_slope_deg = check_max_slope(settings.max_slope_deg)
    if settings.sensor:
        trainset.meta["sensor"] = settings.sensor.get("name")
    if settings.refine_labels:
        trainset = refine_labels(trainset)
    trainset = downscale(trainset, settings.downscale)
    trainset.save(trainset_dir)
    xy = np.full((int(data.point.max()) + 1, 2), np.nan)
    xy[data.point] = data.xy_mm
    write_splits(trainset, splits_path, xy_mm=xy)
    return trainset


def _registration_figure(
    trainset: TrainingSet, samples: list[int], path: str | Path, title: str
) -> None:
    plt = pyplot()

    fig, axes = plt.subplots(1, len(samples), figsize=(2.4 * len(samples), 3.4), dpi=110)
    for ax, i in zip(np.atleast_1d(axes), samples, strict=True):
        ax.imshow(np.asarray(trainset.frames[i]))
        cx, cy = trainset.center_px[i]
        ax.add_patch(plt.Circle((cx, cy), trainset.eval_radius_px[i], fill=False, ec="white", lw=1))
        ax.plot(cx, cy, "+", c="white", ms=6)
        ax.set_title(f"point {trainset.point[i]}", fontsize=8)
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


@dataclass
class RegisteredStore:
    """A collected store with its registration: what labels and the touch height are made from.

    Frames are indexed as in the store; `phase` and `first`/`last` (frame range) per plan row."""

    raw: object  # the store as an xarray Dataset
    sensor: dict
    plan_config: dict  # the plan section the store was collected with
    phase: np.ndarray  # per plan row: "touch", "register" or "grid"
    first: np.ndarray
    last: np.ndarray
    registration: object  # threedcal.dataset.registration.CameraRegistration (of `registered_rows`)
    registered_rows: np.ndarray  # the plan rows the registration located contacts in
    centres: np.ndarray  # (frames, 2) where the affine puts each frame's probe, px
    nominal_depth: np.ndarray  # (frames,) commanded depth below the gel surface there, mm

    @property
    def px_per_mm(self) -> float:
        return float(np.mean(self.registration.fit.px_per_mm))

    def rows(self, phase: str) -> np.ndarray:
        return np.flatnonzero(self.phase == phase)

    def mean_frame(self, row: int) -> np.ndarray:
        """One plan row's frames averaged (less noise than any one), uint8."""
        return _mean_frame(self.raw, self.first[row], self.last[row])


def _mean_frame(raw, start: int, stop: int) -> np.ndarray:
    stack = raw["frames"][start:stop].values.astype(np.float32)
    return np.clip(stack.mean(axis=0) + 0.5, 0, 255).astype(np.uint8)


def contact_material(sensor: Mapping, simulated: bool, bench_gel_mechanics: str | None):
    """The gel's elastic constants when its contacts are elastic, else None (it follows the ball).

    A real gel is elastic. A simulated bench renders the gel its `bench.gel_mechanics` (else the
    profile's `gel.mechanics`) names, and the contacts the registration sees are that gel's."""
    if simulated:
        gel = with_gel_mechanics(sensor, bench_gel_mechanics)["gel"]
        if gel.get("mechanics", "geometric") != "elastic":
            return None
    missing = [k for k in ("youngs_modulus_mpa", "poisson_ratio") if k not in sensor["gel"]]
    if missing:  # a real gel whose profile lacks its constants: the rim, moved by the overlap
        logging.getLogger(__name__).warning(
            "sensor profile %r has no gel.%s: its domed contacts are registered as a gel that "
            "follows the ball (rim centres only; docs/explanation/registration.md, Domed gels)",
            sensor.get("name"),
            " or gel.".join(missing),
        )
        return None
    return GelMaterial.from_profile(sensor["gel"])


def register_store(
    settings: DatasetSettings,
    store_path: str | Path,
    progress: bool = True,
    expect_digest: str | None = None,
    rows: int | None = None,
    prior: RegisteredStore | None = None,
    given: AffineFit | None = None,
) -> RegisteredStore:
    """The printer → pixel affine from a store's grid rows (one contact per row, from the mean of
    its frames), and each frame's depth below the gel where the affine places it. The store is
    read whole and checked (`threedcal.collect.store_read.open_checked`); `rows`: only its first that
    many plan rows, captured so far. `prior`: this store registered earlier (a quick calibration's
    last round); its fit is reused when it located the same rows, whose frames a store never
    changes, rather than located and fitted again (most of a round's labelling time). `given`: a
    registration known beforehand (a simulated bench's truth), used as it is: nothing located."""
    sensor = settings.sensor
    raw = open_checked(store_path, expect_digest, rows=rows)
    height, width = raw["frames"].shape[1:3]
    point_of_frame = raw["point"].values
    n_rows = int(point_of_frame.max()) + 1
    plan_config = raw.attrs.get("config", {}).get("plan", {})
    # the rows captured so far (`rows`): a grid row not yet pressed has no frames to locate
    phase = plan_phases(raw.attrs["plan"], plan_config, raw.attrs.get("sensor_profile", sensor))
    phase = phase[:n_rows]
    first = np.searchsorted(point_of_frame, np.arange(n_rows))
    last = np.searchsorted(point_of_frame, np.arange(n_rows), side="right")
    cmd_xy = np.column_stack([raw["cmd_x_mm"].values, raw["cmd_y_mm"].values])

    def whole(contact) -> bool:  # the rim and a margin inside the image
        margin = contact.radius_px + WHOLE_CONTACT_MARGIN_PX
        return (
            margin <= contact.x_px <= width - 1 - margin
            and margin <= contact.y_px <= height - 1 - margin
        )

    # The registration presses when the plan has them: alone, for their contacts share one depth
    # and so one locator bias, where adding the grid's 1-3 mm contacts mixes biases that the lens
    # fit then bends to (docs/explanation/registration.md, Registration presses).
    rows = np.flatnonzero(phase == "register")
    if not len(rows):
        rows = np.flatnonzero(phase == "grid")
    if given is not None:
        registration = CameraRegistration(given, [], "given", {}, None)
        rows = np.zeros(0, int)
    elif prior is not None and np.array_equal(prior.registered_rows, rows):
        registration = prior.registration
    else:

        def register_rows(rows, whole, progress):
            return _register(settings, raw, rows, first, last, cmd_xy, whole, progress)

        registration, rows = _register_presses(register_rows, phase, rows, whole, progress)
    # where each press lies in the ideal frame: what the trainset's rectified frames show
    centres = registration.fit.ideal(cmd_xy)
    # The plan compensated the dome's sag at the nominal seating; the sensor sits where the
    # registration says, and the sag there is what the press's depth is measured from.
    depth = raw["depth_mm"].values - dome_sag_at_px(sensor, centres[:, 0], centres[:, 1])
    return RegisteredStore(
        raw, sensor, plan_config, phase, first, last, registration, rows, centres, depth
    )


def _register_presses(register_rows, phase, rows, whole, progress):
    """(registration, its rows): the registration presses', or with the grid presses' too where
    those located fewer whole contacts than the affine through a lens needs with one to spare. A
    shallow registration press on a noisy unit can stand too little above the noise to be found;
    the deeper grid contacts then join it, with their own locator bias, rather than a fit through
    a few contacts or none."""
    grid = np.flatnonzero(phase == "grid")
    if not len(grid) or np.array_equal(rows, grid):
        return register_rows(rows=rows, whole=whole, progress=progress), rows
    try:
        registration = register_rows(rows=rows, whole=whole, progress=progress)
        found = sum(c is not None for c in registration.contacts)
    except RegistrationError:  # fewer than an affine's three
        registration, found = None, "fewer than 3"
    if registration is not None and found >= MIN_FIRST_CONTACTS:
        return registration, rows
    logging.getLogger(__name__).warning(
        "registration: the %d registration presses located %s whole contacts (%d needed): "
        "registering on them and the %d grid presses together (a deeper "
        "plan.registration.depth_mm gives fainter contacts more contrast)",
        len(rows),
        found,
        MIN_FIRST_CONTACTS,
        len(grid),
    )
    both = np.union1d(rows, grid)
    return register_rows(rows=both, whole=whole, progress=progress), both


def _register(settings, raw, rows, first, last, cmd_xy, whole, progress):
    """register_camera on the contacts of plan rows `rows` (their mean frames)."""
    sensor = settings.sensor
    height, width = raw["frames"].shape[1:3]
    dome = None
    if sensor["gel"].get("dome"):
        # each press's depth below the gel as the plan meant it (its dome compensation undone)
        nominal = raw["depth_mm"].values[first[rows]] - dome_sag_mm(
            sensor, raw["x_mm"].values[first[rows]], raw["y_mm"].values[first[rows]]
        )
        dome = DomedContacts(
            sensor["gel"]["dome"],
            float(settings.probe_radius_mm),
            np.clip(nominal, 0.0, None),
            float(sensor["px_per_mm"]),
            (height, width),
            material=contact_material(sensor, settings.simulated, settings.bench_gel_mechanics),
        )
    return register_camera(
        cmd_xy[first[rows]],
        [_mean_frame(raw, first[p], last[p]) for p in rows],
        raw["blank_frames"].values.astype(np.float32).mean(axis=0),
        accept=whole,
        flat_gel=sensor["gel"].get("dome") is None,
        progress=progress,
        lens=RadialLens.from_profile(sensor) or False,  # refitted as far as the contacts allow
        dome=dome,
    )


def build_collected(
    settings: DatasetSettings,
    store_path: str | Path,
    trainset_dir: str | Path,
    splits_path: str | Path,
    registration_path: str | Path,
    figure_path: str | Path,
    truth_path: str | Path | None = None,
    progress: bool = True,
    expect_digest: str | None = None,
) -> dict:
    """Raw store → registration (affine + touch height) → exact labels → splits → model-ready set.

    Labels use only what a real user knows: the sphere, the plan and the registration fitted here.
    The bench's hidden truth (simulated scenes) is read only to report the registration's error.
    The affine comes from the plan's grid rows; the touch height from its first-contact search
    (the touch rows, which only serve that: they are not training frames), or, for a plan
    without one, from the grid's contact radii (docs/explanation/registration.md). The store is read back
    whole and checked first (complete, every point captured, every chunk present and readable;
    `expect_digest`: the frame settings collect/summary.json recorded).
    """
    radius_mm = float(settings.probe_radius_mm)
    store = register_store(settings, store_path, progress, expect_digest)
    method = "search" if len(store.rows("touch")) else "rim"
    touch = touch_height(store, radius_mm, method, progress)
    offset = touch["touch_offset_mm"]
    contact_z_mm = round(float(store.sensor["mount"]["z_touch_mm"]) + offset, 4)
    labels = _label_frames(settings, store, offset)
    trainset = _collected_trainset(settings, store, labels, contact_z_mm)
    trainset = downscale(trainset, settings.downscale)
    trainset.save(trainset_dir)
    write_splits(trainset, splits_path, xy_mm=labels.coordinates[["x_mm", "y_mm"]].to_numpy())
    record = _registration_record(store, touch, labels, contact_z_mm)
    if truth_path is not None and Path(truth_path).is_file():
        record.update(_bench_errors(store, labels, truth_path, offset))
    # the fitted lens as OpenCV and ROS read a camera (its focal length: the profile's)
    lens = store.registration.fit.lens
    record["camera"] = None if lens is None else lens.camera_info(profile_focal_px(store.sensor))
    Path(registration_path).write_text(json.dumps(record, indent=2) + "\n")
    picks = (
        np.linspace(0, len(trainset.samples) - 1, min(5, len(trainset.samples))).round().astype(int)
    )
    fit = store.registration.fit
    _registration_figure(
        trainset,
        list(picks),
        figure_path,
        f"registration: residual {fit.residual_px:.2f} px, touch offset {offset:+.3f} mm",
    )
    return record


def labelled_through(
    settings: DatasetSettings,
    store_path: str | Path,
    fit: AffineFit,
    touch_offset_mm: float,
    splits: pd.DataFrame,
    progress: bool = False,
) -> TrainingSet:
    """A store's model-ready set labelled through a registration and touch height known
    beforehand, nothing located or fitted; its points and splits are those of `splits` (the
    store's splits.csv: point, x_mm, y_mm, split, min_p …), matched by plan coordinate, so that
    the set pairs point for point with the one `build_collected` made. A simulated bench's truth
    scores calibrations against the world rather than against one of them
    (threedcal.study.quick_study). Frames that this registration puts out of view are left out."""
    missing = [c for c in ("point", "x_mm", "y_mm", "split", "min_p") if c not in splits.columns]
    if missing:
        raise ConfigError(f"splits: no column {', '.join(missing)} (a dataset stage's splits.csv)")
    store = register_store(settings, store_path, progress, given=fit)
    labels = _label_frames(settings, store, touch_offset_mm)
    point_of = {
        (round(x, 4), round(y, 4)): int(p)
        for p, x, y in splits[["point", "x_mm", "y_mm"]].itertuples(index=False)
    }
    xy = _plan_xy(store.raw)[labels.keep]
    ids = np.array([point_of.get((round(x, 4), round(y, 4)), -1) for x, y in xy], dtype=int)
    known = ids >= 0
    if not known.any():
        raise ConfigError(f"{store_path}: none of its labelled presses is a point of the splits")
    labels.keep, labels.coordinate_id = labels.keep[known], ids[known]
    contact_z_mm = round(float(store.sensor["mount"]["z_touch_mm"]) + touch_offset_mm, 4)
    trainset = _collected_trainset(
        settings, store, labels, contact_z_mm, table=splits.set_index("point")
    )
    return downscale(trainset, settings.downscale)


def collected_so_far(
    settings: DatasetSettings,
    store_path: str | Path,
    rows: int,
    progress: bool = False,
    prior: RegisteredStore | None = None,
) -> tuple[TrainingSet, dict, RegisteredStore]:
    """The model-ready set of a store's first `rows` plan rows, while it is being collected (a
    quick calibration between rounds), its registration record and the registered store (the
    next round's `prior`: register_store). Registered and labelled as `build_collected` does, but
    every labelled press trains: the next round's presses, not a split of these, judge the
    model. Samples' `plan_row` names each frame's press."""
    radius_mm = float(settings.probe_radius_mm)
    store = register_store(settings, store_path, progress, rows=rows, prior=prior)
    method = "search" if len(store.rows("touch")) else "rim"
    touch = touch_height(store, radius_mm, method, progress)
    offset = touch["touch_offset_mm"]
    contact_z_mm = round(float(store.sensor["mount"]["z_touch_mm"]) + offset, 4)
    labels = _label_frames(settings, store, offset)
    trainset = _collected_trainset(settings, store, labels, contact_z_mm, every_press_trains=True)
    trainset.samples["plan_row"] = store.raw["point"].values[labels.keep]
    trainset = downscale(trainset, settings.downscale)
    return trainset, _registration_record(store, touch, labels, contact_z_mm), store


@dataclass
class _Labels:
    """Which frames of a registered store train, at which depth, and their probe coordinates."""

    depth: np.ndarray  # (frames,) depth below the gel with the touch offset applied, mm
    inside: np.ndarray  # (frames,) bool: a grid frame whose probe lies in view, pressed
    too_deep: np.ndarray  # (frames,) bool: inside, but past dataset.max_depth_over_radius
    keep: np.ndarray  # the frames that train (indices)
    coordinate_id: np.ndarray  # per kept frame: its probe coordinate
    coordinates: pd.DataFrame  # one row per coordinate: x_mm, y_mm, point (sorted by point)


def _label_frames(settings: DatasetSettings, store: RegisteredStore, offset: float) -> _Labels:
    """Labels for every grid frame whose probe centre the registration puts inside the image."""
    raw, centres = store.raw, store.centres
    height, width = raw["frames"].shape[1:3]
    radius_mm = float(settings.probe_radius_mm)
    depth = np.clip(store.nominal_depth + offset, 0.0, None)
    inside = (
        in_field_of_view(centres[:, 0], centres[:, 1], width, height)
        & (depth > 0)
        & (store.phase[raw["point"].values] == "grid")
    )
    # Past d = R the contact stops growing and the rest of the press is a vertical wall the camera
    # looks along: frames that differ only in its height look alike while their rim labels do not.
    # Such presses serve the registration and the touch height, not the model (docs/explanation/labels.md).
    max_ratio = settings.max_depth_over_radius
    too_deep = np.zeros_like(inside)
    if max_ratio is not None:
        # the plan's depth, as the user wrote it (its dome compensation undone: a 1 mm press near a
        # domed gel's edge is commanded deeper, not pressed deeper); measured sags would split
        # presses that sit at the limit
        as_written = raw["depth_mm"].values - dome_sag_mm(
            store.sensor, raw["x_mm"].values, raw["y_mm"].values
        )
        too_deep = inside & (as_written > float(max_ratio) * radius_mm + 1e-3)
    keep = np.flatnonzero(inside & ~too_deep)
    if len(keep) == 0:
        raise ConfigError(
            f"dataset.max_depth_over_radius: {max_ratio} leaves no "
            f"frame to train on ({int(too_deep.sum())} of {int(inside.sum())} labelled frames are "
            f"pressed deeper than {max_ratio} x R = {float(max_ratio) * radius_mm:g} mm)"
        )
    plan_xy = _plan_xy(raw)
    coords = pd.DataFrame({"x_mm": plan_xy[keep, 0], "y_mm": plan_xy[keep, 1]})
    coordinate_id = coords.groupby(["x_mm", "y_mm"], sort=True).ngroup().to_numpy()
    unique = coords.assign(point=coordinate_id).drop_duplicates("point").sort_values("point")
    return _Labels(depth, inside, too_deep, keep, coordinate_id, unique)


def _plan_xy(raw) -> np.ndarray:
    return np.column_stack([raw["x_mm"].values, raw["y_mm"].values])


def _collected_trainset(
    settings: DatasetSettings,
    store: RegisteredStore,
    labels: _Labels,
    contact_z_mm: float,
    every_press_trains: bool = False,
    table: pd.DataFrame | None = None,
) -> TrainingSet:
    """The kept frames, rectified through the fitted lens (one mm is one px_per_mm everywhere, as
    the labels are), with their labels and splits (`every_press_trains`: no validation split,
    every press in every subset; `table`: the splits given, by point)."""
    radius_mm = float(settings.probe_radius_mm)
    raw, sensor, fit = store.raw, store.sensor, store.registration.fit
    keep, coordinate_id, depth = labels.keep, labels.coordinate_id, labels.depth
    replicates = settings.replicates
    if table is not None:
        replicates = sum(c == "min_p" or c.startswith("min_p_r") for c in table.columns)
    elif every_press_trains:
        replicates = 1
        table = labels.coordinates.assign(split="train", min_p=1).set_index("point")
    else:
        table = split_points(
            labels.coordinates, list(settings.fractions), seed=settings.seed, replicates=replicates
        ).set_index("point")
    samples = pd.DataFrame(
        {
            "frame": keep,
            "point": coordinate_id,
            "center_x_px": store.centres[keep, 0],
            "center_y_px": store.centres[keep, 1],
            "depth_mm": depth[keep],
            "eval_radius_px": [
                contact_radius_mm(radius_mm, d) * store.px_per_mm for d in depth[keep]
            ],
            "split": table.loc[coordinate_id, "split"].to_numpy(),
            **{
                min_p_column(r): table.loc[coordinate_id, min_p_column(r)].to_numpy()
                for r in range(replicates)
            },
        }
    )
    return TrainingSet(
        frames=rectify_if(fit.lens, raw["frames"].values[keep]),
        blank=rectify_if(fit.lens, raw["blank_frames"].values.astype(np.float32).mean(axis=0)),
        samples=samples.assign(frame=np.arange(len(keep))),
        px_per_mm=store.px_per_mm,
        sphere_radius_mm=radius_mm,
        max_slope_deg=check_max_slope(settings.max_slope_deg),
        meta={
            "source": "collected",
            "store_frames": keep.tolist(),
            "lens": None if fit.lens is None else fit.lens.record(),
            # labels are the depth below the undeformed gel: on a domed gel, its dome's
            "dome": sensor["gel"].get("dome"),
            "sensor": sensor.get("name"),
            # printer mm → rectified camera px and the apex's first-touch Z (model points)
            "registration": {
                "affine_px_per_mm": fit.matrix.round(9).tolist(),
                "contact_z_mm": contact_z_mm,
            },
        },
    )


def _registration_record(
    store: RegisteredStore, touch: dict, labels: _Labels, contact_z_mm: float
) -> dict:
    """registration.json: the fit, how it was found, the touch height and what was labelled."""
    registration = store.registration
    fit = registration.fit
    offset = touch["touch_offset_mm"]
    linear = fit.matrix[:, :2]
    return {
        "affine_px_per_mm": fit.matrix.round(9).tolist(),
        "lens": None if fit.lens is None else fit.lens.record(),
        "residual_px": round(fit.residual_px, 4),
        "lens_free": fit.lens_free,
        "lens_cv_px": None
        if fit.lens_cv_px is None
        else {k: round(v, 4) for k, v in fit.lens_cv_px.items()},
        "px_per_mm": [round(v, 5) for v in fit.px_per_mm],
        "rotation_deg": round(float(np.degrees(np.arctan2(linear[1, 0], linear[0, 0]))), 4),
        "contacts_from": "+".join(dict.fromkeys(store.phase[store.registered_rows].tolist())),
        "contacts_found": int(sum(c is not None for c in registration.contacts)),
        "contacts_used": int(fit.inliers.sum()),
        "locator": registration.locator,
        "residual_px_by_locator": {k: round(v, 4) for k, v in registration.residual_px.items()},
        "symmetry_start": registration.symmetry_start,
        "channel_unmixing": None
        if registration.unmixing is None
        else registration.unmixing.round(4).tolist(),
        **{k: v for k, v in touch.items() if k != "touch_offset_mm"},
        "touch_offset_mm": round(offset, 4),
        "contact_z_mm": contact_z_mm,
        "frames_in_view": int(labels.inside.sum()),
        "frames_too_deep": int(labels.too_deep.sum()),
        "frames_labelled": int(len(labels.keep)),
        "probe_points_in_view": len({tuple(xy) for xy in _plan_xy(store.raw)[labels.inside]}),
        "probe_points_labelled": int(len(labels.coordinates)),
    }


def _bench_errors(store: RegisteredStore, labels: _Labels, truth_path, offset: float) -> dict:
    """The registration's error against the simulated bench's hidden truth (reported, never used)."""

    truth = json.loads(Path(truth_path).read_text())
    if "affine_px_per_mm" not in truth:
        return {}
    raw = store.raw
    cmd_xy = np.column_stack([raw["cmd_x_mm"].values, raw["cmd_y_mm"].values])
    # where the camera truly images each probe point (through the bench's lens, if any)
    probe = np.unique(cmd_xy[labels.inside], axis=0)
    true_px = BenchTruth.read(truth_path).camera_px(probe)
    error = np.linalg.norm(store.registration.fit.apply(probe) - true_px, axis=1)
    return {
        "error_px": round(float(np.sqrt(np.mean(error**2))), 4),
        "error_px_max": round(float(error.max()), 4),
        "touch_offset_error_mm": round(offset - float(truth["touch_offset_mm"]), 4),
    }


def touch_height(
    store: RegisteredStore, radius_mm: float, method: str, progress: bool = False
) -> dict:
    """registration.json's touch fields, by `method`: "search" (the plan's first-contact search,
    the default) or "rim" (the grid's contact radii; d < R only, see docs/explanation/registration.md)."""
    fit = store.registration.fit
    if method == "search":
        touch = store.rows("touch")
        if not len(touch):
            raise ConfigError("the plan has no touch search (plan.touch_search.points is 0)")
        rows = store.first[touch]
        xy = np.column_stack([store.raw["x_mm"].values[rows], store.raw["y_mm"].values[rows]])
        places, place = np.unique(xy, axis=0, return_inverse=True)
        search = store.plan_config.get("touch_search") or {}
        if search.get("method", "steps") == "bisect":
            result = _replayed_bisection(store, touch, xy, radius_mm, search)
        else:  # in the ideal frame, where the registration put the search's places
            result = measure_touch_search(
                [rectify_if(fit.lens, store.mean_frame(p)) for p in touch],
                rectify_if(fit.lens, store.raw["blank_frames"].values),
                store.nominal_depth[rows],
                place.ravel(),
                store.centres[rows],
                store.px_per_mm,
                reach_mm=radius_mm,
                span_mm=TOUCH_FIT_SPAN_MM,
                progress=progress,
            )
        return {
            "touch_offset_mm": result.offset_mm,
            "touch_method": "bisect" if search.get("method") == "bisect" else "search",
            "rim_edge_offset_mm": None,
            "touch_search": {
                "places_mm": places.round(4).tolist(),
                "offset_mm_by_place": result.place_offsets_mm.round(4).tolist(),
                "onset_depth_mm_by_place": result.onset_depth_mm.round(4).tolist(),
                "steps_fitted_by_place": result.steps_fitted.tolist(),
                "signal_exponent": result.exponent,
                "frames": int((store.last[touch] - store.first[touch]).sum()),
            },
        }
    if method != "rim":
        raise ConfigError(f"touch height method {method!r} is not allowed (allowed: search, rim)")
    used = np.flatnonzero(fit.inliers)
    located = store.registered_rows[used]
    estimate = estimate_touch(
        store.nominal_depth[store.first[located]],
        np.array([store.registration.contacts[i].radius_px for i in used]) / store.px_per_mm,
        radius_mm,
    )
    return {
        "touch_offset_mm": estimate.offset_mm,
        "touch_method": "rim",
        "rim_edge_offset_mm": None if estimate.edge_mm is None else round(estimate.edge_mm, 4),
        "touch_search": None,
    }


def _replayed_bisection(store: RegisteredStore, touch, xy, radius_mm: float, search):
    """A bisecting search's answer from its stored presses, judged as the collection judged them
    (camera frames, the profile's scale) at the depths below the gel the registration gives."""
    low, high = touch_search_range(store.sensor, search)
    replay = planned_touch_search(
        xy, np.full(len(touch), high), low, high, float(store.sensor["px_per_mm"]), radius_mm
    )
    replay.begin(store.raw["blank_frames"].values)
    for k, (first, last) in enumerate(zip(store.first[touch], store.last[touch], strict=True)):
        frames = store.raw["frames"][int(first) : int(last)].values
        replay.observe(k, float(store.nominal_depth[first]), frames)
    return replay.result()
