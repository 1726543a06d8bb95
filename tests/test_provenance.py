import shutil

from threedcal.provenance import PACKAGE_ROOT, source_digest


def test_digest_changes_only_with_the_code_it_covers(tmp_path):
    root = tmp_path / "threedcal"
    shutil.copytree(PACKAGE_ROOT, root, ignore=shutil.ignore_patterns("__pycache__"))
    before_scenes = source_digest("scenes", root=root)
    before_cli = source_digest("cli", root=root)
    with (root / "scenes.py").open("a") as f:
        f.write("\n# a change\n")
    assert source_digest("scenes", root=root) != before_scenes
    assert source_digest("cli", root=root) == before_cli


def test_core_change_changes_every_digest(tmp_path):
    root = tmp_path / "threedcal"
    shutil.copytree(PACKAGE_ROOT, root, ignore=shutil.ignore_patterns("__pycache__"))
    before = source_digest("cli", root=root)
    with (root / "config.py").open("a") as f:
        f.write("\n# a change\n")
    assert source_digest("cli", root=root) != before


def test_digest_is_stable_and_rejects_unknown_modules():
    assert source_digest("scenes") == source_digest("scenes")
    try:
        source_digest("no_such_module")
    except ValueError as exc:
        assert "no_such_module" in str(exc)
    else:
        raise AssertionError("unknown module accepted")
