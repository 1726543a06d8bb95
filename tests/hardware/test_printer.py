import math
import time
import uuid

import pytest

from threedcal.errors import ConfigError
from threedcal.hardware.printer import (
    CommandRejected,
    MarlinHost,
    OutOfTravel,
    PrinterDisconnected,
    PrinterError,
    PrinterHalted,
    PrinterReset,
    PrinterTimeout,
    printer_profile,
)
from threedcal.sim.marlin import FIRMWARES, RECOVERABLE_FAULTS


@pytest.fixture
def sim_url():
    """A fresh simmarlin URL factory; the firmwares are forgotten afterwards."""
    names = []

    def make(query="speedup=inf"):
        name = f"t{uuid.uuid4().hex[:8]}"
        names.append(name)
        return f"simmarlin://{name}?{query}", name

    yield make
    for name in names:
        FIRMWARES.withdraw(name)


def script(host):
    host.home()
    host.hold_motors()
    for i in range(30):
        host.move_to(10 + 5 * i, 200 - 4 * i, 2 + (i % 3), feed_mm_s=(20, 100, 5)[i % 3])
        if i % 10 == 9:
            host.wait_until_idle()
        # an M114 after every move (ok_report acts on M114 lines only)
        assert tuple(host.position()) == host.commanded
    host.wait_until_idle()
    return host.position()


def numbered(firmware):
    return [(n, c) for n, c in firmware.executed if n is not None and n >= 1]


def test_handshake_reads_firmware_info(sim_url):
    url, name = sim_url()
    with MarlinHost(url) as host:
        assert host.firmware_info["FIRMWARE_NAME"].startswith("Marlin")
    fw = FIRMWARES.get(name)
    assert fw.executed_commands()[:3] == ["M110 N0", "M115", "G90"]
    assert fw.boots == 2  # power-on, then the DTR reset when the port opened


def test_moves_are_acknowledged_when_queued_and_done_after_m400(sim_url):
    url, name = sim_url()
    with MarlinHost(url) as host:
        fw = FIRMWARES.get(name)
        host.home()
        host.move_to(100, 50, 10, 100)
        assert fw.clock.now() < fw.busy_until()  # `ok` came while the head was still moving
        early = host.position()
        assert (early.x, early.y, early.z) == (100, 50, 10)  # commanded
        assert early.steps_mm != (100, 50, 10)  # the steppers are not there yet
        host.wait_until_idle()
        assert fw.clock.now() == pytest.approx(fw.busy_until())
        pos = host.position()
        assert tuple(pos) == (100, 50, 10) and pos.steps_mm == (100, 50, 10)
        assert fw.position() == (100, 50, 10)


def test_motion_time_matches_model(sim_url):
    url, name = sim_url()
    with MarlinHost(url) as host:
        fw = FIRMWARES.get(name)
        host.home()
        before = fw.motion_time_s
        host.move_to(100, 0, 0, 100)
        host.move_to(100, 0, 10, 100)
        host.wait_until_idle()
        expected = host.model.move_time((0, 0, 0), (100, 0, 0), 100) + host.model.move_time(
            (100, 0, 0), (100, 0, 10), 100
        )
        assert fw.motion_time_s - before == pytest.approx(expected)
        assert expected == pytest.approx(1.2 + 2.05)


@pytest.mark.parametrize(
    "target",
    [(236, 0, 0), (0, -0.001, 0), (0, 0, 250.5), (math.nan, 0, 0), (0, math.inf, 0)],
)
def test_out_of_travel_moves_are_refused_before_sending(sim_url, target):
    url, name = sim_url()
    with MarlinHost(url) as host:
        host.home()
        sent = len(FIRMWARES.get(name).executed)
        with pytest.raises(OutOfTravel, match=r"outside the travel .*nothing was sent"):
            host.move_to(*target)
        assert len(FIRMWARES.get(name).executed) == sent
        host.move_to(235, 235, 250, 500)  # the limits themselves are fine


def test_move_before_home_and_bad_feed_are_refused(sim_url):
    url, _ = sim_url()
    with MarlinHost(url) as host:
        with pytest.raises(PrinterError, match="home"):
            host.move_to(10, 10, 10)
        host.home()
        for feed in (0, -5, math.nan):
            with pytest.raises(ConfigError, match="feed_mm_s"):
                host.move_to(10, 10, 10, feed)


