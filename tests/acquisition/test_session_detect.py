"""Session → observations: detections (board corners, tool tips) checked against OpenCV projections of the
ground truth; failures (skipped station, target not found, missing image, no tool tip) are reported without
stopping the batch."""

from __future__ import annotations

import contextlib
import io
import json
import sys

import cv2
import numpy as np
import pytest

from jcalib.planning.layout import cell_layout
from jcalib.planning.stations import plan_cell
from jcalib.geometry.se3 import invert
from jcalib.io.session import SessionWriter, utc_now
from jcalib.app.simcell import scene_from_layout
from jcalib.errors import BadInputError
from jcalib.pipeline.session import detect_session

CELL = {
    "schema": "jcalib.cell/1",
    "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}, "cam1": {"model": "opencv5", "mount": "base"}},
    "targets": {"board": {"type": "checkerboard", "cols": 8, "rows": 5, "square": 0.02, "mount": "base"}},
}


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    layout = cell_layout(CELL, image_size=(320, 240))
    plan = plan_cell(layout, "viewsets", num_stations=4).plan
    scene = scene_from_layout(layout)
    d = tmp_path_factory.mktemp("sess") / "session"
    w = SessionWriter.create(d, cell=CELL)
    for k, st in enumerate(plan.stations):
        if k == 2:
            w.append_station({"id": st.id, "T_base_flange": None, "joints_deg": None, "time": utc_now(), "images": {},
                              "status": "skipped: unreachable: test"})  # fmt: skip
            continue
        images = {}
        for cam in ("cam0", "cam1"):
            img = scene.render(cam, st.T_base_flange, rng=k)
            if k == 1 and cam == "cam0":
                img = np.full_like(img, 128)  # nothing to find
            images[cam] = w.write_image(cam, st.id, img)
        lens = {"lens": {"cam0": {"Zoom": 350.0}}} if k == 0 else {}  # a zoom setting read back at capture
        w.append_station({"id": st.id, "T_base_flange": st.T_base_flange.tolist(), "joints_deg": [0.0] * 6,
                          "time": utc_now(), "images": images, "status": "ok", **lens})  # fmt: skip
    w.close()
    (d / "images" / "cam1" / f"{plan.stations[3].id}.png").unlink()  # lost after the capture
    return d, layout, plan


def test_detections_match_the_ground_truth_and_failures_are_listed(session):
    d, layout, plan = session
    obs, failures = detect_session(d, progress=False)  # cell from session.json
    ids = [s.id for s in plan.stations]
    got = {(f.station, f.camera, f.reason) for f in failures}
    assert got == {(ids[1], "cam0", "not_found"), (ids[2], None, "skipped"), (ids[3], "cam1", "missing_image")}
    assert [s.id for s in obs.stations] == [ids[0], ids[1], ids[3]]
    assert [s.lens for s in obs.stations] == [{"cam0": {"Zoom": 350.0}}, {}, {}]  # carried into the observations
    assert obs.cameras == {"cam0": (320, 240), "cam1": (320, 240)}
    assert [sorted(det.camera for det in s.detections) for s in obs.stations] == [["cam0", "cam1"], ["cam1"], ["cam0"]]
    t = layout.targets["board"]
    for s in obs.stations:
        np.testing.assert_array_equal(s.T_base_flange, plan.stations[ids.index(s.id)].T_base_flange)
        for det in s.detections:
            cam = layout.cameras[det.camera]
            T_base_cam = s.T_base_flange @ cam.pose if cam.mount == "flange" else cam.pose
            T = invert(T_base_cam) @ t.pose
            rvec, _ = cv2.Rodrigues(T[:3, :3])
            ref, _ = cv2.projectPoints(t.geometry.points[det.point_index], rvec, T[:3, 3], cam.K, cam.dist)
            assert det.point_index.size == 40
            # rendered noisy 320x240 images: sub-pixel corners
            assert np.max(np.linalg.norm(det.pixels - ref.reshape(-1, 2), axis=1)) < 0.5


def _cli(*args):
    from jcalib.app.cli import main

    err = io.StringIO()
    old, sys.argv = sys.argv, ["jcalib", *args]
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            main()
        return 0, err.getvalue()
    except SystemExit as e:
        return int(e.code or 0), err.getvalue()
    finally:
        sys.argv = old


def test_cli_detect_session_and_bad_input(session, tmp_path):
    d, _, plan = session
    code, text = _cli("detect", "--session", str(d), "-o", str(tmp_path / "obs.json"))
    assert code == 0, text
    obs = json.loads((tmp_path / "obs.json").read_text())
    assert obs["schema"] == "jcalib.observations/1" and len(obs["stations"]) == 3
    assert "not_found" in text and "missing_image" in text and "skipped" in text
    code, text = _cli("detect")
    assert code == 2 and "--session" in text
    code, text = _cli("detect", "--session", str(tmp_path))
    assert code == 2 and "no session.json" in text
    bare = tmp_path / "bare"
    SessionWriter.create(bare).close()
    with pytest.raises(BadInputError, match="no cell spec"):
        detect_session(bare, progress=False)
    with pytest.raises(BadInputError, match="no target 'plate'"):
        detect_session(d, CELL, target="plate", progress=False)


