"""`threedcal rig`'s page through its own HTTP API on the simulated bench: a unit set up from
nothing (home, jog, find the gel, save the mount) against the bench's hidden truth; the refusals;
a collection watched; and the rig left safe when the page goes away."""

from __future__ import annotations

import asyncio
import time

import aiohttp
import pytest
import yaml
from simulated_rig import QUICK_PLAN, call, wait_idle, write_scene

from threedcal.collect.plan import clearance_z
from threedcal.errors import ConfigError
from threedcal.page.control import RigControl
from threedcal.page.server import check_host, serving
from threedcal.profiles import load_profile
from threedcal.study.config import load_config


@pytest.fixture
def page(tmp_path, monkeypatch):
    """(RigControl, URL) of a simulated DIGIT served on a free port, in tmp_path."""
    monkeypatch.chdir(tmp_path)
    config, scene = write_scene(tmp_path)
    with RigControl(config, scene) as control, serving(control) as url:
        yield control, url


def truth_mount(control: RigControl) -> dict:
    """Where the bench really seated the sensor: the profile's base, moved by the hidden seating,
    and the hidden first touch."""
    profile = load_profile("sensor", control.scene["sensor"])["mount"]
    truth = control.rig.bench.truth
    return {
        "x_offset_mm": profile["x_offset_mm"] + truth.seating_offset_mm[0],
        "y_offset_mm": profile["y_offset_mm"] + truth.seating_offset_mm[1],
        "z_touch_mm": profile["z_touch_mm"] + truth.touch_offset_mm,
    }


@pytest.mark.slow  # about a hundred simulated presses per sensor
@pytest.mark.parametrize("sensor", ["digit_fots", "gelsight_mini"])
def test_a_unit_is_set_up_from_nothing_through_the_page_api(tmp_path, monkeypatch, sensor):
    monkeypatch.chdir(tmp_path)
    # the touch search as a study's scene has it: three places about the centre
    plan = {**QUICK_PLAN, "touch_search": {"points": 3}}
    config, scene = write_scene(tmp_path, sensor=sensor, seed=11, plan=plan)
    with RigControl(config, scene) as control, serving(control) as url:
        status = call(url, "api/status")[1]
        assert not status["homed"] and status["found"] is None and status["mount_file"]
        assert call(url, "api/home", {})[0] == 200
        # the user jogs the ball roughly over the gel's middle, off it by a millimetre
        for axis, step in (("x", 1.0), ("y", -0.5)):
            assert call(url, "api/jog", {"axis": axis, "step_mm": step})[0] == 200
        assert call(url, "api/find", {})[0] == 200
        status = wait_idle(url)
        assert status["find"]["state"] == "found", status
        # the touch search bisects: its 8 presses at each of the three places
        assert status["find"]["touch_presses"] == 3 * 8, status
        found, truth = status["found"], truth_mount(control)
        assert abs(found["x_offset_mm"] - truth["x_offset_mm"]) < 0.1
        assert abs(found["y_offset_mm"] - truth["y_offset_mm"]) < 0.1
        assert abs(found["z_touch_mm"] - truth["z_touch_mm"]) < 0.02
        # the probe waits lifted over the gel, and the page draws it once registered
        assert status["registered"] and status["position_mm"][2] == pytest.approx(
            found["z_touch_mm"] + found["z_clearance_mm"], abs=1e-3
        )
        assert control.probe_px(status["position_mm"])[2] == 0  # lifted: no contact
        code, answer = call(url, "api/mount", {})
        assert code == 200 and answer["written"] == "rig_mount.yaml"
    saved = yaml.safe_load((tmp_path / "rig_mount.yaml").read_text())
    assert saved == {k: round(v, 4) for k, v in found.items()}
    # the scene now reads the mount from that file; its profile (and the weights' name) unchanged
    scene_config = load_config(config)["scenes"][scene]
    assert scene_config["sensor"] == sensor


