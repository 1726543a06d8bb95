"""pyserial URL handler ``simmarlin://NAME?options``: a serial port wired to a SimMarlin board.

pyserial finds it as ``<package>.protocol_simmarlin`` for every package in
``serial.protocol_handler_packages``; ``threedcal.hardware.printer`` adds ``threedcal.sim``.
Reads run on the firmware's virtual clock (sleeping only ``dt / speedup`` real seconds); see
threedcal.sim.simport. Opening toggles DTR: the AVR board reboots.
"""

from __future__ import annotations

from threedcal.sim.marlin import firmware_for_url
from threedcal.sim.simport import SimulatedPort


class SimMarlinPort(SimulatedPort):
    @staticmethod
    def device_for_url(url: str):
        return firmware_for_url(url)


# pyserial opens a ``simmarlin://`` URL through the module's ``Serial`` class
Serial = SimMarlinPort
