"""Digests of the library source a stage depends on, passed to Snakemake as `params`.

Snakemake reruns a job when its params change, so a digest of the code (and profiles) that a stage
imports makes "the library changed" a rerun reason — and only for the stages that use that code.
The modules are found from the rule's script itself (its threedcal imports, followed transitively,
imports inside functions included), so the list cannot drift from the code the way a hand-kept
one does.
"""

from __future__ import annotations

import ast
import contextlib
import hashlib
import json
import os
import tempfile
from collections.abc import Iterator
from functools import cache
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parent
PACKAGE = "threedcal"
# Data every stage reads through the profile loader: a change to a profile or schema reruns everything.
DATA_DIRS = ("profiles", "schemas")


def module_file(module: str, root: Path = PACKAGE_ROOT) -> Path | None:
    """`threedcal.sim.optics` → its file under `root` (a package → its __init__.py); None if absent."""
    parts = module.split(".")
    if parts[0] != PACKAGE:
        return None
    base = root.joinpath(*parts[1:])
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


# What a file's imports are, by the sha256 of its content, kept across processes: every `snakemake`
# call parses the Snakefile, which digests ~30 scripts' closures (~140 modules); parsing them costs
# ~0.65 s of CPU a call (AMD EPYC), reading the cached summaries ~0.02 s. A summary is exactly what
# the syntax tree gave (see `_summarise`); a missing, unreadable or unwritable cache is parsed anew.


@cache
def cache_version() -> str:
    """The digest of this file: a summary is valid for the code that wrote it, so a change here
    starts a new cache folder rather than reading summaries of another shape."""
    return hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]


def _cache_dir() -> Path | None:
    """None where there is no home to cache in (a relative path would land in the working folder)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    if not os.path.isabs(base):
        return None
    return Path(base) / "threedcal" / f"provenance-{cache_version()}"


@cache
def _summary(source: bytes, filename: str) -> dict:
    """The file's imports (see `_summarise`), from the disk cache when it holds them."""
    folder = _cache_dir()
    key = hashlib.sha256(source).hexdigest()
    path = folder / f"{key}.json" if folder is not None else None
    if path is not None:
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            pass
    summary = _summarise(ast.parse(source, filename=filename))
    if path is not None:
        _store(path, summary)
    return summary


def _store(path: Path, summary: dict) -> None:
    """Written whole or not at all (a reader never sees half a file); a failure only costs a parse."""
    temporary = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(handle, "w") as out:
            json.dump(summary, out)
        os.replace(temporary, path)
    except OSError:
        if temporary is not None:
            with contextlib.suppress(OSError):
                os.unlink(temporary)


def _summarise(tree: ast.Module) -> dict:
    """What `imported_modules` and `_lazy_targets` read of a syntax tree: every import statement
    outside the module's lazy attributes ([names] for `import`, [level, module, names] for
    `from ... import`), and each lazy attribute's imported modules (None: a relative `from .`)."""
    lazy = _lazy_attributes(tree)
    skipped = {node for nodes in lazy.values() for node in nodes}
    imports = []
    for node in _statements(tree.body):
        if node in skipped:
            continue
        if isinstance(node, ast.Import):
            imports.append([[alias.name for alias in node.names]])
        elif isinstance(node, ast.ImportFrom):
            imports.append([node.level, node.module, [alias.name for alias in node.names]])
    # sorted: the same summary whatever order the set holds the nodes in
    lazy_modules = {name: sorted({n.module or "" for n in nodes}) for name, nodes in lazy.items()}
    return {"imports": imports, "lazy": lazy_modules}


def _lazy_attributes(tree: ast.Module) -> dict[str, set[ast.AST]]:
    """Imports inside a module-level `__getattr__` (PEP 562), by the attribute that triggers them."""
    lazy: dict[str, set[ast.AST]] = {}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name == "__getattr__":
            for sub in ast.walk(node):
                if isinstance(sub, ast.ImportFrom):
                    for alias in sub.names:
                        lazy.setdefault(alias.asname or alias.name, set()).add(sub)
    return lazy


