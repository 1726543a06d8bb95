"""A simulated scene for `threedcal rig`'s tests, and calls to its API (a helper module, not a
conftest: a second conftest.py would shadow tests/conftest.py for `from conftest import`)."""

from __future__ import annotations

import json
import urllib.error
import urllib.request

import yaml

# A plan coarse enough to collect in seconds (a touch search at one place, a few registration
# presses, a coarse grid).
QUICK_PLAN = {
    "spacing_mm": 4.0,
    "depth_mm": 1.0,
    "frames": 1,
    "touch_search": {"points": 1},
    "registration": {"spacing_mm": 4.0, "depth_mm": 0.25},
}


def write_scene(folder, sensor="digit_fots", seed=7, saved=False, **extra) -> tuple[str, str]:
    """(config path, scene name) of a simulated scene whose mount is the file rig_mount.yaml;
    `saved`: the file is there, with the profile's values (else the page is to write it)."""
    scene = {
        "sensor": sensor,
        "printer": "ender3",
        "port": "sim",
        "seed": seed,
        "mount": "rig_mount.yaml",  # beside the config: the tests run in `folder`
        "probe": {"radius_mm": 2.0},
        "plan": QUICK_PLAN,
        **extra,
    }
    if saved:
        from threedcal.profiles import load_profile

        mount = load_profile("sensor", sensor)["mount"]
        (folder / "rig_mount.yaml").write_text(yaml.safe_dump(mount))
    path = folder / "rig.yaml"
    path.write_text(yaml.safe_dump({"scenes": {"unit": scene}}))
    return str(path), "unit"


def call(url: str, path: str, body: dict | None = None, method: str | None = None):
    """(HTTP status, JSON answer) of one API call; a body makes it a POST."""
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(
        url + path.lstrip("/"),
        data=data,
        method=method or ("GET" if body is None else "POST"),
        headers={"Content-Type": "application/json"},
    )
    try:
        with urllib.request.urlopen(request, timeout=60) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as error:
        return error.code, json.loads(error.read())


def wait_idle(url: str, timeout_s: float = 120.0) -> dict:
    import time

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        status = call(url, "api/status")[1]
        if status["busy"] is None:
            return status
        time.sleep(0.1)
    raise AssertionError(f"the rig stayed busy for {timeout_s} s: {status}")
