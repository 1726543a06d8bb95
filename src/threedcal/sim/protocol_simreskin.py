"""pyserial URL handler ``simreskin://NAME``: a serial port wired to a registered SimReSkin board.

pyserial finds it as ``<package>.protocol_simreskin`` for every package in
``serial.protocol_handler_packages`` (``threedcal.hardware.printer.register_url_handlers`` adds
``threedcal.sim``). Like ``simmarlin://``, reads run on the coupled firmware's clock (see
threedcal.sim.simport).
"""

from __future__ import annotations

from threedcal.sim.reskin import board_for_url
from threedcal.sim.simport import SimulatedPort


class SimReSkinPort(SimulatedPort):
    @staticmethod
    def device_for_url(url: str):
        return board_for_url(url)


# pyserial opens a ``simreskin://`` URL through the module's ``Serial`` class
Serial = SimReSkinPort
