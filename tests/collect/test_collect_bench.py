"""Collection on the simulated bench: crash safety (SIGKILL + resume), serial faults, registration."""

import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import (
    REPO,
    assert_same_array,
    collect_and_register,
    collect_on_bench,
    lens_free,
    snapshot,
)

from threedcal.collect.store_read import open_raw
from threedcal.dataset.build import build_collected
from threedcal.errors import ConfigError
from threedcal.study.config import validate_config
from threedcal.study.scene import dataset_settings
from threedcal.study.session import collect_scene

LABELS = (
    "point",
    "rep",
    "x_mm",
    "y_mm",
    "depth_mm",
    "cmd_x_mm",
    "cmd_y_mm",
    "cmd_z_mm",
    "reported_x_mm",
    "reported_y_mm",
    "reported_z_mm",
)


def study(**bench) -> dict:
    """A one-scene Mini study as a user writes it (not yet validated)."""
    return {
        "seed": 5,
        "scenes": {
            "s": {
                "sensor": "gelsight_mini",
                "printer": "ender3",
                # one touch-search place (26 one-frame steps): its rows go through every crash,
                # fault and resume below like the grid's
                "plan": {
                    "spacing_mm": 3.0,
                    "depth_mm": 1.0,
                    "frames": 2,
                    "touch_search": {"points": 1},
                },
                "bench": bench,
            }
        },
    }


def scene_config(**bench):
    return validate_config(study(**bench))


def assert_same_store(a, b):
    one, two = open_raw(a), open_raw(b)
    assert_same_array(one.frames.values, two.frames.values)
    assert_same_array(one.blank_frames.values, two.blank_frames.values)
    for name in LABELS:
        assert_same_array(one[name].values, two[name].values, err_msg=name)
    assert bool(one.captured.all()) and bool(two.captured.all())


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    path = tmp_path_factory.mktemp("ref") / "raw.zarr"
    summary = collect_scene("s", scene_config()["scenes"]["s"], path, progress=False)
    return path, summary


def test_summary_counts_and_hardware_estimate(reference):
    _, summary = reference
    # the touch search's 26 steps of one frame, then a 7 x 6 grid on the Mini, 2 frames each
    assert summary["points"] == 26 + 42 and summary["frames"] == 26 + 84
    assert summary["estimated_hardware_s"] > 110 / 25  # at least the capture time at 25 fps
    assert summary["runs"] == 1


def test_injected_serial_faults_give_the_same_store(tmp_path, reference):
    scene = scene_config(faults="all", fault_rate=0.08)["scenes"]["s"]
    collect_scene("s", scene, tmp_path / "raw.zarr", progress=False)
    assert_same_store(reference[0], tmp_path / "raw.zarr")


def captured_points(store) -> int:
    try:
        import zarr

        return int(zarr.open_group(str(store), mode="r")["captured"][:].sum())
    except Exception:  # not created yet, or caught mid-write
        return 0


