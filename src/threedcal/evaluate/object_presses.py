"""The `object_presses` stage: the printer presses each test object at its planned poses, on the
simulated bench or a real rig (threedcal.rig), and one frame is kept per press.

A session on the simulated bench is a later session on the same, still seated sensor: the same gel
and paint, fresh camera noise, a lighting drift and a blank captured at its start; each object is
mounted anew (its true mount off the `pressing.mount` key by hidden errors, `true_mount`). On a
real rig the user mounts each object when the rig asks. See docs/explanation/objects.md.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from threedcal.collect.run import MotionSettings
from threedcal.errors import ConfigError
from threedcal.evaluate.groundtruth import surface_height
from threedcal.evaluate.objects import object_label
from threedcal.evaluate.press_plan import (
    SETS,
    ObjectPress,
    ObjectsSetup,
    PrinterFrame,
    check_presses,
    object_mesh,
    plan_presses,
    read_registration,
    session_draws,
    true_mount,
)
from threedcal.rig import Ask, Rig, check_devices, open_rig
from threedcal.sim.bench import MountedObject
from threedcal.sim.indenters import Relief


def relief_indenter(mesh, px_per_mm: float, rotation_deg: float = 0.0):
    """The mesh as the simulator's height-map indenter: protrusion toward the gel (mm), NaN outside."""
    extent = float(np.ptp(mesh.vertices[:, :2], axis=0).max())
    size = int(math.ceil(extent * math.sqrt(2) * px_per_mm)) + 5
    surface = surface_height(
        mesh, (size, size), px_per_mm, ((size - 1) / 2, (size - 1) / 2), rotation_deg
    )
    relief = np.where(surface.covered, -surface.height_mm, np.nan)
    return Relief(relief, px_per_mm)


@dataclass
class SessionResult:
    blank: np.ndarray  # float32 (H, W, 3): mean of the session's blank frames
    frames: list  # one uint8 frame per press
    records: list  # per press: commanded and reported head position (+ bench truth)
    printer_s: float  # the printer's clock over the session


def run_session(
    rig: Rig,
    presses: Sequence[ObjectPress],
    frame: PrinterFrame,
    settings,
    *,
    mount_object: Callable[[str], None],
    progress: bool = True,
) -> SessionResult:
    """Home, capture the session's blank, then object by object: mount it, press it at each of its
    poses (lift → travel → plunge → wait → settle → flush → one frame), lift. On the bench each
    record keeps the pose it truly rendered (`truth`)."""
    host, camera, clock = rig.printer, rig.sensor, rig.clock
    started = rig.hardware_clock()
    safe_z = frame.clearance_z()
    host.home()
    host.hold_motors()
    width, height = (float(v) for v in frame.sensor["probing"]["plan_area_mm"])
    cx, cy = frame.origin_printer(width / 2, height / 2)
    host.move_to(z=safe_z, feed_mm_s=settings.plunge_feed_mm_s)
    host.move_to(x=cx, y=cy, feed_mm_s=settings.travel_feed_mm_s)
    host.wait_until_idle()
    clock.sleep(settings.settle_s)
    camera.flush()
    blank, _ = camera.capture(settings.n_blank)
    frames, records = [], []
    mounted = None
    for press in tqdm(presses, desc="presses", unit="press", disable=not progress):
        if press.object != mounted:
            host.move_to(z=safe_z, feed_mm_s=settings.plunge_feed_mm_s)
            host.wait_until_idle()
            mount_object(press.object)
            mounted = press.object
        x, y, z = frame.target(press)
        host.move_to(z=safe_z, feed_mm_s=settings.plunge_feed_mm_s)
        host.move_to(x=x, y=y, feed_mm_s=settings.travel_feed_mm_s)
        host.move_to(z=z, feed_mm_s=settings.plunge_feed_mm_s)
        host.wait_until_idle()
        clock.sleep(settings.settle_s)
        reported = host.position()
        camera.flush()
        shot, _ = camera.capture(1)
        frames.append(np.asarray(shot[0]))
        records.append(_press_record((x, y, z), reported, rig))
    host.move_to(z=safe_z, feed_mm_s=settings.plunge_feed_mm_s)
    host.wait_until_idle()
    blank = np.asarray(blank, dtype=np.float32).mean(axis=0)
    return SessionResult(blank, frames, records, rig.hardware_clock() - started)


def _press_record(commanded, reported, rig: Rig) -> dict:
    """Commanded and reported head position; where the steppers are (M114 counts: the commanded
    pose to within half a step); on the bench, the pose it truly rendered."""
    x, y, z = commanded
    steps = reported.steps_mm or (math.nan,) * 3
    record = {"cmd_x_mm": x, "cmd_y_mm": y, "cmd_z_mm": z}
    for axis, at, step in zip("xyz", reported, steps, strict=True):
        record[f"reported_{axis}_mm"] = at
        record[f"steps_{axis}_mm"] = step
    if rig.simulated:
        record["truth"] = dict(rig.bench.last_render)
    return record


