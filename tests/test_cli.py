import ast
import subprocess
import sys
from pathlib import Path

import pytest

import threedcal
from threedcal.cli import Command, build_parser, discover_commands, main
from threedcal.errors import ConfigError


def test_version_flag_prints_package_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"threedcal {threedcal.__version__}"


def test_console_script_help_lists_command_groups():
    exe = [sys.executable, "-m", "threedcal", "--help"]
    out = subprocess.run(exe, capture_output=True, text=True, check=True).stdout
    assert "config" in out and "profiles" in out


def test_every_command_names_a_handler_that_exists():
    """A command's "module:function" names a function of threedcal.cli.handlers (read from the
    source: importing every handler would load torch, pandas and aiohttp)."""
    handlers = Path(threedcal.__file__).parent / "cli" / "handlers"
    named = [c.run for c in discover_commands() if isinstance(c.run, str)]
    assert len(named) >= 15
    for run in named:
        module, _, name = run.partition(":")
        tree = ast.parse((handlers / f"{module}.py").read_text())
        assert name in {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}, run


def test_help_loads_no_handler_and_predict_no_workflow_library():
    """`--help` builds the parser from the light definition modules alone; the handlers of
    predict, live and export, and of the built-in listings, load none of the workflow extra's
    libraries (a plain `pip install threedcal` has none; tests/test_install.py runs it there)."""
    code = (
        "import sys\n"
        "from threedcal.cli import build_parser\n"
        "build_parser()\n"
        "heavy = ('threedcal.cli.handlers', 'torch', 'cv2', 'numpy', 'yaml', 'pandas')\n"
        "print(sorted(m for m in sys.modules if m.startswith(heavy)))\n"
        "import threedcal.cli.handlers.builtin, threedcal.cli.handlers.model\n"
        "workflow = ('zarr', 'snakemake', 'xarray', 'pandas', 'matplotlib', 'statsmodels', "
        "'serial', 'aiohttp', 'onnx')\n"
        "print(sorted(m for m in workflow if m in sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.splitlines() == ["[]", "[]"]


def test_nested_commands_are_built_from_paths_and_run():
    seen = []
    commands = [
        Command(
            ("sim", "soak"),
            "soak",
            lambda a: seen.append(("soak", a.faults)) or 0,
            lambda p: p.add_argument("--faults", type=int, default=1),
        ),
        Command(("sim", "realism"), "realism", lambda a: 3),
    ]
    parser = build_parser(commands)
    args = parser.parse_args(["sim", "soak", "--faults", "7"])
    assert args._run(args) == 0 and seen == [("soak", 7)]
    args = parser.parse_args(["sim", "realism"])
    assert args._run(args) == 3


def test_group_without_subcommand_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["config"])
    assert exc.value.code == 2
    assert "required" in capsys.readouterr().err


def test_config_check_reports_bad_key_with_exit_1(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("scenes:\n  s:\n    sensor: digit\n    printer: ender3\n    sensr: 1\n")
    assert main(["config", "check", str(bad)]) == 1
    err = capsys.readouterr().err
    assert str(bad) in err and "scenes.s: unknown key 'sensr'" in err


def test_config_check_lists_scene_targets(repo, capsys):
    assert main(["config", "check", str(repo / "config.yaml")]) == 0
    out = capsys.readouterr().out
    assert "results/digit_sim/scene.json" in out and "results/mini_sim/scene.json" in out


def test_profiles_list_shows_builtins(capsys):
    assert main(["profiles", "list"]) == 0
    out = capsys.readouterr().out
    assert "digit" in out and "gelsight_mini" in out and "ender3" in out


@pytest.mark.parametrize("count", ["0", "-3"])
def test_reskin_read_count_must_be_positive(capsys, count):
    """Repro: `reskin read --count 0` gave a traceback."""
    assert main(["reskin", "read", "--port", "sim", "--count", count]) == 1
    err = capsys.readouterr().err
    assert f"--count must be a whole number >= 1, got {count}" in err and "Traceback" not in err


def test_objects_export_into_a_file_is_refused_before_writing(tmp_path, capsys):
    """Repro: `objects export --out notes.txt` (or a folder under a file) raised FileExistsError /
    NotADirectoryError from mkdir."""
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    for out in (notes, notes / "stl"):
        assert main(["objects", "export", "--out", str(out), "--objects", "pill"]) == 1
        err = capsys.readouterr().err
        assert err == f"threedcal: error: --out {out}: {notes} is a file, not a folder\n"
    assert notes.read_text() == "mine"


def test_predict_into_a_folder_that_is_a_file_is_refused(tmp_path, capsys):
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    out = notes / "d.npy"
    args = ["predict", "--checkpoint", "m.pt", "--image", "x.png", "--out", str(out)]
    assert main(args) == 1
    assert (
        capsys.readouterr().err
        == f"threedcal: error: --out {out}: {notes} is a file, not a folder\n"
    )


def test_a_path_the_system_refuses_is_one_line_naming_it(monkeypatch, capsys):
    """Any OSError a command meets (no space left, a file where a folder goes) is one line that
    names the path, not a traceback."""
    import threedcal.cli

    def full_disk(args):
        raise OSError(28, "No space left on device", "results/d.npy")

    commands = [Command(("write",), "write something", full_disk)]
    monkeypatch.setattr(threedcal.cli, "discover_commands", lambda: commands)
    assert main(["write"]) == 1
    assert capsys.readouterr().err == "threedcal: error: results/d.npy: No space left on device\n"


def test_cli_reference_page_is_the_parser_and_within_its_word_budget():
    from threedcal.cli.reference import with_cli_reference

    page = Path(__file__).resolve().parents[1] / "docs/reference/cli.md"
    text = page.read_text()
    assert text == with_cli_reference(text), (
        "docs/reference/cli.md is out of date with the command-line parser: run "
        "`.venv/bin/threedcal report cli-reference --write docs/reference/cli.md`"
    )
    assert len(text.split()) <= 1100, "docs/reference/cli.md: over its 1,100 words; shorten help"


def test_cli_reference_lists_every_command_its_arguments_and_defaults():
    from threedcal.cli.reference import cli_reference

    text = cli_reference()
    for command in ("collect", "predict", "live", "sim soak", "report cli-reference"):
        assert f"\n## {command}\n" in f"\n{text}"
    assert "`threedcal predict --checkpoint CHECKPOINT --image IMAGE --out OUT [options]`" in text
    assert "- `--contact-mm` (default `0.05`)" in text and "[checkpoint options](#" in text
    assert text.count("## Checkpoint options") == 1 and "[-h]" not in text


def test_cli_reference_needs_its_markers(capsys):
    from threedcal.cli.reference import with_cli_reference

    with pytest.raises(ConfigError, match="markers"):
        with_cli_reference("# a page without them\n")
    assert main(["report", "cli-reference"]) == 0
    assert "## collect" in capsys.readouterr().out


def test_help_shows_each_literal_default_once(capsys):
    with pytest.raises(SystemExit):
        main(["sim", "soak", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    # --seed and --rate from their argparse defaults, --kinds and --speedup from their help
    assert "(default: 0.2)" in out and out.count("default") == 4
