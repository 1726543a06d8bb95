import shutil
from pathlib import Path

from threedcal.provenance import PACKAGE_ROOT, module_closure, script_digest

REPO = Path(__file__).resolve().parents[1]


def _names(script, root=PACKAGE_ROOT):
    return {str(p.relative_to(root)) for p in module_closure(script, root)}


def _copy_package(tmp_path):
    root = tmp_path / "threedcal"
    shutil.copytree(PACKAGE_ROOT, root, ignore=shutil.ignore_patterns("__pycache__"))
    return root


def test_closure_follows_imports_inside_functions_and_through_packages():
    collect = _names(REPO / "scripts/collect.py")
    assert {"reskin/figures.py", "study/paths.py", "study/session.py"} <= collect
    assert {"__init__.py", "collect/__init__.py"} <= collect  # parents run on import
    speed = _names(REPO / "scripts/inference_speed.py")
    assert any(n.startswith("dataset/") for n in speed)
    assert any(n.startswith("model/") for n in speed)
    # the collection never runs the model or the depth integrators: a model change keeps it cached
    assert not any(n.startswith(("model/", "depth/", "evaluate/")) for n in collect)


def test_lazy_package_attributes_count_only_for_who_names_them(tmp_path):
    plain = tmp_path / "plain.py"
    plain.write_text("import threedcal\n")
    named = tmp_path / "named.py"
    named.write_text("def f():\n    from threedcal import DepthEstimator\n")
    assert "model/inference.py" not in _names(plain)
    assert "model/inference.py" in _names(named)


def test_script_digest_changes_with_code_it_runs_only(tmp_path):
    root = _copy_package(tmp_path)
    script = tmp_path / "stage.py"
    script.write_text("from threedcal.depth.spectral import poisson_dst\n")
    before = script_digest(script, root)
    (root / "reskin" / "model.py").write_text((root / "reskin/model.py").read_text() + "\n# x\n")
    assert script_digest(script, root) == before
    # a module the script reaches only transitively
    closure = _names(script, root)
    deeper = next(n for n in sorted(closure) if n != "depth/spectral.py" and n.startswith("depth/"))
    (root / deeper).write_text((root / deeper).read_text() + "\n# x\n")
    after = script_digest(script, root)
    assert after != before
    (root / "profiles" / "sensors" / "digit.yaml").write_text(
        (root / "profiles/sensors/digit.yaml").read_text() + "\n# x\n"
    )
    assert script_digest(script, root) != after  # every stage reads profiles


def test_script_digest_of_a_missing_script_names_it(tmp_path):
    try:
        script_digest(tmp_path / "nope.py")
    except ValueError as exc:
        assert "nope.py" in str(exc)
    else:
        raise AssertionError("missing script accepted")


def test_every_rule_digests_the_script_it_runs():
    import re

    rules = 0
    for smk in sorted((REPO / "rules").glob("*.smk")):
        # rules defined in a loop are indented and may be anonymous (`rule:`)
        for block in re.split(r"(?m)^[ \t]*(?=rule\b|checkpoint\b)", smk.read_text())[1:]:
            head = block.split(":")[0].split()
            name = head[1] if len(head) > 1 else "(defined in a loop)"
            script = re.search(r'script:\s*"\.\./scripts/([\w.]+)"', block)
            if script is None:
                continue  # a rule without a script (e.g. `all`) runs no library code
            rules += 1
            digests = re.findall(r'code=code_digest\("([\w.]+)"\)', block)
            assert digests == [script.group(1)], f"{smk.name}: rule {name}"
    assert rules >= 15


def test_import_summaries_cached_across_processes_give_what_a_fresh_parse_gives(
    tmp_path, monkeypatch
):
    from threedcal import provenance

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    script = tmp_path / "stage.py"
    script.write_text(
        "import threedcal.cli\n\ndef f():\n    from threedcal import DepthEstimator\n"
    )
    source = script.read_bytes()
    parsed = provenance._summarise(provenance.ast.parse(source))
    key = provenance.hashlib.sha256(source).hexdigest()
    stored = tmp_path / f"cache/threedcal/provenance-{provenance.cache_version()}/{key}.json"
    fresh = provenance._summary.__wrapped__  # as a new process: no in-memory cache
    assert fresh(source, str(script)) == parsed and stored.is_file()
    assert provenance.json.loads(stored.read_text()) == parsed
    marked = {"imports": [[["threedcal.marker"]]], "lazy": {}}
    stored.write_text(provenance.json.dumps(marked))
    assert fresh(source, str(script)) == marked  # read from the file, not parsed again
    stored.write_text("{not json")  # a damaged entry is parsed anew
    assert fresh(source, str(script)) == parsed
    assert provenance.json.loads(stored.read_text()) == parsed
    # no home to cache in: parsed, and nothing written under the working folder
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setattr(provenance.os.path, "expanduser", lambda path: path)
    monkeypatch.chdir(tmp_path)
    assert fresh(source, str(script)) == parsed
    assert not (tmp_path / "~").exists()
