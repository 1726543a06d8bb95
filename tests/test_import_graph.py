"""The library's import graph has no cycle (imports inside functions counted) and no module
imports another's private names: the spine is schema → profiles → config → stages."""

import ast
import importlib
import importlib.util
import re
import subprocess
import sys

from threedcal.provenance import PACKAGE_ROOT, imported_modules, module_file

REPO = PACKAGE_ROOT.parents[1]
SNAKEFILE = REPO / "Snakefile"


def _modules() -> dict[str, object]:
    out = {}
    for path in sorted(PACKAGE_ROOT.rglob("*.py")):
        parts = path.relative_to(PACKAGE_ROOT.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets = {m for m in imported_modules(path, package) if m in modules and m != name}
        # a package's own __init__ is not an edge back into it from its submodules' view
        graph[name] = {t for t in targets if not name.startswith(t + ".")}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (iterative Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_library_import_graph_has_no_cycle():
    assert _cycles(_graph()) == []


def test_spine_order():
    graph = _graph()
    assert "threedcal.study.config" not in graph["threedcal.schema"]
    assert "threedcal.study.config" not in graph["threedcal.profiles"]
    assert "threedcal.schema" in graph["threedcal.profiles"]


def test_no_module_imports_another_modules_private_names():
    offenders = []
    for name, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("threedcal"):
                if module_file(node.module) is None:
                    continue
                for alias in node.names:
                    private = alias.name.startswith("_") and not alias.name.endswith("__")
                    if private and node.module != name:
                        offenders.append(f"{name}: from {node.module} import {alias.name}")
    assert offenders == []


# The study layer and what sits on it; the domain packages below never import them.
UPPER = (
    "threedcal.study",
    "threedcal.report",
    "threedcal.page",
    "threedcal.cli",
)


def test_domain_packages_import_nothing_from_the_study_layer():
    upward = [
        f"{name} -> {target}"
        for name, targets in _graph().items()
        if not name.startswith(UPPER) and name != "threedcal.__main__"
        for target in targets
        if target.startswith(UPPER)
    ]
    assert upward == []


def test_the_snakefile_parse_loads_no_model_or_solver_libraries():
    """Every Snakemake run (and every cluster job) parses the Snakefile: what it imports from
    threedcal stays free of torch, scipy and trimesh (seconds, where the parse takes one)."""
    modules = re.findall(r"^from (threedcal[\w.]*) import", SNAKEFILE.read_text(), re.MULTILINE)
    assert len(modules) > 5
    code = f"import sys\nfor m in {modules!r}: __import__(m)\n" + (
        "print(sorted(k for k in ('torch', 'scipy', 'trimesh') if k in sys.modules))"
    )
    loaded = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert loaded.stdout.strip() == "[]"


def test_every_name_the_scripts_import_from_the_library_exists():
    """The rules' scripts, the benchmarks and the diagnostics run only in whole-study runs: a name
    moved in the library must not be found missing there first."""
    missing = []
    for folder in ("scripts", "benchmarks", "diagnostics"):
        for path in sorted((REPO / folder).glob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("threedcal"):
                    if importlib.util.find_spec(node.module) is None:
                        missing.append(f"{path.relative_to(REPO)}: {node.module}")
                        continue
                    module = importlib.import_module(node.module)
                    for alias in node.names:
                        name = f"{node.module}.{alias.name}"
                        if (
                            not hasattr(module, alias.name)
                            and importlib.util.find_spec(name) is None
                        ):
                            missing.append(f"{path.relative_to(REPO)}: {name}")
    assert missing == []
