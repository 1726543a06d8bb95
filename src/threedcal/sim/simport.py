"""What every simulated serial port shares: no modem lines, no output buffer, an open check.

Kept import-light (pyserial imports the URL handlers that build on it).
"""

from __future__ import annotations

from serial.serialutil import PortNotOpenError, SerialBase


class SimulatedPort(SerialBase):
    """A pyserial port backed by an in-process simulated device; subclasses do open/read/write."""

    BAUDRATES = (
        9600,
        19200,
        38400,
        57600,
        115200,
        230400,
        250000,
    )  # what Marlin and ReSkin boards use

    def _reconfigure_port(self, *args, **kwargs):
        pass

    def _check(self):
        if not self.is_open:
            raise PortNotOpenError()

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
