"""Load and validate a study config: schema check with messages that name the key, defaults, scene rules.

The same function serves the Snakefile and the CLI, so a config that the CLI accepts is one the
workflow accepts, and vice versa.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Iterator, Mapping
from importlib.resources import files
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from threedcal.errors import ConfigError

SCHEMA_PATH = Path(str(files("threedcal") / "schemas" / "config.schema.yaml"))

# The one fraction trained when a scene asks for no ablation: all training coordinates (80 % of all).
FULL_TRAINING_P = 80
# Keys that describe probing hardware, dropped from imported scenes after defaults are filled.
IMPORT_IRRELEVANT = ("printer", "port", "camera", "probe", "plan", "bench", "pressing")


def plain(value: Any) -> Any:
    """numpy scalars and arrays as plain Python values, so messages read `nan`, not `np.float64(nan)`."""
    item = getattr(value, "item", None)
    if item is not None and type(value).__module__ == "numpy":
        return value.item() if getattr(value, "ndim", 0) == 0 else value.tolist()
    return value


def canonical_json(value: Any) -> str:
    """One text per value whatever the order of its keys: what digests and Snakemake params compare."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=plain)


class DuplicateKeyError(ConfigError):
    """A YAML mapping names the same key twice: plain YAML keeps the last one silently."""


class _UniqueKeyLoader(yaml.SafeLoader):
    """yaml.SafeLoader that refuses a key given twice in one mapping (e.g. two scenes of one name)."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            first: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue  # `<<: *anchor` merges may override on purpose
                key = self.construct_object(key_node, deep=True)
                line = key_node.start_mark.line + 1
                try:
                    earlier = first.setdefault(key, line)
                except TypeError:
                    continue  # an unhashable key: SafeLoader reports it below
                if earlier != line:
                    raise DuplicateKeyError(
                        f"line {line}: duplicate key {key!r} (first on line {earlier}); YAML would "
                        "keep only the last one: remove or rename one of them"
                    )
        return super().construct_mapping(node, deep=deep)


def parse_yaml(text: str, source: str = "YAML") -> Any:
    """Parse YAML text like yaml.safe_load, but refuse duplicate keys; errors name `source`."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except DuplicateKeyError as exc:
        raise DuplicateKeyError(f"{source}: {exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: not valid YAML: {exc}") from exc


def load_yaml(path: str | Path) -> Any:
    """Read a YAML file (configs, profiles, dataset descriptions): duplicate keys are an error."""
    path = Path(path)
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file (YAML expected)") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from exc
    return parse_yaml(text, source=str(path))


def load_schema(path: Path = SCHEMA_PATH) -> dict:
    return load_yaml(path)


def key_path(parts) -> str:
    """Render a jsonschema error path as `scenes.digit.model.preset` (list items as `[i]`)."""
    out = ""
    for part in parts:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def _describe(error: jsonschema.ValidationError) -> str:
    where = key_path(error.absolute_path)
    if error.validator == "additionalProperties":
        allowed = sorted(error.schema.get("properties", {}))
        extra = sorted(set(error.instance) - set(allowed))
        return f"{where}: unknown key {', '.join(map(repr, extra))} (allowed: {', '.join(allowed)})"
    if error.validator == "enum":
        return f"{where}: {error.instance!r} is not allowed (allowed: {', '.join(map(str, error.validator_value))})"
    if error.validator == "required":
        return f"{where}: {error.message}"
    if "propertyNames" in error.schema_path:
        return f"{where}: name {error.instance!r} must match {error.validator_value}"
    return f"{where}: {error.message}"


def _iter_errors(instance: Any, schema: Mapping) -> Iterator[jsonschema.ValidationError]:
    validator = jsonschema.Draft202012Validator(schema)
    # Report the deepest error of each failing branch: it is the one that names the exact key.
    for error in sorted(validator.iter_errors(instance), key=lambda e: list(e.absolute_path)):
        leaves = list(error.context) if error.context else []
        yield min(leaves, key=lambda e: -len(e.absolute_path)) if leaves else error


def schema_errors(instance: Any, schema: Mapping) -> list[str]:
    return [_describe(e) for e in _iter_errors(instance, schema)]


