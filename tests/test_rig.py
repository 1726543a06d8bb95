"""The rig: the bench and a real rig opened alike; a person is asked only through `ask`."""

import pytest

from threedcal.errors import ConfigError
from threedcal.hardware.clock import WallClock
from threedcal.profiles import load_profile
from threedcal.rig import BenchClock, Rig, RigError, RigSettings, check_devices, open_rig
from threedcal.study.config import validate_config
from threedcal.study.scene import rig_settings


def test_a_real_rig_asks_through_its_callback_and_refuses_without_one():
    asked = []
    rig = Rig(printer=None, sensor=None, clock=WallClock(), hardware_clock=lambda: 0.0)
    with pytest.raises(RigError, match=r"needs a person at the rig \(Mount the pill\).*ask="):
        rig.prompt("Mount the pill")
    rig.ask = asked.append
    rig.prompt("Attach the probe to the print head")
    assert asked == ["Attach the probe to the print head"]


def test_the_bench_opens_as_a_rig_and_needs_nobody():
    scene = validate_config({"scenes": {"s": {"sensor": "digit", "printer": "ender3"}}})
    scene = scene["scenes"]["s"]
    sensor, printer = load_profile("sensor", "digit"), load_profile("printer", "ender3")
    with open_rig(rig_settings(scene), sensor, printer) as rig:
        assert rig.simulated and isinstance(rig.clock, BenchClock)
        rig.prompt("Mount the pill")  # the bench mounts its own objects: nothing asked
        rig.printer.home()
        started = rig.hardware_clock()
        rig.clock.sleep(2.5)  # a wait advances the bench's own clock, not the wall's
        assert rig.hardware_clock() - started == pytest.approx(2.5)
        frames, stamps = rig.sensor.capture(2)
        assert frames.shape == (2, *rig.bench.gel.background.shape[:2], 3)
        assert stamps[1] > stamps[0]


def test_a_real_printer_needs_a_real_sensor():
    def real(**devices):
        return RigSettings("digit", 1.0, 0, port="/dev/ttyUSB0", **devices)

    digit, reskin = load_profile("sensor", "digit"), load_profile("sensor", "reskin")
    with pytest.raises(ConfigError, match=r"scenes.x.camera: port '/dev/ttyUSB0' is a real"):
        check_devices(real(camera="sim"), digit, "scenes.x")
    with pytest.raises(ConfigError, match=r"scenes.x.reader: .*ReSkin board's serial device"):
        check_devices(real(), reskin, "scenes.x")
    check_devices(real(camera="0"), digit, "scenes.x")  # accepted
