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