def _fill_defaults(instance: Any, schema: Mapping, root: Mapping) -> None:
    """Fill `default` values of the schema into `instance`, in place (validated input only)."""
    if "$ref" in schema:
        schema = root["$defs"][schema["$ref"].rsplit("/", 1)[-1]]
    if not isinstance(instance, dict):
        return
    for key, sub in schema.get("properties", {}).items():
        if key not in instance and "default" in sub:
            instance[key] = copy.deepcopy(sub["default"])
        if key in instance:
            _fill_defaults(instance[key], sub, root)
    extra = schema.get("additionalProperties")
    if isinstance(extra, dict):
        for key, value in instance.items():
            if key not in schema.get("properties", {}):
                _fill_defaults(value, extra, root)


def validate_config(config: Mapping, source: str = "config", *, check_files: bool = False) -> dict:
    """Return a validated copy of `config` with defaults filled; raise ConfigError naming every bad key.

    Beyond the schema this finds what a run would refuse: unknown serial fault names, plans over the
    size limit, deeper than the sensor allows or outside the gel or the printer's travel.
    `check_files` (``threedcal config check``) also reads every imported dataset as its stage would.
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
    _fill_defaults(config, schema, schema)
    for scene in config["scenes"].values():
        scene.setdefault("seed", config["seed"])
        scene.setdefault("torch_threads", config["torch_threads"])
        if is_imported(scene):  # no printer, probe or plan: the data exists already
            for key in IMPORT_IRRELEVANT:
                scene.pop(key, None)
    problems = [
        f"scenes.{name}.{msg}"
        for name, scene in config["scenes"].items()
        for msg in _run_problems(scene, check_files)
    ]
    if problems:
        raise ConfigError(f"{source}: invalid config\n  " + "\n  ".join(problems))
    return config


def _run_problems(scene: Mapping, check_files: bool) -> list[str]:
    """What the scene's stages would refuse at run time, found before anything runs."""
    from threedcal.profiles import load_profile

    try:
        sensor = load_profile("sensor", scene["sensor"])
        printer = load_profile("printer", scene["printer"]) if scene.get("printer") else None
    except ConfigError as exc:
        return [f"{'printer' if 'printer profile' in str(exc) else 'sensor'}: {exc}"]
    if is_imported(scene):
        if not check_files:
            return []  # read by `config check` and by the import stage itself
        from threedcal.dataset.importers import check_import

        try:
            check_import(scene["import"]["format"], scene["import"]["path"])
        except ConfigError as exc:
            return [f"import.path: {exc}"]
        return []
    problems = []
    from threedcal.sim.marlin import parse_faults

    try:
        parse_faults(scene["bench"].get("faults", ""))
    except ConfigError as exc:
        problems.append(f"bench.faults: {exc}")
    from threedcal.collect.plan import plan_from_config, validate_plan

    try:
        plan = plan_from_config(scene["plan"], sensor)
        csv = scene["plan"].get("csv")
        validate_plan(plan, sensor, printer, source=f"plan ({csv})" if csv else "plan")
    except ConfigError as exc:
        text = str(exc)
        problems.append(text if text.startswith("plan") else f"plan: {text}")
    return problems


def _scene_problems(scene: Mapping) -> list[str]:
    from threedcal.profiles import ProfileNotFound, resolve_profile

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
        from threedcal.evaluate.pressing import mount_problem

        problems += [p for p in [mount_problem(scene)] if p]
    return problems


def _magnetic_problems(scene: Mapping) -> list[str]:
    """A magnetic (ReSkin) scene collects readings and trains the localisation MLP, nothing else."""
    from threedcal.profiles import load_profile

    if load_profile("sensor", scene["sensor"]).get("type") != "magnetic":
        return []
    image_only = ("import", "ablation", "objects")
    return [
        f"{key}: not available for a magnetic sensor ({scene['sensor']}): it gives readings, "
        "not images (remove it)"
        for key in image_only
        if scene.get(key)
    ]


def load_config(path: str | Path, *, check_files: bool = False) -> dict:
    return validate_config(load_yaml(path) or {}, source=str(path), check_files=check_files)


def scene_config(config: Mapping, scene: str) -> dict:
    try:
        return config["scenes"][scene]
    except KeyError:
        names = ", ".join(config.get("scenes", {}))
        raise ConfigError(f"no scene {scene!r} in the config (scenes: {names})") from None


def training_fractions(scene: Mapping) -> list[int]:
    """The fractions P (percent) for which a scene trains one model each, ascending."""
    return sorted(scene.get("ablation") or [FULL_TRAINING_P])


def is_imported(scene: Mapping) -> bool:
    return "import" in scene
