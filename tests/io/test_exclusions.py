"""Session exclusions (``exclusions.json``): the file's contract, and that ``jcalib.calibrate`` given a session's
observations honours it exactly as if the views had never been detected."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from jcalib.errors import BadInputError, InputWarning
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.io.exclusions import (Exclusions, apply_exclusions, load_exclusions, parse_exclusions, save_exclusions,
                                  session_of_observations)
from jcalib.io.observations import parse_observations
from jcalib.sim.scene import project_target

BOARD = Checkerboard(cols=9, rows=6, square=0.025)
CAMERA = camera_from_opencv(np.array([[900.0, 0, 640], [0, 900, 480], [0, 0, 1]]), np.array([-0.1, 0.02, 0, 0, 0]),
                            (1280, 960))
CELL = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5"}},
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025}}}


def observations(n: int = 14, seed: int = 3) -> dict:
    from jcalib.geometry.se3 import exp_so3, make_pose

    rng = np.random.default_rng(seed)
    stations = []
    for i in range(n):
        R = exp_so3(rng.uniform(-0.45, 0.45, 3))
        T = make_pose(R, np.array([-0.1 + rng.uniform(-0.05, 0.05), -0.06 + rng.uniform(-0.04, 0.04), 0.6]))
        pix, vis = project_target(CAMERA, T, BOARD.points)
        assert vis.all()
        pix = pix + 0.2 * rng.standard_normal(pix.shape)
        stations.append({"id": f"s{i:03d}", "detections": [
            {"camera": "cam0", "target": "board", "point_index": list(range(54)), "pixels": pix.tolist()}]})
    return {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": [1280, 960]}},
            "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}


def test_round_trip_and_edits(tmp_path):
    e = Exclusions().with_station("s003", True).with_view("s007", "cam_hand", True).with_view("s008", "c", True)
    e = e.with_view("s008", "c", False)
    save_exclusions(tmp_path, e)
    back = load_exclusions(tmp_path)
    assert back.stations == {"s003"} and back.views == {("s007", "cam_hand")}
    assert back.excludes("s003") and back.excludes("s003", "any") and back.excludes("s007", "cam_hand")
    assert not back.excludes("s007") and not back.excludes("s007", "cam_fixed")
    assert back.with_station("s007", False).views == frozenset()  # taking a station back takes its views back
    data = json.loads((tmp_path / "exclusions.json").read_text())
    assert data["schema"] == "jcalib.exclusions/1" and data["excluded"][0] == {"station": "s003"}
    assert load_exclusions(tmp_path / "nowhere") == Exclusions()


@pytest.mark.parametrize("data", [
    [], {"schema": "jcalib.exclusions/2", "excluded": []}, {"schema": "jcalib.exclusions/1", "excluded": {}},
    {"schema": "jcalib.exclusions/1", "excluded": [{"camera": "c"}]},
    {"schema": "jcalib.exclusions/1", "excluded": [{"station": ""}]},
    {"schema": "jcalib.exclusions/1", "excluded": [{"station": "s", "view": "c"}]},
    {"schema": "jcalib.exclusions/1", "excluded": [{"station": 3}]},
    {"schema": "jcalib.exclusions/1", "excluded": [], "extra": 1},
])
def test_bad_files_are_named(data):
    with pytest.raises(BadInputError, match="excl"):
        parse_exclusions(data, "excl.json")


def test_unreadable_file_is_a_clear_error(tmp_path):
    (tmp_path / "exclusions.json").write_bytes(b"\xff\xfe{")
    with pytest.raises(BadInputError, match="exclusions.json"):
        load_exclusions(tmp_path)


def test_apply_drops_views_and_stations():
    obs = parse_observations(observations(5))
    kept, left = apply_exclusions(obs, Exclusions(frozenset({"s001"}), frozenset({("s003", "cam0")})))
    assert [s.id for s in kept.stations] == ["s000", "s002", "s004"]  # s003 had only cam0
    assert left == ["s001", "s003/cam0"]
    same, none = apply_exclusions(obs, Exclusions())
    assert same is obs and none == []


def test_calibrate_honours_the_exclusions_of_a_session_folder(tmp_path):
    import jcalib

    data = observations()
    session = tmp_path / "session"
    session.mkdir()
    (session / "session.json").write_text("{}")
    path = session / "observations.json"
    path.write_text(json.dumps(data))
    assert session_of_observations(path) == session.resolve()
    assert session_of_observations(tmp_path / "observations.json") is None
    save_exclusions(session, Exclusions(frozenset({"s002", "s005"})))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        honoured = jcalib.calibrate(CELL, path)
    assert any(issubclass(w.category, InputWarning) and "s002, s005" in str(w.message) for w in caught)
    assert honoured.file.stats["excluded"] == ["s002", "s005"]
    reference = jcalib.calibrate(CELL, {**data, "stations": [s for s in data["stations"]
                                                             if s["id"] not in ("s002", "s005")]})
    a, b = honoured.file.cameras["cam0"], reference.file.cameras["cam0"]
    for p in ("fx", "fy", "cx", "cy", "k1"):
        assert abs(a.params[a.param_names.index(p)] - b.params[b.param_names.index(p)]) <= 1e-6 * b.std[p], p
    everything = jcalib.calibrate(CELL, data)  # the same file outside a session: nothing left out
    assert "excluded" not in everything.file.stats
    c = everything.file.cameras["cam0"]
    assert abs(c.params[0] - b.params[0]) > 1e-6 * b.std["fx"]  # the exclusion made a difference
