"""``jcalib capture --kind tcp``: the TCP thesis' visual servo at every station of a tcp plan, end to end on
the simulator (KUKAVARPROXY + a fake GigE camera showing the tool's silhouette), through run_capture."""

from __future__ import annotations

import json
import socket
import threading

import numpy as np
import pytest

from jcalib.app.simulate import run_simulate
from jcalib.workflow.capture import run_capture
from jcalib.workflow.plan import run_plan
from jcalib.io.session import read_session

CELL = """schema: jcalib.cell/1
robot: {model: kuka_kr10_r1100_sixx}
cameras:
  cam_fixed:
    model: opencv5
    mount: base
    intrinsics: {K: [[720.0, 0.0, 319.5], [0.0, 720.0, 239.5], [0.0, 0.0, 1.0]], dist: [-0.1, 0.05, 0.0, 0.0, 0.0]}
    settings: {ExposureTime: 12000}
targets:
  board: {type: checkerboard, cols: 8, rows: 6, square: 0.025, mount: base}
tools:
  torch: {observed_by: [cam_fixed]}
"""


def test_capture_kind_tcp_servoes_the_tip_onto_the_image_centre(aravis, tmp_path):
    from jcalib.planning.layout import cell_layout
    from jcalib.vision.tooltip import detect_tool_tip

    import cv2

    (tmp_path / "cell.yaml").write_text(CELL)
    planned = run_plan(tmp_path / "cell.yaml", "tcp", tmp_path / "plan.json", num_stations=4, image_size=(640, 480))
    assert planned.tool == "torch"
    # the real TCP is not the nominal one the plan assumed: shift every planned flange pose by a few mm,
    # so the tip starts 10-30 px off the centre and the servo has to bring it there
    data = json.loads((tmp_path / "plan.json").read_text())
    rng = np.random.default_rng(1)
    for st in data["stations"]:
        st["T_base_flange"][0][3] += float(rng.uniform(-0.006, 0.006))
        st["T_base_flange"][2][3] += float(rng.uniform(-0.006, 0.006))
    (tmp_path / "plan.json").write_text(json.dumps(data))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    stop, info = threading.Event(), {}
    ready = threading.Event()

    def on_ready(i):
        info.update(i)
        ready.set()

    sim = threading.Thread(target=run_simulate, args=(tmp_path / "cell.yaml",), daemon=True, kwargs=dict(
        robot_protocol="kuka", robot_port=port, camera_addresses={"cam_fixed": "127.0.0.1"}, image_size=(640, 480),
        time_scale=0.0, seed=3, stop=stop, on_ready=on_ready))  # fmt: skip
    sim.start()
    try:
        assert ready.wait(120)
        res = run_capture(robot_url=info["robot"], camera_urls={"cam_fixed": "gige://127.0.0.1"},
                          plan_path=tmp_path / "plan.json", out=tmp_path / "session", cell=tmp_path / "cell.yaml",
                          progress=False, packet_size=1400, kind="tcp")  # fmt: skip
    finally:
        stop.set()
        sim.join(30)
    assert res.skipped == {} and len(res.captured) == len(planned.plan)
    meta, stations = read_session(tmp_path / "session")
    assert meta["devices"]["cameras"]["cam_fixed"]["settings"]["ExposureTime"] == pytest.approx(12000)
    layout = cell_layout(tmp_path / "cell.yaml", image_size=(640, 480))  # the simulator's ground truth
    T_base_cam, T_flange_tcp = layout.cameras["cam_fixed"].pose, layout.tools["torch"]
    K, dist = layout.cameras["cam_fixed"].K, layout.cameras["cam_fixed"].dist
    centre = np.array([319.5, 239.5])
    moved = 0
    for st in stations:
        servo = st["servo"]
        assert st["status"] == "ok" and servo["converged"] and servo["error_px"] < 0.5 and servo["iterations"] >= 1
        T = np.array(st["T_base_flange"])
        moved += np.linalg.norm(T[:3, 3] - np.array(st["T_base_flange_commanded"])[:3, 3]) > 1e-4
        tip_cam = (np.linalg.inv(T_base_cam) @ T @ T_flange_tcp)[:3, 3]
        px, _ = cv2.projectPoints(tip_cam[None], np.zeros(3), np.zeros(3), K, dist)
        assert np.linalg.norm(px.ravel() - centre) < 1.0  # truth: the tip sits on the centre (tolerance + noise)
        img = cv2.imread(str(tmp_path / "session" / st["images"]["cam_fixed"]), cv2.IMREAD_UNCHANGED)
        assert np.linalg.norm(detect_tool_tip(img).pixel - centre) < 1.5
    assert moved == len(stations)  # the servo corrected every planned pose