def press_objects(
    setup: ObjectsSetup,
    registration_path: str | Path,
    out_dir: str | Path,
    *,
    name: str = "scene",
    progress: bool = True,
    ask: Ask | None = None,
) -> dict:
    """The `object_presses` rule: both sessions of presses, on the bench (port sim) or a real rig
    (where `ask` asks the user to mount each object: threedcal.rig).

    Writes `frames.npz` (frames, one per press, and each session's blank), `plan.csv` (each press:
    object, set, plan pose, commanded and reported head position), `truth.json` (what the bench
    really did, for reporting only; `{"simulated": false}` on a real rig) and `summary.json` (cost).
    Everything is checked before the printer moves.
    """
    source = f"scenes.{name}"
    sensor, printer = setup.sensor, setup.printer
    if sensor.get("type") != "vision":
        raise ConfigError(f"{source}: test objects need a vision sensor, not {sensor['name']!r}")
    check_devices(setup.rig, sensor, source)
    frame = PrinterFrame(sensor, read_registration(registration_path), setup.mount)
    seed = setup.seed
    presses = plan_presses(list(setup.objects), sensor, setup.pressing, seed)
    check_presses(presses, frame, sensor, printer, source)  # before anything moves
    settings = MotionSettings.from_profile(sensor)
    started = time.perf_counter()
    with open_rig(setup.rig, sensor, printer, ask=ask) as rig:
        results, truth = _press_sessions(rig, setup, frame, presses, seed, settings, progress)
    seconds = time.perf_counter() - started
    summary = {
        "presses": len(presses),
        "seconds": round(seconds, 3),
        "seconds_per_press": round(seconds / max(len(presses), 1), 4),
        **_write_presses(Path(out_dir), presses, results, truth),
    }
    (Path(out_dir) / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def _press_sessions(
    rig: Rig, setup: ObjectsSetup, frame: PrinterFrame, presses, seed: int, settings, progress
):
    """Both sessions on one rig. The bench stays seated as in the calibration (same seed and bench
    settings); each session gets its own camera noise and lighting and each object its true mount."""
    results, truth = {}, {"simulated": rig.simulated}
    if rig.simulated:
        truth.update(sessions={}, presses=[])
    hidden = setup.pressing["bench"]
    reliefs = {}
    for set_index, name in enumerate(SETS):
        mounts = {}

        def mount_object(ref, set_index=set_index, mounts=mounts):
            if not rig.simulated:
                rig.prompt(_mount_request(ref, frame.mount))
                return

            if ref not in reliefs:
                reliefs[ref] = relief_indenter(object_mesh(ref), rig.bench.gel.px_per_mm)
            real = true_mount(frame.mount, hidden, seed, set_index, ref)
            mounts[object_label(ref)] = asdict(real)
            rig.bench.mount(MountedObject(reliefs[ref], real.offset_mm, real.rotation_deg))

        if rig.simulated:
            noise_seed, gain = session_draws(seed, set_index, hidden["lighting_drift"])
            rig.bench.start_session(noise_seed, gain)
        session = [p for p in presses if p.set == name]
        results[name] = run_session(
            rig, session, frame, settings, mount_object=mount_object, progress=progress
        )
        if rig.simulated:
            rig.bench.mount(None)
            truth["sessions"][name] = {"lighting_gain_rgb": gain, "mounts": mounts}
            truth["presses"] += [
                {
                    "center_px": list(r["truth"]["center_px"]),
                    "rotation_deg": r["truth"]["rotation_deg"],
                    "depth_mm": r["truth"]["depth_mm"],
                }
                for r in results[name].records
            ]
    return results, truth


def _mount_request(ref: str, mount) -> str:
    return (
        f"Mount {object_label(ref)} on the print head in place of the ball (origin at "
        f"{mount.x_mm:+.2f}, {mount.y_mm:+.2f}, {mount.z_mm:+.2f} mm from the probe tip, turned "
        f"{mount.rotation_deg:g} deg)"
    )


def _write_presses(out: Path, presses, results, truth) -> dict:
    """frames.npz, plan.csv and truth.json; the printer's time per session (summary.json's)."""
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    frames = []
    for press, (record, image) in zip(
        presses,
        [(r, f) for s in SETS for r, f in zip(results[s].records, results[s].frames, strict=True)],
        strict=True,
    ):
        rows.append(
            {
                "frame": len(frames),
                "object": press.object,
                "label": object_label(press.object),
                "set": press.set,
                "press": press.number,
                "x_mm": press.x_mm,
                "y_mm": press.y_mm,
                "depth_mm": press.depth_mm,
                **{k: v for k, v in record.items() if k != "truth"},
            }
        )
        frames.append(image)
    np.savez_compressed(
        out / "frames.npz",
        frames=np.stack(frames),
        blanks=np.stack([results[s].blank for s in SETS]),
        sets=np.array(SETS),
    )
    pd.DataFrame(rows).to_csv(out / "plan.csv", index=False)
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return {
        "printer_s": {s: round(results[s].printer_s, 1) for s in SETS},
        "printer_s_per_press": round(
            sum(results[s].printer_s for s in SETS) / max(len(presses), 1), 2
        ),
    }


def read_presses(pressing_dir: str | Path) -> tuple[pd.DataFrame, np.ndarray, dict, dict]:
    """The object_presses outputs: plan table, frames, a blank per session, the bench truth."""
    pressing_dir = Path(pressing_dir)
    plan = pd.read_csv(pressing_dir / "plan.csv")
    with np.load(pressing_dir / "frames.npz") as data:
        frames = data["frames"]
        blanks = dict(zip(data["sets"].tolist(), data["blanks"], strict=True))
    truth = json.loads((pressing_dir / "truth.json").read_text())
    return plan, frames, blanks, truth
