"""Session → observations: detections checked against OpenCV projections of the ground truth; failures
(skipped station, target not found, missing image) are reported without stopping the batch."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import sys

import cv2
import numpy as np
import pytest

from jcalib.acquisition.layout import cell_layout
from jcalib.acquisition.planner import plan_cell
from jcalib.acquisition.robots.poses import invert
from jcalib.acquisition.session import SessionWriter, utc_now
from jcalib.acquisition.simcell import scene_from_layout
from jcalib.errors import BadInputError
from jcalib.session_detect import detect_session

CELL = {
    "schema": "jcalib.cell/1",
    "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}, "cam1": {"model": "opencv5", "mount": "base"}},
    "targets": {"board": {"type": "checkerboard", "cols": 8, "rows": 5, "square": 0.02, "mount": "base"}},
}


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    from jcalib.sim.scene import View, render_view

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
        live = dataclasses.replace(scene, views=[View(st.id, st.T_base_flange)])
        images = {}
        for cam in ("cam0", "cam1"):
            img = render_view(live, 0, cam, rng=k)
            if k == 1 and cam == "cam0":
                img = np.full_like(img, 128)  # nothing to find
            images[cam] = w.write_image(cam, st.id, img)
        w.append_station({"id": st.id, "T_base_flange": st.T_base_flange.tolist(), "joints_deg": [0.0] * 6,
                          "time": utc_now(), "images": images, "status": "ok"})  # fmt: skip
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
    from jcalib.cli import main

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