@pytest.mark.long
@pytest.mark.slow
def test_sigkill_at_random_moments_then_resume_gives_the_uninterrupted_store(tmp_path, reference):
    config_path = tmp_path / "config.yaml"
    # the reference's plan: kills land in the touch search and the grid
    config_path.write_text(yaml.safe_dump(study()))
    store = tmp_path / "raw.zarr"
    command = [
        sys.executable,
        "-m",
        "threedcal",
        "collect",
        "--config",
        str(config_path),
        "--scene",
        "s",
        "--out",
        str(store),
    ]
    # Kill at an early moment (before or while the store is made), then after k captured points.
    targets = [0, 3, 11, 26, 37, 50]
    kills = 0
    for target in targets:
        process = subprocess.Popen(
            command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        deadline = time.monotonic() + 60
        while process.poll() is None and time.monotonic() < deadline:
            if (target == 0 and store.exists()) or captured_points(store) >= target > 0:
                break
            time.sleep(0.01)
        if process.poll() is None:
            os.kill(process.pid, signal.SIGKILL)
            process.wait()
            kills += 1
        else:
            assert process.returncode == 0
            break
    subprocess.run(
        command, cwd=REPO, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    assert kills >= 3, "the runs finished before the kills: make the plan longer"
    assert_same_store(reference[0], store)
    assert open_raw(store).attrs["complete"] is True


def test_complete_store_is_never_overwritten(reference, tmp_path):
    from threedcal.collect.store import SettingsMismatch

    before = snapshot(reference[0])
    # Same settings: nothing is collected, the store's summary comes back.
    summary = collect_scene(
        "s", scene_config()["scenes"]["s"], reference[0], staging_path=tmp_path / "x"
    )
    assert summary["points"] == 26 + 42 and summary["frame_digest"] == reference[1]["frame_digest"]
    assert not (tmp_path / "x").exists()
    # Other settings: refused, naming the key (old → new) and how to recollect.
    other = scene_config()
    other["scenes"]["s"]["seed"] = 6
    other["scenes"]["s"]["probe"]["radius_mm"] = 3.0
    with pytest.raises(SettingsMismatch) as exc:
        collect_scene("s", other["scenes"]["s"], reference[0], staging_path=tmp_path / "x")
    message = str(exc.value)
    assert "seed: 5 → 6" in message and "probe.radius_mm: 2.0 → 3.0" in message
    assert f"mv {reference[0]} {reference[0]}.old" in message
    assert snapshot(reference[0]) == before


def test_invalid_plan_fails_before_any_motion(tmp_path):
    plan = tmp_path / "plan.csv"
    plan.write_text("x,y,depth,frames\n1,1,1,1\n2,2,9,1\n")
    config = scene_config()
    config["scenes"]["s"]["plan"] = {"csv": str(plan)}
    from threedcal.errors import ConfigError

    with pytest.raises(
        ConfigError, match=r"plan.csv, line 3: depth 9 mm .* beyond the sensor's maximum"
    ):
        collect_scene("s", config["scenes"]["s"], tmp_path / "raw.zarr", progress=False)
    assert not (tmp_path / "raw.zarr").exists()


@pytest.mark.long
@pytest.mark.slow
def test_registration_recovers_the_hidden_seating(tmp_path):
    scene = validate_config(
        {
            "seed": 2,
            "scenes": {
                "s": {
                    "sensor": "gelsight_mini",
                    "printer": "ender3",
                    "plan": {"spacing_mm": 2.0, "depth_mm": 1.0, "frames": 1},
                    "bench": {
                        "seating_offset_mm": 0.5,
                        "seating_rotation_deg": 2.0,
                        "touch_offset_mm": 0.1,
                    },
                }
            },
        }
    )["scenes"]["s"]
    collect_scene(
        "s", scene, tmp_path / "raw.zarr", truth_path=tmp_path / "truth.json", progress=False
    )
    record = build_collected(
        dataset_settings(scene),
        tmp_path / "raw.zarr",
        tmp_path / "ts",
        tmp_path / "splits.csv",
        tmp_path / "reg.json",
        tmp_path / "reg.png",
        tmp_path / "truth.json",
        progress=False,
    )
    truth = json.loads((tmp_path / "truth.json").read_text())
    # The goal is 0.3 px. The rim locator's centres drift with the LEDs across the Mini's flat
    # gel (~0.45 px); mirror symmetry does not, and its affine residual shows it.
    assert record["locator"] == "symmetry", record
    assert record["residual_px_by_locator"]["symmetry"] < record["residual_px_by_locator"]["rim"]
    assert record["error_px"] <= 0.3, record
    assert record["residual_px"] <= 0.2, record
    assert abs(record["rotation_deg"] - truth["seating_rotation_deg"]) < 0.2
    # the default first-contact search: the touch height within the target, 0.02 mm (measured
    # -0.012: the geometric gel's raised rim bends the contact signal's power law; 0.001-0.004 mm
    # on the DIGIT's geometric and elastic gels, docs/explanation/registration.md)
    assert record["touch_method"] == "search"
    assert abs(record["touch_offset_error_mm"]) <= 0.02, record


@pytest.mark.long
@pytest.mark.slow
def test_probing_at_several_depths_separates_touch_height_from_rim_offset(tmp_path):
    """One depth: the rim's edge offset reads as 0.09 mm of extra depth (README, registration).
    Several: both are fitted, and the touch height comes out within 0.05 mm."""
    plan = {
        "spacing_mm": 2.0,
        "depths_mm": [0.5, 1.0, 1.5],
        "frames": 1,
        "touch_search": {"points": 0},  # the radii's estimate, for plans without
    }
    record = collect_and_register(tmp_path, "digit", plan, 3)
    assert record["touch_method"] == "rim" and record["touch_search"] is None
    assert abs(record["touch_offset_error_mm"]) < 0.05, record
    # the located rim sits outside the true edge by about a pixel (19.5 px/mm)
    assert 0.02 < record["rim_edge_offset_mm"] < 0.1, record


def assert_search_found_the_touch(record, folder, within_mm=0.01):
    """Within `within_mm` of the hidden touch height (the issue's target 0.02 mm; mean 3.3 um on
    the DIGIT and 8.8 um on the Mini over seeds 0-2 in docs/explanation/registration.md), the affine from the
    grid rows, and no touch frame in the training set."""
    assert record["touch_method"] == "search"
    assert abs(record["touch_offset_error_mm"]) <= within_mm, record
    assert len(record["touch_search"]["offset_mm_by_place"]) == 3
    assert record["error_px"] < 0.5, record
    # touch frames only locate the gel: the training set holds grid frames alone
    samples = (folder / "ts" / "samples.csv").read_text().splitlines()
    assert len(samples) - 1 == record["frames_labelled"]
    assert record["frames_labelled"] + record["frames_too_deep"] == record["frames_in_view"]
    raw = open_raw(folder / "raw.zarr")
    assert record["frames_in_view"] <= raw.sizes["frame"] - record["touch_search"]["frames"]


@pytest.mark.long
@pytest.mark.parametrize(
    "calibration, within_mm",
    # the Mini's touch is found less closely: 8.8 um mean, 14.2 at worst over seeds 0-2 of
    # docs/explanation/registration.md (its table of touch-height errors), 10.4 on this fixture's seed 3; held
    # to the 0.02 mm
    [("paper_digit_calibration", 0.01), ("paper_mini_calibration", 0.02)],
)
def test_touch_search_finds_the_hidden_touch_height_at_d_equal_r(calibration, within_mm, request):
    """config/paper.yaml's depth, d = R, on both vision sensors: the rim's radii tell nothing there
    (a = R), the default first-contact search does."""
    _, folder, record = request.getfixturevalue(calibration)
    assert_search_found_the_touch(record, folder, within_mm)


def test_a_plan_without_registration_presses_registers_the_rows_captured_so_far(
    paper_digit_calibration, monkeypatch
):
    """A quick calibration between rounds registers its first rows alone; with no registration
    presses their grid presses are located, not the plan's whole grid (not yet pressed)."""
    from threedcal.dataset import build
    from threedcal.dataset.build import register_store

    scene, folder, _ = paper_digit_calibration
    whole = register_store(dataset_settings(scene), folder / "raw.zarr", progress=False)
    rows = int(whole.rows("grid")[0]) + 40
    so_far = register_store(dataset_settings(scene), folder / "raw.zarr", progress=False, rows=rows)
    assert len(so_far.phase) == rows and so_far.registered_rows.max() < rows
    assert list(so_far.registered_rows) == [r for r in whole.registered_rows if r < rows]
    ideal = so_far.registration.fit.ideal(np.array([[10.0, 10.0]]))
    assert np.allclose(ideal, whole.registration.fit.ideal(np.array([[10.0, 10.0]])), atol=1.0)
    # registered again (a quick calibration's next round): the last fit when it located the same
    # rows, whose frames never change; fitted anew when the rows differ
    fits = []

    def fit(*args):  # the locating and fitting, recorded, its answer the last round's
        fits.append(args[2])
        return so_far.registration

    monkeypatch.setattr(build, "_register", fit)
    same = register_store(
        dataset_settings(scene), folder / "raw.zarr", progress=False, rows=rows, prior=so_far
    )
    assert fits == [] and same.registration is so_far.registration
    assert np.array_equal(same.centres, so_far.centres)
    register_store(
        dataset_settings(scene), folder / "raw.zarr", progress=False, rows=rows - 5, prior=so_far
    )
    assert len(fits) == 1 and list(fits[0]) == list(so_far.registered_rows[:-5])


@pytest.mark.long
def test_touch_search_finds_the_hidden_touch_height_with_a_vertical_rim(tmp_path):
    """A cross plan cycling d < R and d > R (a vertical contact rim)."""
    plan = {
        "pattern": "cross",
        "spacing_mm": 2.0,
        "depths_mm": [1.0, 3.0],
        "depth_mode": "cycle",
        "frames": 1,
        "arm_width_mm": 2.0,
    }
    scene = collect_on_bench(tmp_path, lens_free("digit"), plan, 5)
    paths = [tmp_path / n for n in ("ts", "splits.csv", "reg.json", "reg.png", "truth.json")]
    record = build_collected(dataset_settings(scene), tmp_path / "raw.zarr", *paths, progress=False)
    assert_search_found_the_touch(record, tmp_path)
    # the 3 mm presses (a 1 mm wall the camera looks along) register the rig but are not trained
    # on (dataset.max_depth_over_radius, default 0.75): every labelled frame is a 1 mm press
    samples = pd.read_csv(tmp_path / "ts" / "samples.csv")
    assert record["frames_too_deep"] > 0 and record["frames_labelled"] > 0
    assert 0 < record["probe_points_labelled"] < record["probe_points_in_view"]
    assert samples["depth_mm"].between(0.9, 1.1).all()
    # null keeps them; a limit below every press leaves nothing to train on: refused, naming the key
    # (their outputs beside the default's, which the checks above read)
    others = [tmp_path / f"null_{n}" for n in ("ts", "splits.csv", "reg.json", "reg.png")]
    every = {**scene, "dataset": {**scene["dataset"], "max_depth_over_radius": None}}
    kept = build_collected(dataset_settings(every), tmp_path / "raw.zarr", *others, progress=False)
    assert kept["frames_too_deep"] == 0 and kept["frames_labelled"] == kept["frames_in_view"]
    assert kept["probe_points_labelled"] == kept["probe_points_in_view"]
    none = {**scene, "dataset": {**scene["dataset"], "max_depth_over_radius": 0.1}}
    with pytest.raises(ConfigError, match="dataset.max_depth_over_radius: 0.1 leaves no frame"):
        build_collected(dataset_settings(none), tmp_path / "raw.zarr", *others, progress=False)


# ------------------------------------------------------- contact laws the simulator does not have
def hertz_surface(self, indenter, center_px, rotation_deg, depth_mm, window):
    """GelSimulator.surface with the Hertz solution for a sphere on an elastic half-space in place
    of the rigid gel: a = sqrt(R d); the surface follows d − r²/2R inside,
    ((2a² − r²) asin(a/r) + a sqrt(r² − a²)) / (π R) outside (it sinks around the contact)."""
    y0, y1, x0, x1 = window
    axis_x, axis_y = self.axis_mm(center_px)
    r = np.hypot(self.X[y0:y1, x0:x1] - axis_x, self.Y[y0:y1, x0:x1] - axis_y)
    radius = indenter.radius_mm
    a = math.sqrt(radius * depth_mm)
    safe = np.maximum(r, a)
    outside = (
        (2 * a * a - safe**2) * np.arcsin(np.minimum(a / safe, 1.0))
        + a * np.sqrt(np.maximum(safe**2 - a * a, 0.0))
    ) / (math.pi * radius)
    sink = np.where(r < a, depth_mm - r * r / (2 * radius), outside)
    return (self.Z0[y0:y1, x0:x1] + sink).astype(np.float32), r < a


def wide_window(self, indenter, center_px, depth_mm, rotation_deg=0.0):
    """GelSimulator.window reaching 3 R around the axis: where the Hertz surface still sinks."""
    reach = 3 * indenter.radius_mm * self.px_per_mm
    x0, x1 = max(int(center_px[0] - reach), 0), min(int(center_px[0] + reach) + 1, self.width)
    y0, y1 = max(int(center_px[1] - reach), 0), min(int(center_px[1] + reach) + 1, self.height)
    return (y0, y1, x0, x1) if x1 - x0 >= 3 and y1 - y0 >= 3 else None


def wide_skirt(sensor: str, folder) -> str:
    """`sensor`'s profile with a skirt three times as wide holding most of the displaced volume."""
    from threedcal.profiles import resolve_profile

    profile = yaml.safe_load(resolve_profile("sensor", sensor).read_text())
    profile["gel"].update(skirt_width_per_thickness=0.3, rim_volume_fraction=0.8)
    path = folder / f"{sensor}_wide_skirt.yaml"
    path.write_text(yaml.safe_dump(profile))
    return str(path)


def touch_error_with_true_centres(tmp_path, sensor, seed):
    """Collect a touch search and measure δ with the contacts placed by the bench's true affine:
    the search alone, apart from the registration (tested above)."""
    from threedcal.collect.plan import dome_sag_at_px
    from threedcal.collect.scene_plan import plan_phases
    from threedcal.dataset.touch import TOUCH_FIT_SPAN_MM, measure_touch_search

    plan = {"spacing_mm": 8.0, "depth_mm": 1.0, "frames": 1}
    scene = collect_on_bench(tmp_path, sensor, plan, seed)
    raw = open_raw(tmp_path / "raw.zarr")
    truth = json.loads((tmp_path / "truth.json").read_text())
    profile = raw.attrs["sensor_profile"]
    phase = plan_phases(raw.attrs["plan"], scene["plan"], profile)
    rows = np.searchsorted(raw["point"].values, np.flatnonzero(phase == "touch"))
    xy = np.column_stack([raw["cmd_x_mm"].values[rows], raw["cmd_y_mm"].values[rows]])
    affine = np.asarray(truth["affine_px_per_mm"])
    centres = xy @ affine[:, :2].T + affine[:, 2]
    result = measure_touch_search(
        raw["frames"].values[rows],
        raw["blank_frames"].values,
        raw["depth_mm"].values[rows] - dome_sag_at_px(profile, centres[:, 0], centres[:, 1]),
        np.unique(xy, axis=0, return_inverse=True)[1].ravel(),
        centres,
        float(profile["px_per_mm"]),
        reach_mm=2.0,
        span_mm=TOUCH_FIT_SPAN_MM,
    )
    return result.offset_mm - truth["touch_offset_mm"]


@pytest.mark.long
@pytest.mark.parametrize(
    "sensor, change, seed",
    [("digit", "elastic", 11), ("gelsight_mini", "elastic", 12), ("gelsight_mini", "skirt", 13)],
)
def test_touch_search_does_not_assume_the_contact_law(tmp_path, monkeypatch, sensor, change, seed):
    """The search fits contact area against depth with a free slope: a Hertz-like elastic gel
    (a² = Rd, the surface sinking around the contact) or a skirt three times as wide holding most
    of the displaced volume leave it within 0.02 mm (measured: 8 and 2 um). The rim's radii read
    an elastic contact as half as deep: hundreds of micrometres off."""
    from threedcal.sim.optics import GelSimulator

    if change == "elastic":  # the Hertz solution in place of the rigid gel
        monkeypatch.setattr(GelSimulator, "surface", hertz_surface)
        monkeypatch.setattr(GelSimulator, "window", wide_window)
    else:
        sensor = wide_skirt(sensor, tmp_path)
    assert abs(touch_error_with_true_centres(tmp_path, str(sensor), seed)) <= 0.02


@pytest.mark.long
def test_touch_search_sees_through_a_blurred_camera(tmp_path):
    """The elastic DIGIT behind a 6 px camera blur (what the optics fit finds on the real DIGIT
    frames, profile digit_fots): a contact's half-peak size is then mostly blur, and a line through
    the sizes put the gel 0.36 mm too high (the search before its contact signal; registration of
    the default plan, seed 11). The signal is a projection, which a blur scales but does not offset:
    within 0.01 mm (measured 0.1 um here, at most 0.8 um on seeds 21-24)."""
    from conftest import _profile_variant

    def blurred(profile):
        profile["gel"]["mechanics"] = "elastic"
        profile["optics"]["blur_sigma_px"] = 6.0

    sensor = _profile_variant("digit", "elastic-blur6", blurred)
    assert abs(touch_error_with_true_centres(tmp_path, sensor, 11)) <= 0.01


@pytest.mark.long
@pytest.mark.slow
def test_a_domed_gels_edge_presses_train_at_the_depth_the_plan_wrote(tmp_path):
    """Near the DIGIT's edge the plan commands a 1 mm press up to a millimetre deeper (the dome's
    sag): dataset.max_depth_over_radius (0.75 R = 1.5 mm) reads the plan's 1 mm and keeps it."""
    plan = {"spacing_mm": 2.0, "depth_mm": 1.0, "frames": 1}
    record = collect_and_register(tmp_path, "digit", plan, 2)
    raw = open_raw(tmp_path / "raw.zarr")
    assert float(raw["depth_mm"].max()) > 1.5  # commanded past the limit at the edge
    assert record["frames_too_deep"] == 0, record
    assert record["frames_labelled"] == record["frames_in_view"] > 0, record
