import subprocess
import sys

import pytest

import threedcal
from threedcal.cli import Command, build_parser, main


def test_version_flag_prints_package_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"threedcal {threedcal.__version__}"


def test_console_script_help_lists_command_groups():
    exe = [sys.executable, "-m", "threedcal", "--help"]
    out = subprocess.run(exe, capture_output=True, text=True, check=True).stdout
    assert "config" in out and "profiles" in out


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
