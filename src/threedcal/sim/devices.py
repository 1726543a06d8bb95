"""Simulated devices found by name: a bench serves its firmware or ReSkin board under a name, and
the pyserial handler of ``simmarlin://NAME`` or ``simreskin://NAME`` finds that same object.

Kept free of pyserial: the config check reaches the firmware's fault list without it.
"""

from __future__ import annotations

from typing import Generic, TypeVar

Device = TypeVar("Device")


class DeviceRegistry(Generic[Device]):
    """The devices behind one URL scheme, by name."""

    def __init__(self, scheme: str, what: str, hint: str):
        self.scheme, self.what, self.hint = scheme, what, hint
        self._devices: dict[str, Device] = {}

    def serve(self, name: str, device: Device) -> Device:
        """Make `device` the one behind ``scheme://name``."""
        self._devices[name] = device
        return device

    def get(self, name: str) -> Device:
        try:
            return self._devices[name]
        except KeyError:
            raise KeyError(f"no {self.what} named {name!r} ({self.hint})") from None

    def __contains__(self, name: str) -> bool:
        return name in self._devices

    def withdraw(self, name: str) -> None:
        """``scheme://name`` no longer reaches anything (a no-op when nothing is served there)."""
        self._devices.pop(name, None)
