"""Host throughput on the fake firmware, against a bare write-and-wait-for-ok loop in the same run
(pyserial readline, no line numbers or checksums); also the motion model's printer-time estimate
for a 10 x 10 probe grid, for scale.
"""

from __future__ import annotations

import time

import serial

from threedcal.hardware.printer import MarlinHost, register_url_handlers
from threedcal.sim.marlin import FIRMWARES

N = 3000


def host_rate() -> float:
    with MarlinHost("simmarlin://bench-host?speedup=inf") as host:
        start = time.perf_counter()
        for _ in range(N):
            host.send("M105")
        rate = N / (time.perf_counter() - start)
    FIRMWARES.withdraw("bench-host")
    return rate


def bare_rate() -> float:
    register_url_handlers()
    port = serial.serial_for_url("simmarlin://bench-bare?speedup=inf&reset_on_open=0", timeout=5)
    start = time.perf_counter()
    for _ in range(N):
        port.write(b"M105\n")
        while not port.readline().startswith(b"ok"):
            pass
    rate = N / (time.perf_counter() - start)
    port.close()
    FIRMWARES.withdraw("bench-bare")
    return rate


def main() -> None:
    bare = bare_rate()
    host = host_rate()
    print(f"bare write+readline loop: {bare:,.0f} commands/s")
    print(f"MarlinHost (numbered, checksummed, classified): {host:,.0f} commands/s")
    print(f"ratio host/bare: {host / bare:.2f}")
    from threedcal.hardware.motion import MotionModel
    from threedcal.hardware.printer import printer_profile

    model = MotionModel(printer_profile("ender3"))
    targets = []
    for i in range(10):
        for j in range(10):
            x, y = 100 + 2 * i, 100 + 2 * j
            targets += [(x, y, 12.0), (x, y, 10.0), (x, y, 12.0)]
    est = model.plan_time(targets, 20.0)
    print(f"10x10 grid, 3 moves per point: motion model {est:.0f} s of printer time")


if __name__ == "__main__":
    main()