TOOL_CELL = {**CELL, "tools": {"needle": {"observed_by": ["cam1"]}}}


@pytest.fixture(scope="module")
def tool_session(tmp_path_factory):
    """3 board stations then 4 tool stations (the tcp planner), rendered by the simulated cell: cam1
    shows the tool's silhouette while the tip is in its tool zone. One tool image is lost to a flat frame."""
    layout = cell_layout(TOOL_CELL, image_size=(320, 240))
    board = plan_cell(layout, "viewsets", num_stations=3).plan.stations
    tool = plan_cell(layout, "tcp", num_stations=4).plan.stations
    scene = scene_from_layout(layout)
    d = tmp_path_factory.mktemp("tool") / "session"
    w = SessionWriter.create(d, cell=TOOL_CELL)
    stations = [(f"b{k}", st.T_base_flange) for k, st in enumerate(board)]
    stations += [(f"t{k}", st.T_base_flange) for k, st in enumerate(tool)]
    for k, (sid, T) in enumerate(stations):
        images = {}
        for cam in ("cam0", "cam1"):
            img = scene.render(cam, T, rng=k)
            if sid == "t3" and cam == "cam1":
                img = np.full_like(img, 200)  # the backlight alone: no tool in view
            images[cam] = w.write_image(cam, sid, img)
        w.append_station({"id": sid, "T_base_flange": T.tolist(), "joints_deg": [0.0] * 6, "time": utc_now(),
                          "images": images, "status": "ok"})  # fmt: skip
    w.close()
    return d, layout, dict(stations)


def test_tool_tips_are_detected_where_the_board_is_not(tool_session):
    d, layout, poses = tool_session
    obs, failures = detect_session(d, progress=False)
    by_id = {s.id: s for s in obs.stations}
    cam = layout.cameras["cam1"]
    T_flange_tool = layout.tools["needle"]
    for sid in ("t0", "t1", "t2"):
        dets = by_id[sid].detections
        tips = [det for det in dets if det.camera == "cam1"]
        assert len(tips) == 1 and tips[0].tool == "needle" and tips[0].target is None, (sid, dets)
        p_cam = invert(cam.pose) @ poses[sid] @ T_flange_tool[:, 3]
        ref, _ = cv2.projectPoints(p_cam[None, :3], np.zeros(3), np.zeros(3), cam.K, cam.dist)
        # rendered noisy 320x240 silhouette, ~11 px wide shaft: a sub-pixel tip (measured 0.06-0.3 px)
        assert np.linalg.norm(tips[0].pixels.reshape(2) - ref.ravel()) < 0.5, sid
    for sid in ("b0", "b1", "b2"):  # board stations: corners only, no tool search
        assert {(det.camera, det.target, det.tool) for det in by_id[sid].detections} == {
            ("cam0", "board", None), ("cam1", "board", None)}, sid
    cam1_failures = {(f.station, f.target, f.reason) for f in failures if f.camera == "cam1"}
    # a tool image found needs no board: the only cam1 failures are those of the flat frame
    assert cam1_failures == {("t3", "board", "not_found"), ("t3", "needle", "not_found")}
    assert obs.cameras["cam1"] == (320, 240)
    # the observations file round-trips the tips ({"camera", "tool", "pixel"})
    from jcalib.io.observations import load_observations, save_observations

    save_observations(d.parent / "obs.json", obs)
    again = load_observations(d.parent / "obs.json")
    tip = next(det for s in again.stations if s.id == "t0" for det in s.detections if det.tool)
    np.testing.assert_array_equal(tip.pixels.reshape(2), next(
        det for det in by_id["t0"].detections if det.tool).pixels.reshape(2))


def test_tool_search_off_and_a_camera_observing_two_tools(tool_session):
    d, _, _ = tool_session
    obs, failures = detect_session(d, progress=False, tools=False)
    assert not any(det.tool for s in obs.stations for det in s.detections)
    assert ("t0", "cam1", "board", "not_found") in {(f.station, f.camera, f.target, f.reason) for f in failures}
    two = {**TOOL_CELL, "tools": {"needle": {"observed_by": ["cam1"]}, "torch": {"observed_by": ["cam1"]}}}
    obs, failures = detect_session(d, two, progress=False)
    assert not any(det.tool for s in obs.stations for det in s.detections)
    assert any(f.station == "t0" and f.reason == "ambiguous" and "tool=" in f.message for f in failures)
    obs, _ = detect_session(d, two, tool="torch", progress=False)
    assert {det.tool for s in obs.stations for det in s.detections if det.tool} == {"torch"}
    with pytest.raises(BadInputError, match="no tool 'drill'"):
        detect_session(d, two, tool="drill", progress=False)