def test_refusals_name_why_and_send_nothing(page):
    control, url = page
    acked = control.rig.printer.acked

    def refused(body, status=409):
        before = len(acked)
        code, answer = call(url, "api/jog", body)
        assert code == status, answer
        assert len(acked) == before, "a refused jog sent G-code"
        return answer["error"]

    assert "home first" in refused({"axis": "z", "step_mm": -1})
    assert call(url, "api/home", {})[0] == 200
    z = control.rig.printer.commanded[2]
    floor = control.limits.floor_z
    message = refused({"axis": "z", "step_mm": floor - z - 0.01})
    assert "deepest the digit_fots profile allows" in message and "max_penetration_mm" in message
    assert "axis 'w'" in refused({"axis": "w", "step_mm": 1}, 400)
    assert "not a number" in refused({"axis": "x", "step_mm": "far"}, 400)
    assert "finite" in refused({"axis": "x", "step_mm": float("1e9")}, 400)
    for _ in range(2):
        assert call(url, "api/jog", {"axis": "x", "step_mm": 50})[0] == 200
    assert "outside the travel" in refused({"axis": "x", "step_mm": 50})
    for _ in range(2):
        assert call(url, "api/jog", {"axis": "x", "step_mm": -50})[0] == 200
    # down to the floor is allowed; sideways there is not (the ball would drag on the gel)
    assert call(url, "api/jog", {"axis": "z", "step_mm": floor - z})[0] == 200
    assert "lift it" in refused({"axis": "x", "step_mm": 0.5})
    code, answer = call(url, "api/status")
    assert "lift it" in answer["refusal"]
    status, answer = call(url, "api/mount", {})
    assert status == 409 and "find the gel first" in answer["error"]


def test_bad_host_input_is_refused_before_anything_opens():
    assert check_host("127.0.0.1") == "127.0.0.1"
    assert check_host("localhost") == "localhost"
    for bad in ("", "two words", "http://127.0.0.1", "no-such-host.invalid"):
        with pytest.raises(ConfigError, match="--host"):
            check_host(bad)


def test_bad_host_on_the_command_line(tmp_path, monkeypatch, capsys):
    from threedcal.cli import main

    monkeypatch.chdir(tmp_path)
    config, scene = write_scene(tmp_path)
    code = main(["rig", "--config", config, "--scene", scene, "--host", "no-such-host.invalid"])
    assert code != 0
    assert "--host 'no-such-host.invalid'" in capsys.readouterr().err


@pytest.mark.slow  # a short simulated collection
def test_a_collection_is_watched_and_owns_the_printer(tmp_path, monkeypatch):
    """While the page's collection runs its status answers at once, a jog is refused naming the
    collection, and the page shows rows done, time left and the last frame."""
    monkeypatch.chdir(tmp_path)
    config, scene = write_scene(tmp_path, saved=True)
    with RigControl(config, scene) as control, serving(control) as url:
        assert call(url, "api/collect", {})[0] == 200
        waits, refusal, seen = [], None, None
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:
            started = time.perf_counter()
            status = call(url, "api/status")[1]
            waits.append(time.perf_counter() - started)
            collection = status["collection"]
            if collection["state"] != "running":
                break
            if collection["rows_done"] >= 5 and refusal is None:
                refusal = call(url, "api/jog", {"axis": "z", "step_mm": 1})
                seen = (collection["rows_done"], collection["left_s"], status["frame_seq"])
            time.sleep(0.05)
        assert collection["state"] == "done", collection
        assert collection["rows_done"] == collection["rows_total"] > 5
        assert refusal[0] == 409 and "collection owns the printer" in refusal[1]["error"]
        assert seen[1] is not None and seen[1] > 0 and seen[2] > 0
        # not a timing claim (benchmarks/bench_rig_page.py measures it): the status never waits
        # on the printer, which the collection held for seconds
        assert max(waits) < 2.0, max(waits)
        assert (tmp_path / "results" / "unit" / "raw.zarr").is_dir()