@pytest.mark.parametrize("kind", RECOVERABLE_FAULTS)
def test_each_fault_kind_is_recovered_exactly(sim_url, kind):
    url, clean = sim_url()
    with MarlinHost(url) as host:
        expected_pos = script(host)
    url, faulty = sim_url(f"speedup=inf&faults={kind}&rate=0.3&seed=3")
    with MarlinHost(url) as host:
        pos = script(host)
    assert FIRMWARES.get(faulty).faults_injected[kind] >= 5
    assert numbered(FIRMWARES.get(faulty)) == numbered(FIRMWARES.get(clean))
    assert pos == expected_pos


def test_reset_in_the_middle_of_a_run_is_an_error(sim_url):
    url, name = sim_url()
    with MarlinHost(url) as host:
        host.home()
        host.move_to(50, 50, 5)
        FIRMWARES.get(name).schedule_fault("reset")
        with pytest.raises(PrinterReset, match="reset itself.*home again"):
            host.move_to(60, 60, 5)
        assert not host.homed


def test_halt_and_disconnect_are_errors(sim_url):
    url, name = sim_url()
    with MarlinHost(url) as host:
        FIRMWARES.get(name).schedule_fault("halt")
        with pytest.raises(PrinterHalted, match="kill"):
            host.home()
    url, name = sim_url()
    with MarlinHost(url) as host:
        FIRMWARES.get(name).schedule_fault("disconnect")
        with pytest.raises(PrinterDisconnected, match="disconnected"):
            host.home()


def test_silence_becomes_a_timeout_after_retries(sim_url):
    url, name = sim_url()
    with MarlinHost(url, retries=2) as host:
        fw = FIRMWARES.get(name)
        fw.kinds, fw.rate = ("drop_line",), 1.0
        with pytest.raises(
            PrinterTimeout, match=r"no reply to line N\d+ 'M114' after 2 retransmission"
        ):
            host.position()
        assert host.stats.timeouts == 2


def test_long_commands_outlast_the_reply_timeout(sim_url):
    url, name = sim_url()
    with MarlinHost(url, reply_timeout_s=1.0) as host:
        host.home()  # ~4 s of homing: acknowledged only at the end, busy keepalives meanwhile
        host.move_to(0, 0, 200, 5)  # 40 s of Z travel
        host.wait_until_idle()
        assert FIRMWARES.get(name).position() == (0, 0, 200)
        assert host.stats.timeouts == 0 and host.stats.busy >= 19


def test_unknown_command_is_rejected(sim_url):
    url, _ = sim_url()
    with MarlinHost(url) as host:
        with pytest.raises(CommandRejected, match="Unknown command"):
            host.send("G999")
        host.home()  # the link is still in step


def test_hold_motors_and_emergency_stop(sim_url):
    url, name = sim_url()
    host = MarlinHost(url)
    host.home()
    host.hold_motors()
    fw = FIRMWARES.get(name)
    assert fw.motors_on and fw.idle_timeout_s == 0
    host.move_to(200, 200, 0, 100)
    host.emergency_stop()
    assert fw.halted and fw.executed[-1] == (None, "M112")
    assert fw.position() != (200, 200, 0)  # stopped where it was, not at the target
    with pytest.raises(PrinterError, match="closed"):
        host.send("M114")


def test_speedup_paces_simulated_time_in_real_time(sim_url):
    url, name = sim_url("speedup=100")
    start = time.monotonic()
    with MarlinHost(url) as host:
        host.home()
        host.move_to(100, 0, 0, 100)
        host.wait_until_idle()
    simulated = FIRMWARES.get(name).clock.now()
    assert time.monotonic() - start >= 0.9 * simulated / 100


def test_url_options_are_checked(sim_url):
    with pytest.raises(PrinterDisconnected, match="unknown option"):
        MarlinHost("simmarlin://x?sped=3")
    with pytest.raises(PrinterDisconnected, match="unknown fault"):
        MarlinHost("simmarlin://y?faults=gremlins")


def test_reopening_a_url_reaches_the_same_firmware(sim_url):
    url, name = sim_url()
    with MarlinHost(url) as host:
        host.home()
    fw = FIRMWARES.get(name)
    with MarlinHost(url) as host:
        assert not host.homed
    assert FIRMWARES.get(name) is fw and fw.boots == 3


def test_printer_profile_schema_is_closed(tmp_path):
    profile = printer_profile("ender3")
    assert profile["max_feedrate_mm_s"] == {"x": 500, "y": 500, "z": 5}
    assert profile["timeouts_s"]["reply"] == 5
    bad = dict(profile, travel_mm={"x": 235, "y": 235, "z": 250}, nozzle=0.4)
    with pytest.raises(ConfigError, match="unknown key 'nozzle'"):
        printer_profile(bad)
    missing = {k: v for k, v in profile.items() if k != "steps_per_mm"}
    with pytest.raises(ConfigError, match="steps_per_mm"):
        printer_profile(missing)
