"""``jcalib ui`` refuses whoever lacks the token, cross-site requests, other hosts, paths outside its folders,
and a second browser's motion commands; it listens on 127.0.0.1 by default.

The app runs as a user starts it (a subprocess printing its URL), with a replay camera and a simulated KUKA
controller served by this test on 127.0.0.1: the real server, the real protocol, nothing else on the network.
"""

from __future__ import annotations

import http.client
import json
import socket
from pathlib import Path

import numpy as np
import pytest


CELL = """schema: jcalib.cell/1
robot: {model: kuka_kr10_r1100_sixx}
cameras:
  cam0: {model: opencv5, mount: flange}
targets:
  board: {type: checkerboard, cols: 9, rows: 6, square: 0.025, mount: base}
"""


@pytest.fixture(scope="module")
def app(tmp_path_factory, ui_tools):
    from jcalib.acquisition.robots.serve import make_server
    from jcalib.acquisition.robots.simulated import SimulatedController

    tmp = tmp_path_factory.mktemp("ui-security")
    replay = _replay(tmp)
    (tmp / "cell.yaml").write_text(CELL)
    (tmp / "secret.txt").write_text("not for the browser")
    server = make_server("kuka", "127.0.0.1", 0, SimulatedController(time_scale=0.0)).start()
    ui = ui_tools.start_ui(["--cell", str(tmp / "cell.yaml"), "--session", str(tmp / "session"), "--port", "0",
                   "--robot", f"kuka://127.0.0.1:{server.port}", "--camera", f"cam0=replay://{replay}"], cwd=tmp)
    try:
        yield ui
    finally:
        code = ui_tools.stop_ui(ui)
        server.stop()
        assert code == 0, ui.output()


def _replay(tmp: Path) -> Path:
    import cv2

    folder = tmp / "replay"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(3):
        cv2.imwrite(str(folder / f"f{k}.png"), rng.integers(0, 255, (48, 64), dtype=np.uint8))
    return folder


