"""pyserial URL handler ``simmarlin://NAME?options``: a serial port wired to a SimMarlin board.

pyserial finds it as ``<package>.protocol_simmarlin`` for every package in
``serial.protocol_handler_packages``; ``threedcal.hardware.printer`` adds ``threedcal.sim``.
Read timeouts on this port are in *simulated* seconds: waiting advances the firmware's virtual
clock (sleeping only ``dt / speedup`` real seconds), and the port offers that clock to the host as
``threedcal_clock`` so the host's deadlines are kept in the printer's time, not the CPU's.
"""

from __future__ import annotations

import math

from serial.serialutil import SerialException

from threedcal.errors import ConfigError
from threedcal.sim.simport import SimulatedPort


class Serial(SimulatedPort):
    def __init__(self, *args, **kwargs):
        self.firmware = None
        super().__init__(*args, **kwargs)

    def open(self):
        from threedcal.sim.marlin import firmware_for_url

        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        try:
            self.firmware = firmware_for_url(self._port)
        except ConfigError as exc:
            raise SerialException(str(exc)) from exc
        if self.firmware.disconnected:
            raise SerialException(f"could not open port {self._port}: device vanished")
        self.is_open = True
        self.firmware.open()  # DTR toggles on open: an AVR board reboots

    @property
    def threedcal_clock(self):
        return self.firmware.clock.now

    def close(self):
        if self.is_open and self.firmware is not None:
            self.firmware.close()
        self.is_open = False

    def _check(self):
        super()._check()
        if self.firmware.disconnected:
            raise SerialException(
                "device reports readiness to read but returned no data "
                "(device disconnected or multiple access on port?)"
            )

    @property
    def in_waiting(self):
        self._check()
        return self.firmware.waiting(self.firmware.clock.now())

    def read(self, size=1):
        self._check()
        clock = self.firmware.clock
        timeout = math.inf if self._timeout is None else float(self._timeout)
        deadline = clock.now() + timeout
        data = b""
        while True:
            data += self.firmware.take(size - len(data), clock.now())
            self._check()
            if len(data) >= size or timeout == 0:
                return data
            due = self.firmware.next_due()
            if data and (due is None or due > clock.now()):
                return data  # like a real port: hand over what has arrived
            if due is None or due > deadline:
                if math.isinf(deadline):
                    raise SerialException("read without timeout on a silent simulated port")
                clock.advance_to(deadline)
                return data
            clock.advance_to(due)

    def write(self, data):
        self._check()
        data = bytes(data)
        self.firmware.receive(data)
        return len(data)

    def reset_input_buffer(self):
        self._check()
        self.firmware.take(1 << 30, self.firmware.clock.now())
