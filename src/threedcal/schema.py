"""The bottom of the configuration spine: YAML reading, JSON-schema validation and defaults.

Configs (`threedcal.study.config`) and profiles (`threedcal.profiles`) are both read through here, so
neither imports the other for these basics and every module below them can read a validated file.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Iterator, Mapping
from functools import lru_cache
from importlib.resources import files
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from threedcal.errors import ConfigError

SCHEMA_DIR = Path(str(files("threedcal") / "schemas"))
SCHEMA_KINDS = ("config", "sensor", "printer")


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


# libyaml's parser where PyYAML has it (its wheels do): the same safe constructors and resolver in
# a fifth of pure Python's time on the profiles, schemas and configs, which every `snakemake` call
# and every job parses.
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _UniqueKeyLoader(_SAFE_LOADER):
    """The safe loader that refuses a key given twice in one mapping (e.g. two scenes of one name)."""

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
    """Parse YAML text like yaml.safe_load, but refuse duplicate keys; errors name `source`.

    Each call gets its own copy; a text is parsed once per process (a Snakefile parse reads the
    schemas and profiles dozens of times: ~1 s each `snakemake` call with pure-Python YAML)."""
    return copy.deepcopy(_parse_yaml(text, source))


@lru_cache(maxsize=256)  # bounded: fuzz tests parse thousands of texts
def _parse_yaml(text: str, source: str) -> Any:
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


def schema_path(kind: str) -> Path:
    """The JSON schema (as YAML) of a config (`config`) or a profile kind (`sensor`, `printer`)."""
    if kind not in SCHEMA_KINDS:
        raise ValueError(f"unknown schema {kind!r} (schemas: {', '.join(SCHEMA_KINDS)})")
    return SCHEMA_DIR / f"{kind}.schema.yaml"


def load_schema(kind: str = "config") -> dict:
    return load_yaml(schema_path(kind))


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
    # Among equally deep ones, a type mismatch is the alternative the value was not meant as (a
    # `dome` mapping is not `null`): what is wrong inside the alternative of its type comes first.
    for error in sorted(validator.iter_errors(instance), key=lambda e: list(e.absolute_path)):
        leaves = list(error.context) if error.context else []
        yield _best_leaf(leaves) if leaves else error


def _best_leaf(leaves: list[jsonschema.ValidationError]) -> jsonschema.ValidationError:
    best = min(leaves, key=lambda e: (-len(e.absolute_path), e.validator == "type"))
    if best.validator != "type":
        return best
    # No alternative of the value's type: name every type allowed, not just the first.
    types: list[str] = []
    for leaf in leaves:
        if leaf.validator == "type" and leaf.absolute_path == best.absolute_path:
            value = leaf.validator_value
            types += [t for t in (value if isinstance(value, list) else [value]) if t not in types]
    best = copy.copy(best)
    best.message = f"{best.instance!r} is not of type " + " or ".join(map(repr, types))
    return best


def schema_errors(instance: Any, schema: Mapping) -> list[str]:
    return [_describe(e) for e in _iter_errors(instance, schema)]


def section(name: str, values: Mapping[str, Any], where: str | None = None) -> dict:
    """A config section (`$defs/<name>` of the config schema) validated, the schema's defaults filled.

    What settings classes are built from, so no class keeps defaults of its own."""
    schema = load_schema("config")
    node = schema["$defs"][name]
    values = copy.deepcopy(dict(values))
    problems = schema_errors(values, node)
    if problems:
        raise ConfigError(f"{where or name}: " + "; ".join(problems))
    fill_defaults(values, node, schema)
    return values


def fill_defaults(instance: Any, schema: Mapping, root: Mapping | None = None) -> None:
    """Fill `default` values of the schema into `instance`, in place (validated input only)."""
    root = schema if root is None else root
    if "$ref" in schema:
        schema = root["$defs"][schema["$ref"].rsplit("/", 1)[-1]]
    if not isinstance(instance, dict):
        return
    for key, sub in schema.get("properties", {}).items():
        if key not in instance and "default" in sub:
            instance[key] = copy.deepcopy(sub["default"])
        if key in instance:
            fill_defaults(instance[key], sub, root)
    extra = schema.get("additionalProperties")
    if isinstance(extra, dict):
        for key, value in instance.items():
            if key not in schema.get("properties", {}):
                fill_defaults(value, extra, root)


REFERENCE_BEGIN = (
    "<!-- generated from the config schema by `threedcal config reference`; do not edit -->"
)
REFERENCE_END = "<!-- end of generated reference -->"


def _resolved(node: Mapping, root: Mapping) -> dict:
    node = dict(node)
    while "$ref" in node:
        target = root["$defs"][node.pop("$ref").rsplit("/", 1)[-1]]
        node = {**target, **node}
    return node


def _allowed(node: Mapping) -> str:
    if "enum" in node:
        return " \\| ".join(f"`{v}`" for v in node["enum"])
    kind = node.get("type", "")
    kinds = kind if isinstance(kind, list) else [kind]
    text = " or ".join(str(k) for k in kinds if k)
    if kind == "array" and "enum" in node.get("items", {}):
        text = "list of " + " \\| ".join(f"`{v}`" for v in node["items"]["enum"])
    bounds = [
        f"{sym} {node[key]}"
        for key, sym in (
            ("minimum", "≥"),
            ("exclusiveMinimum", ">"),
            ("maximum", "≤"),
            ("exclusiveMaximum", "<"),
        )
        if key in node
    ]
    return ", ".join([text, *bounds]) if text else ", ".join(bounds)


def schema_keys(kind: str = "config") -> list[tuple[str, dict]]:
    """Every key of a schema as (dotted path, resolved node), depth first; `<name>` for map keys."""
    root = load_schema(kind)
    out: list[tuple[str, dict]] = []

    def walk(node: Mapping, path: str) -> None:
        node = _resolved(node, root)
        for key, sub in node.get("properties", {}).items():
            here = f"{path}.{key}" if path else key
            sub = _resolved(sub, root)
            if not any(p == here for p, _ in out):
                out.append((here, sub))
            walk(sub, here)
        extra = node.get("additionalProperties")
        if isinstance(extra, Mapping) and ("$ref" in extra or "properties" in extra):
            walk(extra, f"{path}.<name>")
        for alternative in [*node.get("oneOf", []), *node.get("anyOf", [])]:
            walk(alternative, path)

    walk(root, "")
    return out


def reference_table(kind: str = "config") -> str:
    """A Markdown list of every key: allowed values, default, description (docs/reference/).

    A block defined once and used in two places (a scene's model and the pretraining's) is listed
    in full under a scene; the other place names it and shows only its own defaults."""
    root = load_schema(kind)
    places: dict[str, list[str]] = {}
    lines: list[str] = []
    listed: set[str] = set()

    def walk(node: Mapping, path: str, emit: bool) -> None:
        node = _resolved(node, root)
        for key, sub in node.get("properties", {}).items():
            here = f"{path}.{key}" if path else key
            ref = sub.get("$ref", "").rsplit("/", 1)[-1] if isinstance(sub, Mapping) else ""
            sub = _resolved(sub, root)
            block = "properties" in sub
            if not emit:
                if ref and block:
                    places.setdefault(ref, []).append(here)
                walk(sub, here, emit)
                continue
            main = min(places.get(ref, [here]), key=lambda p: (not p.startswith("scenes."), p))
            own_default = "default" in sub and (not block or main != here)
            facts = [_allowed(sub).replace(" \\| ", ", ")]
            if own_default:
                facts.append(f"default `{canonical_json(sub['default'])}`")
            meaning = " ".join(str(sub.get("description", "")).split())
            if block and ref and main != here:
                meaning += f" (keys as `{main}`)"
            if here not in listed:
                listed.add(here)
                lines.append(f"- `{here}` ({'; '.join(f for f in facts if f)}): {meaning}")
            if main == here or not (block and ref):
                walk(sub, here, emit)
        extra = node.get("additionalProperties")
        if isinstance(extra, Mapping) and ("$ref" in extra or "properties" in extra):
            walk(extra, f"{path}.<name>", emit)
        for alternative in [*node.get("oneOf", []), *node.get("anyOf", [])]:
            walk(alternative, path, emit)

    walk(root, "", emit=False)
    walk(root, "", emit=True)
    return "\n".join(lines) + "\n"


def with_reference(page: str, kind: str = "config") -> str:
    """`page` with the text between the reference markers replaced by a fresh reference table."""
    if REFERENCE_BEGIN not in page or REFERENCE_END not in page:
        raise ConfigError(
            f"the page has no reference markers ({REFERENCE_BEGIN} ... {REFERENCE_END})"
        )
    head, rest = page.split(REFERENCE_BEGIN, 1)
    _, tail = rest.split(REFERENCE_END, 1)
    return f"{head}{REFERENCE_BEGIN}\n{reference_table(kind)}{REFERENCE_END}{tail}"