def imported_modules(path: Path, package: str | None, root: Path = PACKAGE_ROOT) -> set[str]:
    """Every threedcal module a file imports anywhere in it (top level, functions, branches).

    A package's lazy attributes (imports inside its `__getattr__`) count for the importer that
    names them (`from threedcal import DepthEstimator`), not for every importer of the package.
    """
    found = set()
    for entry in _summary(path.read_bytes(), str(path))["imports"]:
        if len(entry) == 1:  # import a, b.c
            found.update(entry[0])
            continue
        level, module, names = entry
        if level:  # relative: resolved against the importing module's package
            if package is None:
                continue
            base = package.split(".")[: len(package.split(".")) - level + 1]
            module = ".".join(base + ([module] if module else []))
        else:
            module = module or ""
        found.add(module)
        # `from threedcal.sim import optics` imports the submodule too
        found.update(f"{module}.{name}" for name in names)
        found.update(_lazy_targets(module, names, root))
    return {m for m in found if m == PACKAGE or m.startswith(PACKAGE + ".")}


def _statements(nodes: list) -> Iterator[ast.AST]:
    """Every statement, nested ones included (function, class, if/try/with/match bodies): an
    import is a statement, so expressions (most of a tree) need not be walked."""
    for node in nodes:
        yield node
        for field in ("body", "orelse", "finalbody", "handlers", "cases"):
            children = getattr(node, field, None)
            if isinstance(children, list):
                yield from _statements(children)


def _lazy_targets(module: str, names: list[str], root: Path) -> set[str]:
    """The modules a package's `__getattr__` imports for the given attribute names."""
    path = module_file(module, root)
    if path is None or path.name != "__init__.py":
        return set()
    lazy = _summary(path.read_bytes(), str(path))["lazy"]
    return {module for name in names for module in lazy.get(name, ()) if module}


def _with_parents(module: str) -> list[str]:
    """Importing a.b.c runs a/__init__, a/b/__init__ and a/b/c."""
    parts = module.split(".")
    return [".".join(parts[: i + 1]) for i in range(len(parts))]


def module_closure(script: str | Path, root: Path = PACKAGE_ROOT) -> list[Path]:
    """The library files a script runs when it executes: its threedcal imports, transitively."""
    return list(_closure(Path(script).resolve(), root.resolve()))


@cache
def _closure(script: Path, root: Path) -> tuple[Path, ...]:
    seen: dict[str, Path] = {}
    todo = sorted(imported_modules(script, None, root))
    while todo:
        module = todo.pop()
        for name in _with_parents(module):
            if name in seen:
                continue
            path, imports = _module_imports(name, root)
            if path is None:
                continue  # an attribute (`from threedcal.study.config import load_yaml`), not a module
            seen[name] = path
            todo.extend(imports - set(seen))
    return tuple(sorted(set(seen.values())))


@cache
def _module_imports(name: str, root: Path) -> tuple[Path | None, frozenset[str]]:
    """A module's file (None: not a module) and the threedcal modules it imports, looked up once
    per process: a Snakefile parse walks ~30 scripts' closures, which share most modules, and
    finding and reading each module again for every script would cost ~0.1 s of CPU per parse."""
    path = module_file(name, root)
    if path is None:
        return None, frozenset()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    return path, frozenset(imported_modules(path, package, root))


def _data_files(root: Path) -> list[Path]:
    return sorted(
        p for d in DATA_DIRS for p in (root / d).rglob("*") if p.suffix == ".yaml" and p.is_file()
    )


def script_digest(script: str | Path, root: Path = PACKAGE_ROOT) -> str:
    """sha256 (16 hex) of the script, every library module it runs, and the profiles and schemas."""
    script = Path(script)
    if not script.is_file():
        raise ValueError(f"no script {script} to digest")
    digest = hashlib.sha256(script.read_bytes())
    root = root.resolve()
    for path in [*module_closure(script, root), *_data_files(root)]:
        digest.update(b"\0" + str(path.relative_to(root)).encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]
