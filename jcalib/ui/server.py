"""The operator app's web server: pages, the JSON API, the event and live-frame websockets (FastAPI).

FastAPI (on Starlette and uvicorn) serves everything from this package, assets included: the app works on
a cell PC without internet. Every request passes :class:`jcalib.ui.security.Guard` (token, host, origin);
state-changing requests also need the browser to hold the control lease, except STOP.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from pathlib import Path
from typing import Any

from fastapi import Depends, FastAPI, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool

import jcalib
from jcalib.errors import BadInputError, DeviceError, JcalibError
from jcalib.ui import inspect
from jcalib.ui.jobs import Busy
from jcalib.ui.pages import PAGES, render_page
from jcalib.ui.security import CLIENT_HEADER, Guard
from jcalib.ui.state import AppState

__all__ = ["make_app"]

STATIC = Path(__file__).parent / "static"


class ReadOnly(JcalibError):
    """This browser does not control the cell."""

    exit_code = 2


def make_app(state: AppState, token: str, hosts: set[str]):
    """The ASGI application of ``state``, guarded by ``token`` for the ``Host`` values in ``hosts``."""

    @contextlib.asynccontextmanager
    async def lifespan(app):
        state.bus.bind(asyncio.get_running_loop())
        yield
        state.begin_close()  # the app's stop waits for it (launch: join_background)

    api = FastAPI(title="jcalib ui", lifespan=lifespan, docs_url=None, redoc_url=None, openapi_url=None)
    api.mount("/static", StaticFiles(directory=STATIC), name="static")

    @api.exception_handler(JcalibError)
    async def jcalib_error(request: Request, exc: JcalibError):
        status = 409 if isinstance(exc, Busy) else 403 if isinstance(exc, ReadOnly) else \
            503 if isinstance(exc, DeviceError) else 400
        return JSONResponse({"error": str(exc)}, status_code=status)

    def controller(request: Request) -> str:
        client = request.headers.get(CLIENT_HEADER)
        if not state.lease.holds(client):
            raise ReadOnly("read-only: another browser controls the cell (it can release control, or take over "
                           f"{int(state.lease.timeout_s)} s after it closed its pages)")
        return client

    async def body(request: Request) -> dict:
        raw = await request.body()
        if len(raw) > (16 << 20):
            raise BadInputError("request body larger than 16 MiB")
        try:
            data = json.loads(raw or b"{}")
        except ValueError:
            raise BadInputError("request body: expected JSON") from None
        if not isinstance(data, dict):
            raise BadInputError("request body: expected a JSON object")
        return data

    # --- pages ---------------------------------------------------------------------------------------
    def page_route(path: str):
        def page() -> HTMLResponse:
            return HTMLResponse(render_page(path, token, state.config.title, jcalib.__version__),
                                headers={"cache-control": "no-store"})  # fmt: skip

        return page

    for path in PAGES:
        api.get(path, response_class=HTMLResponse, include_in_schema=False)(page_route(path))

    @api.get("/report")
    def report():
        path = state.config.report_path
        if not path.is_file():
            return HTMLResponse("<p>No report yet: calibrate first (Calibrate &amp; inspect). The report is written "
                                "a few seconds after each solve.</p>", status_code=404)
        return FileResponse(path, media_type="text/html")

    # --- state, control, STOP -------------------------------------------------------------------------
    @api.get("/api/state")
    def get_state(request: Request):
        client = request.headers.get(CLIENT_HEADER)
        return {"control": state.lease.status(client), "jobs": state.jobs.to_json(),
                "devices": {"robot": state.config.robot_url, "robot_state": state.robot_state, "cameras": list(state.cameras),
                            "error": state.device_error, "simulated": state.config.simulated},
                "session": str(state.config.session_dir), "cell": str(state.config.cell_path)}  # fmt: skip

    @api.get("/api/control")
    def get_control(request: Request):
        return state.lease.status(request.headers.get(CLIENT_HEADER))

    @api.post("/api/control/claim")
    def claim(request: Request):
        client = request.headers.get(CLIENT_HEADER)
        if not client:
            raise BadInputError("X-Jcalib-Client header missing")
        if not state.lease.acquire(client):
            raise ReadOnly("another browser controls the cell; it must release control (or close its pages)")
        state.bus.publish({"type": "control"})
        return state.lease.status(client)

    @api.post("/api/control/release")
    def release(client: str = Depends(controller)):
        state.lease.release(client)
        state.bus.publish({"type": "control"})
        return state.lease.status(client)

    @api.post("/api/stop")
    def stop():
        return {"message": state.stop()}

    # --- cell ----------------------------------------------------------------------------------------
    @api.get("/api/cell")
    def get_cell():
        return state.cell_document()

    @api.post("/api/cell/validate")
    async def validate_cell(request: Request):
        data = await body(request)
        spec = await run_in_threadpool(state.cell_spec, data.get("text"))
        return {"ok": True, "summary": state.cell_summary(spec)}

    @api.put("/api/cell")
    async def put_cell(request: Request, client: str = Depends(controller)):
        data = await body(request)
        return await run_in_threadpool(state.save_cell, data.get("text"))

    @api.get("/api/cell/scene")
    def scene():
        return state.scene()

    # --- cameras -------------------------------------------------------------------------------------
    @api.get("/api/cameras")
    def cameras():
        return state.camera_list()

    @api.post("/api/cameras/{camera}/settings")
    async def camera_settings(camera: str, request: Request, client: str = Depends(controller)):
        data = await body(request)
        return await run_in_threadpool(state.set_camera_settings, camera, data.get("settings"))

    # --- plan and capture ----------------------------------------------------------------------------
    @api.post("/api/plan")
    async def plan(request: Request, client: str = Depends(controller)):
        data = await body(request)
        job = await run_in_threadpool(state.start_plan, data)
        return {"job": job.to_json()}

    @api.get("/api/plan")
    def get_plan():
        return state.plan_summary()

    @api.post("/api/capture/start")
    async def capture_start(request: Request, client: str = Depends(controller)):
        data = await body(request)
        job = await run_in_threadpool(state.start_capture, data)
        return {"job": job.to_json()}

    @api.post("/api/capture/{what}")
    def capture_control(what: str, client: str = Depends(controller)):
        if what not in ("pause", "resume", "abort"):
            raise BadInputError(f"capture: expected pause, resume or abort, got {what!r}")
        return {"message": state.capture_command(what)}

    @api.get("/api/capture")
    def capture_status():
        return {"state": state.capture_state or None, "history": state.adaptive_history}

    @api.get("/api/session")
    def session():
        return state.session_summary()

    @api.get("/api/session/thumb/{station}/{camera}")
    def thumb(station: str, camera: str):
        return Response(state.thumbnail(station, camera), media_type="image/jpeg")

    @api.get("/api/session/image/{station}/{camera}")
    def image(station: str, camera: str):
        from jcalib.ui.live import encode_jpeg
        from jcalib.vision import load_image

        data, _ = encode_jpeg(load_image(state.image_path(station, camera)), quality=92)
        return Response(data, media_type="image/jpeg")

    @api.get("/api/coverage/{camera}.png")
    def coverage(camera: str):
        return Response(state.coverage_png(camera), media_type="image/png")

    # --- calibrate, inspect, exclusions ----------------------------------------------------------------
    @api.post("/api/calibrate")
    def calibrate(client: str = Depends(controller)):
        return {"job": inspect.start_calibrate(state).to_json()}

    @api.post("/api/exclusions")
    async def exclusions(request: Request, client: str = Depends(controller)):
        data = await body(request)
        job = await run_in_threadpool(inspect.set_exclusion, state, data.get("station"), data.get("camera"),
                                      data.get("excluded"))
        return {"job": job.to_json()}

    @api.get("/api/result")
    def result():
        return inspect.result_summary(state)

    @api.get("/api/result/view/{station}/{camera}")
    def view(station: str, camera: str):
        return inspect.view_residuals(state, station, camera)

    # --- export ----------------------------------------------------------------------------------------
    @api.get("/api/export/formats")
    def formats():
        return inspect.export_formats(state)

    @api.post("/api/export")
    async def export(request: Request):
        data = await body(request)
        name, text = await run_in_threadpool(inspect.export, state, data.get("format"), data.get("options") or {})
        return Response(text.encode("utf-8"), media_type="text/plain; charset=utf-8",
                        headers={"content-disposition": f'attachment; filename="{name}"'})

    # --- websockets ------------------------------------------------------------------------------------
    @api.websocket("/ws/events")
    async def events(ws: WebSocket):
        client = ws.query_params.get("client") or ""
        await ws.accept()
        queue = state.bus.subscribe()
        state.lease.connected(client)
        closed = asyncio.create_task(_until_closed(ws))
        try:
            while not closed.done():
                getter = asyncio.create_task(queue.get())
                await asyncio.wait({getter, closed}, return_when=asyncio.FIRST_COMPLETED)
                if not getter.done():
                    getter.cancel()
                    break
                await ws.send_text(json.dumps(getter.result(), allow_nan=False, default=_json_default))
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            closed.cancel()
            state.bus.unsubscribe(queue)
            state.lease.disconnected(client)

    @api.websocket("/ws/live")
    async def live(ws: WebSocket):
        camera = ws.query_params.get("camera") or ""
        client = ws.query_params.get("client") or ""
        await ws.accept()
        det = state.detectors.get(camera)
        if det is None:
            await ws.send_text(json.dumps({"type": "error", "message": f"camera {camera!r} is not connected"}))
            await ws.close()
            return
        state.lease.connected(client)
        await run_in_threadpool(det.watch)
        try:
            await _stream(ws, det)
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            state.lease.disconnected(client)
            await run_in_threadpool(det.unwatch)

    return Guard(api, token, hosts)


def _json_default(x: Any):
    import numpy as np

    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


async def _until_closed(ws: WebSocket) -> None:
    """Returns when the page closes the websocket (or the server shuts down); "ack" messages are ignored."""
    with contextlib.suppress(WebSocketDisconnect, RuntimeError):
        while True:
            message = await ws.receive()
            if message.get("type") == "websocket.disconnect":
                return


async def _stream(ws: WebSocket, det) -> None:
    """Send the newest frame after the page drew the previous one ("ack"), and every new overlay; returns when
    the page closes the websocket."""
    from jcalib.ui.live import encode_jpeg

    ack = asyncio.Event()
    ack.set()
    closed = asyncio.Event()

    async def receive() -> None:
        with contextlib.suppress(WebSocketDisconnect, RuntimeError):
            while True:
                message = await ws.receive()
                if message.get("type") == "websocket.disconnect":
                    break
                if message.get("text") == "ack":
                    ack.set()
        closed.set()
        ack.set()

    reader = asyncio.create_task(receive())
    cam, seq, overlay_seq = det.camera, 0, -1
    try:
        while not closed.is_set():
            await ack.wait()
            if closed.is_set():
                break
            frame, new = await run_in_threadpool(cam.wait_frame, seq, 0.25)
            overlay = det.overlay
            if overlay.get("seq", 0) != overlay_seq and overlay.get("time"):
                overlay_seq = overlay.get("seq", 0)
                await ws.send_text(json.dumps({"type": "overlay", **overlay}, default=_json_default))
            if frame is None or new == seq:
                continue
            seq = new
            data, scale = await run_in_threadpool(encode_jpeg, frame.image)
            await ws.send_text(json.dumps({"type": "frame", "seq": seq, "scale": scale, "fps": cam.fps,
                                           "width": int(frame.image.shape[1]), "height": int(frame.image.shape[0])}))
            ack.clear()
            await ws.send_bytes(data)
    finally:
        reader.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reader
