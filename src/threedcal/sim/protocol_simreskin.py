"""pyserial URL handler ``simreskin://NAME``: a serial port wired to a registered SimReSkin board.

pyserial finds it as ``<package>.protocol_simreskin`` for every package in
``serial.protocol_handler_packages`` (``threedcal.hardware.printer.register_url_handlers`` adds
``threedcal.sim``). Like ``simmarlin://``, read timeouts are in *simulated* seconds on the coupled
firmware's clock, offered to the reader as ``threedcal_clock``.
"""

from __future__ import annotations

import math

from serial.serialutil import SerialException

from threedcal.errors import ConfigError
from threedcal.sim.simport import SimulatedPort


class Serial(SimulatedPort):
    def __init__(self, *args, **kwargs):
        self.board = None
        super().__init__(*args, **kwargs)

    def open(self):
        from threedcal.sim.reskin import board_for_url

        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        try:
            self.board = board_for_url(self._port)
        except ConfigError as exc:
            raise SerialException(str(exc)) from exc
        self.is_open = True
        self.board.open()

    @property
    def threedcal_clock(self):
        return self.board.clock.now

    def close(self):
        if self.is_open and self.board is not None:
            self.board.close()
        self.is_open = False

    @property
    def in_waiting(self):
        self._check()
        return self.board.waiting(self.board.clock.now())

    def read(self, size=1):
        self._check()
        clock = self.board.clock
        timeout = math.inf if self._timeout is None else float(self._timeout)
        deadline = clock.now() + timeout
        data = b""
        while True:
            data += self.board.take(size - len(data), clock.now())
            if len(data) >= size or timeout == 0 or data:
                return data  # like a real port: hand over what has arrived
            due = self.board.next_due(clock.now())
            if due > deadline:
                if math.isinf(deadline):
                    raise SerialException("read without timeout on a simulated port")
                clock.advance_to(deadline)
                return data
            clock.advance_to(due)

    def write(self, data):
        self._check()
        return len(bytes(data))  # the board ignores what the host sends

    def reset_input_buffer(self):
        self._check()
        self.board.reset_input(self.board.clock.now())
