import re

import pytest

from threedcal.cli import main
from threedcal.hardware.printer import MarlinHost
from threedcal.sim.marlin import RECOVERABLE_FAULTS
from threedcal.sim.soak import acknowledged_early, compare_logs, run_soak, soak_table


@pytest.fixture
def firmware(sim_firmware):
    """A fault-free fake firmware (faults are scheduled line by line)."""
    return sim_firmware


def numbered(board):
    return [(n, c) for n, c in board.executed if n is not None and n >= 1]


def test_every_fault_class_soaks_without_loss_repeat_or_early_ack():
    """The soak table, small: each class on its own, then mixed (the docs hold the 1,000 run)."""
    results = soak_table(60, seed=1, rate=0.3, speedup=float("inf"), progress=False)
    assert [r.kind for r in results] == [*RECOVERABLE_FAULTS, "mixed"]
    for r in results:
        assert r.faults >= 60, r.row()
        assert (r.lost, r.duplicated, r.early, r.reordered, r.bad_reports) == (0, 0, 0, False, 0), (
            r.row()
        )
        assert r.executed == r.sent
        if r.kind != "mixed":  # one class at a time: no line without a fault is ever re-sent
            assert r.out_of_step == 0, r.row()


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


def test_acknowledged_early_compares_ack_and_finish_times():
    executed = [(1, "G1"), (2, "M400"), (None, "M112")]
    done = [1.0, 5.0, 6.0]
    assert acknowledged_early({1: 1.0, 2: 5.0}, executed, done) == 0
    assert acknowledged_early({1: 1.0, 2: 4.9}, executed, done) == 1


def test_lost_ok_after_a_resend_keeps_the_output(firmware):
    """Repro: the ok after `Resend:` lost → the host re-sent the line and threw its output away:
    M114 then said "no position line"."""
    url, board = firmware
    with MarlinHost(url) as host:
        host.home()
        host.move_to(30, 40, 5)
        board.schedule_fault("drop_resend_ok")  # the M114 line: Error + Resend, its ok lost
        position = host.position()
        assert tuple(position) == (30, 40, 5)
        host.move_to(31, 41, 6)
        assert tuple(host.position()) == (31, 41, 6)
    assert board.faults_injected["drop_resend_ok"] == 1
    assert numbered(board) == [(n, c) for n, c in host.acked if n >= 1]


def test_lost_resend_line_is_no_acknowledgement(firmware):
    """Repro: `Resend:` lost (only Error and ok arrive) → the host took the ok for the line, and
    wait_until_idle() returned while the head still moved."""
    url, board = firmware
    with MarlinHost(url) as host:
        host.home()
        host.move_to(200, 200, 20, feed_mm_s=100)  # seconds of motion still queued
        board.schedule_fault("drop_resend")  # the M400 line: Error + ok, no Resend
        host.wait_until_idle()
        assert board.position(host._now()) == (200, 200, 20)  # at rest when it returned
        assert host.ack_times[host._next - 1] >= board.done_at[-1]
    assert board.faults_injected["drop_resend"] == 1
    assert numbered(board)[-1] == (host._next - 1, "M400")


def test_after_a_late_reply_the_host_is_back_in_step_at_once(firmware):
    """Repro: a reply later than the timeout (no busy:) left the host one line out of step for
    the rest of the session: every later line was sent twice."""
    url, board = firmware
    with MarlinHost(url) as host:
        host.home()
        board.schedule_fault("late")  # the next line's reply comes after the reply timeout
        host.move_to(10, 10, 10)
        late = host._next - 1
        for i in range(8):
            host.move_to(20 + i, 20, 10)
            assert tuple(host.position()) == (20 + i, 20, 10)
        assert host.transmissions[late] == 2  # timed out once, sent again: refused as a repeat
        assert all(host.transmissions[n] == 1 for n in range(late + 1, host._next))
        assert host.stats.timeouts == 1
    assert numbered(board) == [(n, c) for n, c in host.acked if n >= 1]


def test_position_report_on_the_ok_line_is_read(firmware):
    """Repro: some firmwares answer M114 on the ok line (`ok X:.. Y:.. Z:..`): no position found."""
    url, board = firmware
    with MarlinHost(url) as host:
        host.home()
        host.move_to(12.5, 7.25, 3)
        board.schedule_fault("ok_report")
        assert tuple(host.position()) == (12.5, 7.25, 3)
    assert board.faults_injected["ok_report"] == 1


def test_cli_soak_prints_a_table_per_class(capsys):
    assert (
        main(
            [
                "sim",
                "soak",
                "--faults",
                "15",
                "--seed",
                "2",
                "--speedup",
                "inf",
                "--kinds",
                "late,drop_resend",
            ]
        )
        == 0
    )
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].split() == [
        "class",
        "faults",
        "lines",
        "lost",
        "duplicated",
        "acked_early",
        "out_of_step",
        "bad_reports",
    ]
    assert [line.split()[0] for line in lines[1:]] == ["late", "drop_resend", "mixed"]
    for line in lines[1:]:
        assert re.fullmatch(r"\S+\s+\d+\s+\d+\s+0\s+0\s+0\s+\d+\s+0", line)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--rate", "0"], "--rate must be a probability in (0, 1]"),
        (["--rate", "nan"], "--rate must be a probability"),
        (["--speedup", "0"], "--speedup must be > 0"),
        (["--speedup", "-1"], "--speedup must be > 0"),
        (
            ["--speedup", "nan"],
            "--speedup must be > 0 simulated seconds per real second (or inf), got nan",
        ),
        (["--faults", "0"], "--faults must be a whole number >= 1"),
        (["--kinds", "reset"], "recoverable faults only"),
        (["--kinds", "bogus"], "unknown fault kind(s) 'bogus'"),
    ],
)
def test_cli_soak_arguments_are_checked(capsys, args, message):
    """Repro: `sim soak --rate 0` never ended; --speedup 0|-1|nan gave tracebacks."""
    assert main(["sim", "soak", "--faults", "5", *args]) == 1
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_cli_printer_check_on_simulated_port(capsys):
    assert main(["printer", "check", "--port", "simmarlin://clicheck?speedup=inf", "--home"]) == 0
    out = capsys.readouterr().out
    assert "firmware: Marlin" in out and "position: X=0.000 Y=0.000 Z=0.000 mm" in out


def test_cli_printer_check_bad_port_is_one_line_error(capsys):
    assert main(["printer", "check", "--port", "/dev/does-not-exist-threedcal"]) == 1
    assert "cannot open printer port" in capsys.readouterr().err


def test_cli_printer_ports_runs(capsys):
    assert main(["printer", "ports"]) == 0
