import re

from threedcal.cli import main
from threedcal.sim.soak import compare_logs, run_soak


def test_soak_of_1000_faults_loses_and_repeats_nothing():
    result = run_soak(1000, seed=0, progress=False)
    assert result.faults >= 1000
    assert (result.lost, result.duplicated, result.reordered) == (0, 0, False)
    assert result.executed == result.sent > 1000
    assert len(result.fault_counts) == 7 and min(result.fault_counts.values()) > 50


def test_soak_is_deterministic_per_seed():
    a = run_soak(100, seed=5, speedup=float("inf"), progress=False)
    b = run_soak(100, seed=5, speedup=float("inf"), progress=False)
    c = run_soak(100, seed=6, speedup=float("inf"), progress=False)
    assert a == b and a != c


def test_compare_logs_finds_lost_duplicated_and_reordered():
    sent = [(1, "A"), (2, "B"), (3, "C")]
    assert compare_logs(sent, sent) == (0, 0, False)
    assert compare_logs(sent, [(1, "A"), (3, "C")]) == (1, 0, False)
    assert compare_logs(sent, [(1, "A"), (2, "B"), (2, "B"), (3, "C")]) == (0, 1, False)
    assert compare_logs(sent, [(2, "B"), (1, "A"), (3, "C")]) == (0, 0, True)
    assert (
        compare_logs(sent, [(1, "A"), (2, "X"), (3, "C")])[0] == 1
    )  # wrong content counts as lost


def test_cli_soak_prints_one_final_line(capsys):
    assert main(["sim", "soak", "--faults", "30", "--seed", "2", "--speedup", "inf"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    assert re.fullmatch(r"faults=\d+ sent=\d+ executed=\d+ lost=0 duplicated=0", out[0])


def test_cli_printer_check_on_simulated_port(capsys):
    assert main(["printer", "check", "--port", "simmarlin://clicheck?speedup=inf", "--home"]) == 0
    out = capsys.readouterr().out
    assert "firmware: Marlin" in out and "position: X=0.000 Y=0.000 Z=0.000 mm" in out


def test_cli_printer_check_bad_port_is_one_line_error(capsys):
    assert main(["printer", "check", "--port", "/dev/does-not-exist-threedcal"]) == 1
    assert "cannot open printer port" in capsys.readouterr().err


def test_cli_printer_ports_runs(capsys):
    assert main(["printer", "ports"]) == 0
