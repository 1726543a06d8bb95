"""Load and validate a study config: schema check with messages that name the key, defaults, scene rules.

The same function serves the Snakefile and the CLI, so a config that the CLI accepts is one the
workflow accepts, and vice versa.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from threedcal.collect.plan import validate_plan, whole_contacts
from threedcal.collect.quick_plan import quick_plan, quick_problems, rows_per_press
from threedcal.collect.scene_plan import plan_from_config, registration_presses_of
from threedcal.dataset.importers import check_import, load_imported
from threedcal.dataset.reframe import reframe_problem
from threedcal.errors import ConfigError
from threedcal.mount import with_mount
from threedcal.object_refs import object_problem
from threedcal.pretrained import provenance, shipped_sensors, shipped_weights
from threedcal.profiles import ProfileNotFound, load_profile, resolve_profile
from threedcal.rig import check_devices
from threedcal.schema import fill_defaults, load_schema, load_yaml, schema_errors
from threedcal.sim.marlin import parse_faults
from threedcal.study.fractions import FULL_TRAINING_P, normalise_ablation, training_fractions
from threedcal.study.scene import rig_settings, scene_mount_values

# Keys that describe probing hardware, dropped from imported scenes after defaults are filled.
IMPORT_IRRELEVANT = (
    "printer",
    "port",
    "camera",
    "reader",
    "mount",
    "probe",
    "plan",
    "bench",
    "pressing",
)


def validate_config(
    config: Mapping, source: str = "config", *, check_files: bool = False, new_mount: bool = False
) -> dict:
    """Return a validated copy of `config` with defaults filled; raise ConfigError naming every bad key.

    Beyond the schema this finds what a run would refuse: unknown serial fault names, plans over the
    size limit, deeper than the sensor allows or outside the gel or the printer's travel.
    `check_files` (``threedcal config check``) also reads every imported dataset as its stage would.
    `new_mount` (``threedcal rig``, which writes it): a scene's mount file may be missing.
    """
    if not isinstance(config, Mapping):
        raise ConfigError(
            f"{source}: invalid config\n  (top level): must be a mapping of keys to values, "
            f"got {type(config).__name__}"
        )
    schema = load_schema()
    problems = schema_errors(config, schema)
    if problems:
        raise ConfigError(f"{source}: invalid config\n  " + "\n  ".join(problems))
    problems = [
        f"scenes.{name}.{msg}"
        for name, scene in config["scenes"].items()
        for msg in _scene_problems(scene)
    ]
    if problems:
        raise ConfigError(f"{source}: invalid config\n  " + "\n  ".join(problems))
    config = copy.deepcopy(dict(config))
    # each scene its own copy: a YAML alias (`model: *finetune`) would otherwise share one dict
    config["scenes"] = {name: copy.deepcopy(scene) for name, scene in config["scenes"].items()}
    fill_defaults(config, schema)
    for scene in config["scenes"].values():
        scene["ablation"] = normalise_ablation(scene.get("ablation"))
        scene.setdefault("seed", config["seed"])
        scene.setdefault("torch_threads", config["torch_threads"])
        if is_imported(scene):  # no printer, probe or plan: the data exists already
            for key in IMPORT_IRRELEVANT:
                scene.pop(key, None)
    problems = (
        [
            f"scenes.{name}.{msg}"
            for name, scene in config["scenes"].items()
            for msg in _run_problems(scene, check_files, new_mount)
        ]
        + _realism_problems(config)
        + _real_check_problems(config)
    )
    problems += compare_problems(config)
    if problems:
        raise ConfigError(f"{source}: invalid config\n  " + "\n  ".join(problems))
    return config


def realism_sets(config: Mapping[str, Any]) -> list[list[str | None]]:
    """[real folder, sensor, gel mechanics or None] the realism stage fits and compares
    (realism.real/sensor first, then realism.also); [] without a realism section."""
    realism = config.get("realism") or {}
    if not realism:
        return []
    first = {"sensor": "gelsight_mini", **realism}
    return [
        [str(s["real"]), str(s["sensor"]), s.get("gel_mechanics")]
        for s in [first, *realism.get("also", [])]
    ]


def _realism_problems(config: Mapping) -> list[str]:
    """The realism stage's folders and sensors, named now (Snakemake would refuse a missing folder
    only when it parses the workflow, without naming the key)."""
    problems = []
    for i, (real, sensor, _) in enumerate(realism_sets(config)):
        where = "realism" if i == 0 else f"realism.also[{i - 1}]"
        if not Path(real).is_dir():
            problems.append(f"{where}.real: {real} is not a folder (a ball-image dataset expected)")
        try:
            load_profile("sensor", sensor)
        except ConfigError as exc:
            problems.append(f"{where}.sensor: {exc}")
    return problems


def real_check_sets(config: Mapping[str, Any]) -> list[dict]:
    """The real_check stage's {real, sensor} sets; [] without a real_check section."""
    return [dict(s) for s in (config.get("real_check") or {}).get("sets", [])]