def test_collect_refuses_a_found_mount_that_was_not_saved(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    config, scene = write_scene(tmp_path, saved=True)
    with RigControl(config, scene) as control:
        from threedcal.mount import SensorMount

        control.found = SensorMount(109.0, 111.0, 135.1, 2.0)
        with pytest.raises(Exception, match="save the mount"):
            control.collect()


async def _close_socket_while(url: str, action: str) -> None:
    async with aiohttp.ClientSession() as session:
        socket = await session.ws_connect(url + "ws")
        reader = asyncio.create_task(socket.receive())  # answers the server's pings, as a browser
        async with session.post(url + action, json={}) as response:
            assert response.status == 200, await response.text()
        await asyncio.sleep(0.5)  # the job is under way
        assert not reader.done(), "the server closed the page's socket"
        await socket.close()  # the page is closed
        await reader


def _wait(predicate, timeout_s=120.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError("timed out")


def test_leaving_the_page_during_a_collection_lifts_the_probe(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    config, scene = write_scene(tmp_path, saved=True, plan={**QUICK_PLAN, "spacing_mm": 0.5})
    with RigControl(config, scene) as control, serving(control) as url:
        asyncio.run(_close_socket_while(url, "api/collect"))
        _wait(lambda: control.collection["state"] != "running")
        _wait(lambda: control.busy is None)
        assert control.collection["state"] == "stopped"
        assert "page" in control.collection["why"]
        assert control.collection["rows_done"] < control.collection["rows_total"]
        firmware = control.rig.bench.firmware
        # lifted as collect lifts: to the clearance height over the scene's mount
        assert firmware.position()[2] == pytest.approx(clearance_z(control.sensor), abs=0.01)
        assert control.rig.printer.acked[-1][1] == "M84"  # steppers released (ender3: steppers_off)
        # the store keeps what was captured and says why it stopped
        import zarr

        store = zarr.open_group("results/unit/raw.zarr", mode="r")
        runs = dict(store["captured"].attrs)["runs"]
        assert "StoppedFromPage" in runs[-1]["stopped"]
        assert "lifted" in runs[-1]["safe_stop"]


def test_leaving_the_page_while_finding_the_gel_lifts_the_probe(page):
    control, url = page
    assert call(url, "api/home", {})[0] == 200
    asyncio.run(_close_socket_while(url, "api/find"))
    _wait(lambda: control.busy is None)
    assert control.find_state["state"] == "failed" and "stopped" in control.find_state["why"]
    assert control.rig.bench.firmware.position()[2] == pytest.approx(
        control.limits.safe_z, abs=0.01
    )
    assert control.rig.printer.acked[-1][1] == "M84"
    assert not control.rig.printer.homed  # released: home again before the next move
    assert "home first" in call(url, "api/jog", {"axis": "z", "step_mm": 1})[1]["error"]


def test_the_stop_button_lifts_an_idle_probe(page):
    control, url = page
    assert call(url, "api/home", {})[0] == 200
    assert call(url, "api/jog", {"axis": "z", "step_mm": -2.0})[0] == 200
    assert call(url, "api/stop", {})[0] == 200
    assert control.rig.bench.firmware.position()[2] == pytest.approx(
        control.limits.safe_z, abs=0.01
    )
    assert "lifted" in call(url, "api/status")[1]["message"]


def test_the_frame_is_a_jpeg_of_the_image_beside_its_difference(page):
    import urllib.request

    import cv2
    import numpy as np

    control, url = page
    call(url, "api/home", {})
    with urllib.request.urlopen(url + "api/frame.jpg") as response:
        assert response.headers["Content-Type"] == "image/jpeg"
        image = cv2.imdecode(np.frombuffer(response.read(), np.uint8), cv2.IMREAD_COLOR)
    height, width = control.sensor["image"]["height_px"], control.sensor["image"]["width_px"]
    assert image.shape == (height, 2 * width + 4, 3)