def request(app, method: str, path: str, *, headers: dict | None = None, body: dict | None = None,
            host: str | None = None) -> tuple[int, dict, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", app.port, timeout=30)
    h = dict(headers or {})
    if host is not None:
        h["Host"] = host
    data = None if body is None else json.dumps(body).encode()
    if data is not None:
        h["Content-Type"] = "application/json"
    conn.request(method, path, body=data, headers=h)
    r = conn.getresponse()
    out = r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
    conn.close()
    return out


def ws_status(app, path: str, *, origin: str | None = None) -> int | None:
    """The HTTP status of a websocket handshake (101 when accepted)."""
    s = socket.create_connection(("127.0.0.1", app.port), timeout=30)
    lines = [f"GET {path} HTTP/1.1", f"Host: 127.0.0.1:{app.port}", "Upgrade: websocket", "Connection: Upgrade",
             "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Version: 13"]
    if origin:
        lines.append(f"Origin: {origin}")
    s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
    reply = s.recv(4096).decode("latin-1")
    s.close()
    return int(reply.split()[1]) if reply.startswith("HTTP/1.1") else None


def auth(app, client: str = "a") -> dict:
    return {"X-Jcalib-Token": app.token, "X-Jcalib-Client": client}


@pytest.mark.parametrize("path", ["/", "/live", "/capture", "/inspect", "/export", "/api/state", "/api/cell",
                                  "/static/app.css", "/static/common.js", "/report", "/api/session"])
def test_no_token_is_refused_and_a_wrong_one_too(app, path):
    status, _, body = request(app, "GET", path)
    assert status == 401, body
    assert b"not for the browser" not in body and b"schema" not in body
    status, _, _ = request(app, "GET", path + ("&" if "?" in path else "?") + "token=wrong" + app.token[5:])
    assert status == 403
    status, _, _ = request(app, "GET", path, headers={"X-Jcalib-Token": "x" * len(app.token)})
    assert status == 403


def test_the_token_in_the_url_sets_a_strict_cookie_and_leaves_the_address_bar(app):
    status, headers, _ = request(app, "GET", f"/?token={app.token}")
    assert status == 303 and headers["location"] == "/"
    cookie = headers["set-cookie"]
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    status, _, body = request(app, "GET", "/live", headers={"Cookie": cookie.split(";")[0]})
    assert status == 200 and b"<title>Live" in body


def test_state_changes_need_the_header_not_the_cookie(app):
    cookie = f"jcalib_token={app.token}"
    status, _, _ = request(app, "POST", "/api/cell/validate", headers={"Cookie": cookie}, body={"text": CELL})
    assert status == 403  # a cross-site form would carry the cookie, never the header
    status, _, _ = request(app, "POST", "/api/cell/validate", body={"text": CELL})
    assert status == 401
    status, _, body = request(app, "POST", "/api/cell/validate", headers=auth(app), body={"text": CELL})
    assert status == 200, body
    status, _, body = request(app, "POST", "/api/cell/validate", headers=auth(app), body={"text": "cameras: 3"})
    assert status == 400 and b"error" in body


def test_websockets_need_the_token_and_our_origin(app):
    assert ws_status(app, "/ws/events?client=a") == 403
    assert ws_status(app, "/ws/events?client=a&token=nope") == 403
    assert ws_status(app, f"/ws/events?client=a&token={app.token}", origin="http://evil.example") == 403
    assert ws_status(app, f"/ws/live?camera=cam0&token={app.token}", origin="http://evil.example") == 403
    assert ws_status(app, f"/ws/events?client=a&token={app.token}", origin=f"http://127.0.0.1:{app.port}") == 101


def test_other_host_names_are_refused_against_dns_rebinding(app):
    status, _, _ = request(app, "GET", "/api/state", headers=auth(app), host=f"evil.example:{app.port}")
    assert status == 403
    status, _, _ = request(app, "GET", "/api/state", headers=auth(app), host=f"localhost:{app.port}")
    assert status == 200


@pytest.mark.parametrize("path", [
    "/static/../state.py", "/static/%2e%2e/state.py", "/static/..%2Fsecurity.py",
    "/api/session/image/..%2F..%2Fsecret.txt/cam0", "/api/session/image/s000/..%2F..%2F..%2Fsecret.txt",
    "/api/session/thumb/%2Fetc%2Fpasswd/cam0", "/api/coverage/..%2F..%2Fsecret.txt.png", "/report/../cell.yaml",
    "/api/result/view/..%2F..%2Fsecret.txt/cam0",
])
def test_traversal_is_refused(app, path):
    status, _, body = request(app, "GET", path, headers=auth(app))
    assert status in (400, 403, 404), (status, body[:200])
    assert b"not for the browser" not in body and b"def " not in body and b"root:" not in body


def test_default_bind_is_loopback_only(app):
    assert app.url.startswith("http://127.0.0.1:")
    # the listening socket in /proc/net/tcp: local address 0100007F (127.0.0.1), not 00000000 (all)
    port = f"{app.port:04X}"
    listening = [line.split()[1] for line in Path("/proc/net/tcp").read_text().splitlines()[1:]
                 if line.split()[1].endswith(":" + port) and line.split()[3] == "0A"]
    assert listening == [f"0100007F:{port}"]


def test_a_second_browser_cannot_move_the_robot_but_can_stop_it(app):
    import websockets.sync.client as wsc

    # browser A connects its event stream and takes control
    with wsc.connect(f"ws://127.0.0.1:{app.port}/ws/events?client=a&token={app.token}",
                     origin=f"http://127.0.0.1:{app.port}"):
        status, _, body = request(app, "POST", "/api/control/claim", headers=auth(app, "a"))
        assert status == 200 and json.loads(body)["you"] is True
        # browser B: read-only for everything that changes the cell or moves the robot
        for path, payload in (("/api/capture/start", {"confirm": True, "mode": "plan"}),
                              ("/api/plan", {"kind": "handeye", "stations": 4}),
                              ("/api/cameras/cam0/settings", {"settings": {"ExposureTime": 1000}}),
                              ("/api/control/claim", None), ("/api/calibrate", {})):
            status, _, body = request(app, "POST", path, headers=auth(app, "b"), body=payload)
            assert status == 403, (path, status, body)
            assert b"another browser controls the cell" in body
        status, _, body = request(app, "PUT", "/api/cell", headers=auth(app, "b"), body={"text": CELL})
        assert status == 403
        # STOP works for every browser
        status, _, body = request(app, "POST", "/api/stop", headers=auth(app, "b"))
        assert status == 200 and b"STOP" in body
        # A may: a capture without a plan is refused for that reason, not for control
        status, _, body = request(app, "POST", "/api/capture/start", headers=auth(app, "a"),
                                  body={"confirm": True, "mode": "plan"})
        assert status == 400 and b"plan stations first" in body
        status, _, body = request(app, "POST", "/api/capture/start", headers=auth(app, "a"),
                                  body={"confirm": False, "mode": "plan"})
        assert status == 400 and b"confirmation" in body
        request(app, "POST", "/api/control/release", headers=auth(app, "a"))


def test_the_control_lease_passes_only_when_its_holder_releases_or_leaves():
    import time

    from jcalib.ui.security import ControlLease

    lease = ControlLease(timeout_s=0.3)
    assert lease.acquire("a") and lease.holds("a")
    lease.connected("a")
    assert not lease.acquire("b") and not lease.holds("b")
    time.sleep(0.4)
    assert not lease.acquire("b")  # a is still connected
    assert lease.status("a") == {"holder": "a", "you": True, "clients": 1}
    lease.disconnected("a")
    assert not lease.acquire("b")  # gone for less than the timeout
    time.sleep(0.4)
    assert lease.acquire("b") and lease.status("b")["you"] and not lease.status("a")["you"]
    lease.release("a")  # not the holder: no effect
    assert lease.holds("b")
    lease.release("b")
    assert lease.acquire("a")
    assert not lease.holds(None) and not lease.holds("")
