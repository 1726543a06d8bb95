"""What every simulated serial port shares: a device found by URL, reads on its virtual clock, no
modem lines, no output buffer, an open check.

A device offers: `clock` (with now() and advance_to(t)), open(), close(), `disconnected`,
waiting(now), take(size, now), next_due(now) (when more output will have arrived, or None),
receive(data) and reset_input(now). Read timeouts are in *simulated* seconds: waiting advances the
device's clock, and the port offers that clock to the host as ``threedcal_clock`` so the host's
deadlines are kept in the device's time, not the CPU's.
"""

from __future__ import annotations

import math

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from threedcal.errors import ConfigError


class SimulatedPort(SerialBase):
    """A pyserial port backed by an in-process simulated device; subclasses say how a URL finds it."""

    BAUDRATES = (
        9600,
        19200,
        38400,
        57600,
        115200,
        230400,
        250000,
    )  # what Marlin and ReSkin boards use

    def __init__(self, *args, **kwargs):
        self.device = None
        super().__init__(*args, **kwargs)

    @staticmethod
    def device_for_url(url: str):
        raise NotImplementedError

    def open(self):
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        try:
            self.device = self.device_for_url(self._port)
        except ConfigError as exc:
            raise SerialException(str(exc)) from exc
        if self.device.disconnected:
            raise SerialException(f"could not open port {self._port}: device vanished")
        self.is_open = True
        self.device.open()

    @property
    def threedcal_clock(self):
        return self.device.clock.now

    def close(self):
        if self.is_open and self.device is not None:
            self.device.close()
        self.is_open = False

    def _reconfigure_port(self, *args, **kwargs):
        pass

    def _check(self):
        if not self.is_open:
            raise PortNotOpenError()
        if self.device.disconnected:
            raise SerialException(
                "device reports readiness to read but returned no data "
                "(device disconnected or multiple access on port?)"
            )

    @property
    def in_waiting(self):
        self._check()
        return self.device.waiting(self.device.clock.now())

    def read(self, size=1):
        self._check()
        clock = self.device.clock
        timeout = math.inf if self._timeout is None else float(self._timeout)
        deadline = clock.now() + timeout
        data = b""
        while True:
            data += self.device.take(size - len(data), clock.now())
            self._check()
            if len(data) >= size or timeout == 0:
                return data
            due = self.device.next_due(clock.now())
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
        self.device.receive(data)
        return len(data)

    def reset_input_buffer(self):
        self._check()
        self.device.reset_input(self.device.clock.now())

    def reset_output_buffer(self):
        self._check()

    @property
    def out_waiting(self):
        return 0

    def _update_dtr_state(self):
        pass

    def _update_rts_state(self):
        pass

    def _update_break_state(self):
        pass

    @property
    def cts(self):
        return True

    @property
    def dsr(self):
        return True

    @property
    def ri(self):
        return False

    @property
    def cd(self):
        return True
