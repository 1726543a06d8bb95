"""`threedcal rig`'s web server (aiohttp): the page, its JSON API, the camera's frames, the heartbeat.

Every device call runs in a worker thread (RigControl holds the printer there); the event loop only
answers, so the status answers at once whatever the rig is doing. A page holds a WebSocket open to
/ws, pinged by the server every HEARTBEAT_S: when the last page's socket closes or stops answering
(the tab closed, the laptop asleep, the cable out), the rig is stopped as the stop button stops it.

API (JSON in and out; a refusal is 409 and a bad request 400, each with {"error": why}):
GET /api/status, GET /api/frame.jpg (the live image beside its difference to the blank),
POST /api/home, /api/blank, /api/jog {"axis": "x|y|z", "step_mm": s}, /api/find, /api/collect
(each {"wait": true} to answer when the job has ended, as a script wants), /api/stop,
/api/mount {"replace": false}.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import json
import socket
import threading
from collections.abc import Iterator
from importlib.resources import files
from pathlib import Path

import cv2
import numpy as np
from aiohttp import WSMsgType, web

from threedcal.errors import ConfigError, ThreedcalError
from threedcal.page.control import BadRequest, Refused, RigControl

HEARTBEAT_S = (
    5.0  # the server pings each page this often; a ping unanswered for half that closes it
)
STATIC = Path(str(files("threedcal") / "page" / "static"))
CONTROL = web.AppKey("control", RigControl)
SOCKETS = web.AppKey("sockets", set)
# The difference image is |frame - blank| times this, so a light touch shows.
DIFFERENCE_GAIN = 4.0


def check_host(host: str) -> str:
    """`--host` as given, if this machine can listen there; else a ConfigError naming it."""
    text = str(host).strip()
    if not text or any(c.isspace() for c in text) or "/" in text:
        raise ConfigError(f"--host {host!r}: not an address or host name (e.g. 127.0.0.1)")
    try:
        ipaddress.ip_address(text)
        return text
    except ValueError:
        pass
    try:
        socket.getaddrinfo(text, None)
    except (socket.gaierror, UnicodeError) as exc:
        raise ConfigError(
            f"--host {host!r}: this machine cannot resolve it ({exc}); give an address such as "
            "127.0.0.1 (the default: this machine only) or 0.0.0.0 (every network it is on)"
        ) from None
    return text


def is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def view_jpeg(frame: np.ndarray | None, blank: np.ndarray | None, probe: tuple | None) -> bytes:
    """The live frame (the probe drawn where the found mount puts it) beside |frame − blank|."""
    if frame is None:
        canvas = np.full((240, 320, 3), 40, np.uint8)
    else:
        live = np.ascontiguousarray(frame[..., ::-1])  # RGB inside, BGR for OpenCV
        if probe is not None:
            col, row, radius = probe
            centre = (int(round(col)), int(round(row)))
            cv2.drawMarker(live, centre, (0, 255, 255), cv2.MARKER_CROSS, 14, 1)
            if radius >= 1:
                cv2.circle(live, centre, int(round(radius)), (0, 255, 255), 1)
        if blank is None:
            difference = np.zeros_like(live)
        else:
            change = np.abs(frame.astype(np.float32) - blank) * DIFFERENCE_GAIN
            difference = np.clip(change, 0, 255).astype(np.uint8)[..., ::-1]
        gap = np.full((live.shape[0], 4, 3), 255, np.uint8)
        canvas = np.concatenate([live, gap, difference], axis=1)
    ok, data = cv2.imencode(".jpg", canvas, [cv2.IMWRITE_JPEG_QUALITY, 85])
    if not ok:
        raise ThreedcalError("the frame could not be encoded as JPEG")
    return data.tobytes()


def _answer(call):
    """A handler running `call(control, body)` in a worker thread; refusals as 409, bad input 400."""

    async def handler(request: web.Request) -> web.Response:
        control = request.app[CONTROL]
        body = {}
        if request.can_read_body:
            try:
                body = await request.json()
            except (json.JSONDecodeError, UnicodeDecodeError):
                return web.json_response({"error": "the body is not JSON"}, status=400)
            if not isinstance(body, dict):
                return web.json_response({"error": "the body must be a JSON object"}, status=400)
        loop = asyncio.get_running_loop()
        try:
            result = await loop.run_in_executor(None, call, control, body)
        except BadRequest as exc:
            return web.json_response({"error": str(exc)}, status=400)
        except (Refused, ThreedcalError) as exc:
            control._refuse(exc)
            return web.json_response({"error": str(exc)}, status=409)
        return web.json_response({"ok": True, **(result or {}), "status": control.status()})

    return handler


async def status(request: web.Request) -> web.Response:
    return web.json_response(request.app[CONTROL].status())


async def frame(request: web.Request) -> web.Response:
    control = request.app[CONTROL]

    def render() -> tuple[int, bytes]:
        seq, image, blank, probe = control.latest_frame()
        return seq, view_jpeg(image, blank, probe)

    seq, data = await asyncio.get_running_loop().run_in_executor(None, render)
    return web.Response(
        body=data,
        content_type="image/jpeg",
        headers={"Cache-Control": "no-store", "X-Frame-Seq": str(seq)},
    )


async def page(request: web.Request) -> web.Response:
    return web.FileResponse(STATIC / "index.html")


async def heartbeat(request: web.Request) -> web.WebSocketResponse:
    """The page's liveness: when the last page's socket goes, the rig is stopped safely."""
    app = request.app
    socket_ = web.WebSocketResponse(heartbeat=HEARTBEAT_S)
    await socket_.prepare(request)
    app[SOCKETS].add(socket_)
    try:
        async for message in socket_:
            if message.type == WSMsgType.ERROR:
                break
    finally:
        app[SOCKETS].discard(socket_)
        if not app[SOCKETS]:
            control = app[CONTROL]
            await asyncio.get_running_loop().run_in_executor(
                None, control.stop, "the page was closed or lost its connection"
            )
    return socket_


def make_app(control: RigControl) -> web.Application:
    app = web.Application()
    app[CONTROL] = control
    app[SOCKETS] = set()
    app.router.add_get("/", page)
    app.router.add_get("/api/status", status)
    app.router.add_get("/api/frame.jpg", frame)
    app.router.add_get("/ws", heartbeat)
    actions = {
        "/api/home": lambda c, b: c.home(),
        "/api/blank": lambda c, b: c.take_blank(),
        "/api/jog": lambda c, b: c.jog(b.get("axis"), b.get("step_mm")),
        "/api/find": lambda c, b: c.find_gel(wait=bool(b.get("wait", False))),
        "/api/collect": lambda c, b: c.collect(wait=bool(b.get("wait", False))),
        "/api/stop": lambda c, b: c.stop(),
        "/api/mount": lambda c, b: c.save_mount(bool(b.get("replace", False))),
    }
    for path, call in actions.items():
        app.router.add_post(path, _answer(call))

    async def close_sockets(app: web.Application) -> None:
        for socket_ in list(app[SOCKETS]):
            await socket_.close()

    app.on_shutdown.append(close_sockets)
    return app


@contextlib.contextmanager
def serving(control: RigControl, host: str = "127.0.0.1", port: int = 0) -> Iterator[str]:
    """The page served from a thread of its own while the block runs; yields its URL."""
    loop = asyncio.new_event_loop()
    runner = web.AppRunner(make_app(control), handle_signals=False)
    loop.run_until_complete(runner.setup())
    site = web.TCPSite(runner, host, port)
    loop.run_until_complete(site.start())
    bound = runner.addresses[0][1]
    thread = threading.Thread(target=loop.run_forever, name="threedcal-rig-page", daemon=True)
    thread.start()
    try:
        yield f"http://{host}:{bound}/"
    finally:
        asyncio.run_coroutine_threadsafe(runner.cleanup(), loop).result(timeout=30)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout=30)
        loop.close()


def serve(control: RigControl, host: str, port: int, announce=print) -> None:
    """Serve until Ctrl-C or SIGTERM (the caller then makes the rig safe and closes it)."""

    async def main() -> None:
        runner = web.AppRunner(make_app(control), handle_signals=True)
        await runner.setup()
        await web.TCPSite(runner, host, port).start()
        announce(f"http://{host}:{runner.addresses[0][1]}/")
        try:
            await asyncio.Event().wait()
        finally:
            await runner.cleanup()

    with contextlib.suppress(KeyboardInterrupt, web.GracefulExit):
        asyncio.run(main())