def _real_check_problems(config: Mapping) -> list[str]:
    """The real_check stage's folders and sensors (with shipped weights), named now."""
    problems = []
    for i, entry in enumerate(real_check_sets(config)):
        where = f"real_check.sets[{i}]"
        if not Path(entry["real"]).is_dir():
            problems.append(f"{where}.real: {entry['real']} is not a folder (a ball-image dataset)")
        if entry["sensor"] not in shipped_sensors():
            problems.append(
                f"{where}.sensor: no shipped weights for {entry['sensor']!r} (shipped: "
                f"{', '.join(shipped_sensors())})"
            )
    return problems


def _run_problems(scene: Mapping, check_files: bool, new_mount: bool = False) -> list[str]:
    """What the scene's stages would refuse at run time, found before anything runs."""
    try:
        sensor = load_profile("sensor", scene["sensor"])
        printer = load_profile("printer", scene["printer"]) if scene.get("printer") else None
    except ConfigError as exc:
        return [f"{'printer' if 'printer profile' in str(exc) else 'sensor'}: {exc}"]
    try:
        sensor = with_mount(sensor, scene_mount_values(scene, None, missing_ok=new_mount))
    except ConfigError as exc:
        return [str(exc)]
    if check_files and (scene.get("model") or {}).get("init") == "pretrained":
        # (the workflow finds them when it plans a training: `make pretrained` builds them)

        try:
            shipped_weights(sensor.get("name"))
        except ConfigError as exc:
            return [f"model.init: {exc}".replace("model.init: model.init: ", "model.init: ")]
    if (scene.get("sim_to_real") or {}).get("enabled") and not (
        is_imported(scene) and sensor.get("type") == "vision"
    ):
        return [
            "sim_to_real.enabled: the sim-to-real stage needs an imported scene of a vision "
            "sensor (its real frames are what the simulated pretraining is tested on)"
        ]
    if is_imported(scene):
        shipped = _shipped_problems(scene, sensor)
        if shipped or not check_files:
            return shipped  # the files: read by `config check` and by the import stage itself
        try:
            check_import(scene["import"]["format"], scene["import"]["path"])
        except ConfigError as exc:
            return [f"import.path: {exc}"]
        return _shipped_problems(scene, sensor, frames=True)
    problems = []
    try:  # a real printer with the simulated camera: refused by collect, so named here first
        check_devices(rig_settings(scene), sensor, source="scene")
    except ConfigError as exc:
        problems.append(str(exc).removeprefix("scene."))
    try:
        parse_faults(scene["bench"].get("faults", ""))
    except ConfigError as exc:
        problems.append(f"bench.faults: {exc}")
    if scene["plan"].get("pattern") == "quick":
        quick = quick_scene_problems(scene, sensor)
        if quick:
            return problems + quick
    try:
        plan = plan_from_config(scene["plan"], sensor, quick_run(scene))
        csv = scene["plan"].get("csv")
        validate_plan(plan, sensor, printer, source=f"plan ({csv})" if csv else "plan")
    except ConfigError as exc:
        text = str(exc)
        problems.append(text if text.startswith("plan") else f"plan: {text}")
    return problems + _object_problems(scene)


