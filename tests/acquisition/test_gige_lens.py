"""The fake GigE camera's motorised lens: ``Zoom`` and ``Focus`` features a GigE client sets and reads back,
whose values reach the frame source with every frame."""

from __future__ import annotations

import numpy as np
import pytest

from jcalib.acquisition.cameras import FakeGigECamera, GigECamera
from jcalib.acquisition.cameras.fake_gige import LENS_FEATURES, lens_genicam_xml
from jcalib.acquisition.capture import check_lens_settings, set_lens
from jcalib.errors import BadInputError
from jcalib.io.plan import make_plan, with_lens_settings


def test_lens_xml_adds_the_features_once():
    base = '<RegisterDescription>\n<Category Name="Root" NameSpace="Standard">\n</Category>\n</RegisterDescription>'
    xml = lens_genicam_xml(base)
    for name, (reg, _, _) in LENS_FEATURES.items():
        assert xml.count(f'<Integer Name="{name}"') == 1 and f"<Address>{reg:#x}</Address>" in xml
    assert xml.count("<pFeature>LensControl</pFeature>") == 1


def test_zoom_and_focus_are_set_read_back_and_rendered(aravis):
    seen = []
    image = np.full((48, 64), 90, np.uint8)

    def source(req):
        seen.append(dict(req.lens))
        return image

    with FakeGigECamera(source, "127.0.0.1", sensor_size=(64, 48), lens_features=True):
        cam = GigECamera("127.0.0.1", name="cam0")
        try:
            assert cam.has("Zoom") and cam.has("Focus")
            assert cam.get("Zoom") == LENS_FEATURES["Zoom"][1]
            cam.set("Zoom", 350)
            cam.set("Focus", 620)
            assert (cam.get("Zoom"), cam.get("Focus")) == (350, 620)
            seen.clear()
            assert np.array_equal(cam.grab().image, image)
            # what capture does at a station that sets the lens: set, read back, record
            plan = with_lens_settings(make_plan([np.eye(4)]), ["cam0.Zoom=640"])
            check_lens_settings(plan, {"cam0": cam})
            assert set_lens({"cam0": cam}, plan.stations[0].lens) == {"cam0": {"Zoom": 640.0}}
            with pytest.raises(BadInputError, match="cam1"):
                check_lens_settings(with_lens_settings(plan, ["cam1.Zoom=1"]), {"cam0": cam})
            with pytest.raises(BadInputError, match="Iris"):
                check_lens_settings(with_lens_settings(make_plan([np.eye(4)]), ["cam0.Iris=1"]), {"cam0": cam})
        finally:
            cam.close()
    assert {"Zoom": 350.0, "Focus": 620.0} in seen


def test_simulate_serves_a_zoom_camera_and_writes_its_functions(aravis, tmp_path):
    """``jcalib simulate`` with a cell camera that has ``lens:``: its fake GigE camera has Zoom, renders through
    the simulated lens at the value set (another image), and the truth file holds the lens's functions."""
    import json
    import threading
    import time

    from jcalib.app.simulate import run_simulate
    from jcalib.sim.zoom import ZoomLensModel

    cell = {"schema": "jcalib.cell/1", "robot": {"model": "kuka_kr10_r1100_sixx"},
            "cameras": {"cam0": {"model": "opencv5", "mount": "flange", "lens": {"settings": ["Zoom"]}}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025, "mount": "base"}}}
    (tmp_path / "cell.json").write_text(json.dumps(cell))
    stop, info = threading.Event(), {}
    worker = threading.Thread(target=run_simulate, args=(tmp_path / "cell.json",), daemon=True, kwargs=dict(
        robot_protocol="kuka", robot_port=0, camera_addresses={"cam0": "127.0.0.1"}, truth=tmp_path / "truth.json",
        stop=stop, on_ready=info.update, time_scale=0.0))
    worker.start()
    deadline = time.monotonic() + 120
    while not info and worker.is_alive() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert info, "the simulator did not start"
    try:
        cam = GigECamera("127.0.0.1", name="cam0")
        try:
            wide = cam.grab().image
            cam.set("Zoom", 900)
            assert cam.get("Zoom") == 900
            assert not np.array_equal(cam.grab().image, wide)
        finally:
            cam.close()
    finally:
        stop.set()
        worker.join(30)
    truth = json.loads((tmp_path / "truth.json").read_text())["lenses"]["cam0"]
    lens = ZoomLensModel(f_wide_px=0.8 * truth["image_size"][0], image_size=tuple(truth["image_size"]))
    k = truth["settings"].index(500.0)
    np.testing.assert_allclose(truth["params"][k], lens.params(500.0), rtol=1e-12)
    assert truth["shift_m"][-1] == lens.shift_m(1000.0)