def _shipped_problems(scene: Mapping, sensor: Mapping, frames: bool = False) -> list[str]:
    """sim_to_real.shipped: weights shipped for the scene's sensor; with `frames`, the imported
    frames (after dataset.downscale) can be pooled, or turned and pooled, to their size."""
    values = scene.get("sim_to_real") or {}
    if not (values.get("enabled") and values.get("shipped")):
        return []

    if sensor.get("name") not in shipped_sensors():
        return [
            f"sim_to_real.shipped: no shipped weights for sensor {sensor.get('name')!r} "
            f"(shipped: {', '.join(shipped_sensors()) or 'none'}); set shipped: false"
        ]
    if not frames:
        return []

    blank = load_imported(
        scene["import"]["format"], scene["import"]["path"], sensor["image"].get("orientation")
    ).blank
    factor = int((scene.get("dataset") or {}).get("downscale", 1))
    shape = (blank.shape[0] // factor, blank.shape[1] // factor)
    problem = reframe_problem(shape, tuple(provenance(sensor["name"])["image_shape"]))
    return [f"sim_to_real.shipped: the imported {problem}"] if problem else []


def quick_scene_problems(scene: Mapping, sensor: Mapping) -> list[str]:
    """What a quick calibration (plan.pattern: quick) would refuse once its printer had moved:
    rounds that cannot cover the gel, a stop rule out of range, shipped weights made for another
    sensor, network or frame size, and stages it does not run."""
    # local: scipy stays out of the Snakefile's parse
    from threedcal.stop_rule import rule_problems

    quick = scene["quick"]
    problems = quick_problems(scene["plan"], sensor)
    problems += rule_problems(float(quick["margin"]), float(quick["confidence"]))
    if not problems and sensor.get("type") == "vision" and sensor.get("lens"):
        problems += _quick_registration_problems(scene, sensor)
    asked = {
        "ablation": bool(normalise_ablation(scene.get("ablation"))["fractions"]),
        "objects": bool(scene.get("objects")),
    }
    for key in (k for k, wanted in asked.items() if wanted):
        problems.append(
            f"{key}: a quick calibration (plan.pattern: quick) trains one model round by "
            f"round; it has no {key} stage (remove `{key}`, or use a grid plan)"
        )
    model = scene.get("model") or {}
    if model.get("init") == "pretrained" and sensor.get("type") == "vision":
        problems += _pretrained_problems(sensor, model, int(scene["dataset"]["downscale"]))
    return problems


def _quick_registration_problems(scene: Mapping, sensor: Mapping) -> list[str]:
    """A quick plan whose registration presses (or, with none, its first round's) leave too few
    whole contacts for the first round's registration: the affine through the profile's lens, its
    contacts to spare for the outliers (threedcal.dataset.camera_fit.fit_camera)."""
    from threedcal.dataset.camera_fit import MIN_FIRST_CONTACTS  # local: as rule_problems (scipy)

    plan = scene["plan"]
    rows = registration_presses_of(plan, sensor)
    which = f"its {len(rows)} registration presses"
    if rows.empty:
        first = quick_plan(sensor, plan, quick_run(scene))
        first = first.iloc[: int(plan["round_presses"]) * rows_per_press(plan)]
        paused = first[first["phase"] == "register"]
        rows = first if paused.empty else paused
        which = f"its first round's {len(rows)} presses"
        if not paused.empty:
            which += f" (paused {plan['registration']['depth_mm']:g} mm deep)"
    whole = whole_contacts(sensor, rows, float(scene["probe"]["radius_mm"]))
    if whole >= MIN_FIRST_CONTACTS:
        return []
    return [
        f"plan.registration: {which} would leave about {whole} contacts whole in the frame; the "
        f"first round's registration needs {MIN_FIRST_CONTACTS} (more round_presses, a "
        "shallower depth_mm, or registration presses; "
        "docs/explanation/registration.md#registration-presses)"
    ]


# The bench settings that decide which unit is simulated and how it sits in its base (with the
# sensor profile and the scene's seed): two scenes alike in these probe the same unit, seated alike.
UNIT_KEYS = (
    "unit",
    "gel_mechanics",
    "seating_offset_mm",
    "seating_rotation_deg",
    "touch_offset_mm",
)


def compare_problems(config: Mapping) -> list[str]:
    """A quick scene's `quick.compare_with` (its full calibration, arm (c) of quick/arms.csv): a
    collected scene of this config, of the same unit (sensor, and on the bench the same unit,
    seating and seed), with P = 80 models, test objects and the same probe and working resolution."""
    problems = []
    for name, scene in config["scenes"].items():
        other = (scene.get("quick") or {}).get("compare_with")
        if other is None:
            continue
        key = f"scenes.{name}.quick.compare_with"
        if (scene.get("plan") or {}).get("pattern") != "quick":
            problems.append(f"{key}: only a quick scene (plan.pattern: quick) is compared")
            continue
        full = config["scenes"].get(other)
        if full is None or other == name:
            names = ", ".join(n for n in config["scenes"] if n != name)
            problems.append(f"{key}: no other scene {other!r} in this config (scenes: {names})")
            continue
        if is_imported(full) or (full.get("plan") or {}).get("pattern") == "quick":
            problems.append(f"{key}: {other} is not a collected grid scene of this unit")
            continue
        differ = [
            f"{k} {scene.get(k)!r} here, {full.get(k)!r} there"
            for k in ("sensor", "port", "seed")
            if scene.get(k) != full.get(k)
        ]
        if scene.get("port") == "sim":
            differ += [
                f"bench.{k} {scene['bench'].get(k)!r} here, {full['bench'].get(k)!r} there"
                for k in UNIT_KEYS
                if scene["bench"].get(k) != full["bench"].get(k)
            ]
        for section, k in (("probe", "radius_mm"), ("dataset", "downscale")):
            if scene[section].get(k) != full[section].get(k):
                differ.append(
                    f"{section}.{k} {scene[section].get(k)!r} here, {full[section].get(k)!r} there"
                )
        if differ:
            problems.append(
                f"{key}: {other} is not this unit, seated and imaged alike: " + "; ".join(differ)
            )
        if FULL_TRAINING_P not in training_fractions(full):
            problems.append(
                f"{key}: {other} trains no P = {FULL_TRAINING_P} models (its ablation.fractions)"
            )
        if has_arms(scene) and not full.get("objects"):
            problems.append(
                f"{key}: {other} presses no test objects (its `objects`), which the arms score "
                "(or set quick.arms: false)"
            )
    return problems


def is_quick(scene: Mapping) -> bool:
    """A scene calibrated in rounds of presses (plan.pattern: quick)."""
    return not is_imported(scene) and (scene.get("plan") or {}).get("pattern") == "quick"


def compared_with(scene: Mapping) -> str | None:
    """The scene a quick scene's rounds are scored against (`quick.compare_with`), or None."""
    return (scene.get("quick") or {}).get("compare_with") if is_quick(scene) else None


def has_arms(scene: Mapping) -> bool:
    """A compared quick scene scored arm by arm (`quick.arms`, quick/arms.*)."""
    return bool(compared_with(scene)) and bool((scene.get("quick") or {}).get("arms", True))


def quick_run(scene: Mapping) -> int:
    """Which run of its quick calibration a quick scene is (`quick.run`, 1 unless set): run r
    draws its own presses and training seed, as a second calibration of the unit would."""
    return int((scene.get("quick") or {}).get("run", 1)) if is_quick(scene) else 1


def _pretrained_problems(sensor: Mapping, model: Mapping, downscale: int) -> list[str]:
    """The shipped weights against the frames and network a scene would fine-tune them on."""
    image = sensor["image"]
    shape = (int(image["height_px"]) // downscale, int(image["width_px"]) // downscale)
    try:
        shipped_weights(sensor.get("name"), shape)
    except ConfigError as exc:
        return [str(exc).replace("model.init: pretrained: ", "model.init: ", 1)]
    made = provenance(sensor["name"])
    if made.get("sensor") != sensor.get("name"):
        return [
            f"model.init: the shipped {sensor['name']} weights record sensor "
            f"{made.get('sensor')!r}: rebuild them (`make pretrained`)"
        ]
    if made.get("preset") and made["preset"] != model.get("preset"):
        return [
            f"model.preset: {model.get('preset')!r}, but the shipped {sensor['name']} weights "
            f"(model.init: pretrained) are a {made['preset']!r} network: set model.preset: "
            f"{made['preset']}, or train from scratch (init: null)"
        ]
    return []


def _object_problems(scene: Mapping) -> list[str]:
    """Each test object is a built-in name or an STL file that exists: found now, not at the
    pressing stage after the collection and the training. What the STL holds is read by
    threedcal.evaluate.objects.check_object_files (the workflow and `config check` call it): the
    collection's code never imports the evaluation's, so changing it never reruns a collection."""
    return [
        f"objects[{i}]: {problem}"
        for i, ref in enumerate(scene.get("objects") or [])
        if (problem := object_problem(ref))
    ]


def _scene_problems(scene: Mapping) -> list[str]:
    problems = []
    imported = "import" in scene
    if imported and scene.get("printer") is not None:
        problems.append("printer: an imported scene has no printer (remove `printer` or `import`)")
    if not imported and scene.get("printer") is None:
        problems.append("printer: required unless the scene has `import` (e.g. printer: ender3)")
    if imported and "plan" in scene:
        problems.append("plan: an imported scene has no probe plan (remove `plan` or `import`)")
    for kind in ("sensor", "printer"):
        ref = scene.get(kind)
        if ref is None:
            continue
        try:
            resolve_profile(kind, ref)
        except ProfileNotFound as exc:
            problems.append(f"{kind}: {exc}")
    if scene.get("sensor") is not None and not problems:
        problems += _magnetic_problems(scene)
    if not imported and scene.get("objects"):
        problems += [p for p in [mount_problem(scene)] if p]
    return problems


def _magnetic_problems(scene: Mapping) -> list[str]:
    """A magnetic (ReSkin) scene collects readings and trains the localisation MLP, nothing else."""
    if load_profile("sensor", scene["sensor"]).get("type") != "magnetic":
        if scene.get("reader", "sim") != "sim":
            return [
                "reader: only a magnetic sensor has a reader board; a camera sensor's device is `camera`"
            ]
        return []
    image_only = ("import", "ablation", "objects")
    problems = [
        f"{key}: not available for a magnetic sensor ({scene['sensor']}): it gives readings, "
        "not images (remove it)"
        for key in image_only
        if scene.get(key)
    ]
    if scene.get("camera", "sim") != "sim":
        problems.append(
            f"camera: a magnetic sensor ({scene['sensor']}) has no camera: name its board's serial "
            "device as `reader` (e.g. reader: /dev/ttyACM0)"
        )
    return problems


def load_config(path: str | Path, *, check_files: bool = False, new_mount: bool = False) -> dict:
    return validate_config(
        load_yaml(path) or {}, source=str(path), check_files=check_files, new_mount=new_mount
    )


def scene_config(config: Mapping, scene: str) -> dict:
    try:
        return config["scenes"][scene]
    except KeyError:
        names = ", ".join(config.get("scenes", {}))
        raise ConfigError(f"no scene {scene!r} in the config (scenes: {names})") from None


def is_imported(scene: Mapping) -> bool:
    return "import" in scene


def mount_problem(scene: Mapping) -> str | None:
    """What is wrong with a scene's mount (as `pressing.mount: ...`), or None."""
    if scene.get("pressing", {}).get("mount") is None and scene.get("port", "sim") != "sim":
        return (
            "pressing.mount: required when the printer presses the test objects on a real rig "
            f"(port {scene.get('port')!r}): give x_mm, y_mm, z_mm of the object's press-frame "
            "origin relative to the probe tip and its rotation_deg as mounted"
        )
    return None
