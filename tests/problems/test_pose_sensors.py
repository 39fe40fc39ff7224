"""Pose sensors are first-class (issue 33): ``sensors: {tracker: {kind: pose, mount: base}}`` and stations'
``poses: [{sensor, target, T_sensor_target}]``, with no lens model and no image size.

A 2-axis positioner with hidden DH errors, measured by a fixed laser tracker (6-DOF), written with
``sensors:``: the calibrated DH parameters lie within their σ of the simulation's truth (χ² over the free
parameters); the same data written in the camera form (a ``pinhole`` camera with an image size and
``T_cam_target``) give the same numbers.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import jcalib
from jcalib.errors import BadInputError
from jcalib.io.cell import cell_to_dict, parse_cell
from jcalib.io.observations import parse_observations
from jcalib.sim.kinematic_cells import synthetic_positioner_cell

SEED, STATIONS = 4, 16


def _solve(form: str):
    cell, obs, truth = synthetic_positioner_cell(SEED, num_stations=STATIONS, num_heldout=2, form=form)
    return cell, obs, truth, jcalib.calibrate(cell, obs, {"prediction": False}).file


@pytest.fixture(scope="module")
def both():
    return _solve("sensor"), _solve("camera")


def test_sensor_cell_needs_no_lens_and_no_image_size(both):
    (cell, obs, _, _), _ = both
    assert "cameras" not in cell and "cameras" not in obs
    assert set(cell["sensors"]["tracker"]) == {"kind", "mount"}
    assert set(obs["stations"][0]["poses"][0]) == {"sensor", "target", "T_sensor_target"}


def test_laser_tracker_positioner_recovers_its_dh_parameters_within_sigma(both):
    (_, _, truth, res), _ = both
    k = res.kinematics["robot"]
    free = [list(k.names).index(n) for n in k.calibrated]
    assert len(free) >= 2
    e = (np.asarray(k.values) - truth["params"])[free]
    chi2 = float(e @ np.linalg.solve(np.asarray(k.covariance), e))
    assert chi2 < stats.chi2.ppf(0.999, len(free)), (k.calibrated, e)
    # the errors were real: the nominal model is off by many σ
    d = (truth["params"] - truth["nominal"])[free]
    assert float(d @ np.linalg.solve(np.asarray(k.covariance), d)) > 100.0
    assert "T_base_tracker" in res.transforms and not res.cameras  # a sensor has no intrinsics


def test_camera_form_gives_the_same_numbers(both):
    (_, _, _, a), (_, _, _, b) = both
    ka, kb = a.kinematics["robot"], b.kinematics["robot"]
    np.testing.assert_allclose(ka.values, kb.values, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ka.covariance, kb.covariance, rtol=1e-9, atol=0)
    for n in ("T_base_tracker", "T_flange_part"):
        np.testing.assert_allclose(a.transforms[n].matrix, b.transforms[n].matrix, rtol=0, atol=1e-12)


def test_sensor_cell_and_measurements_round_trip():
    cell, obs, _ = synthetic_positioner_cell(0, num_stations=3, num_heldout=0, form="sensor")
    spec = parse_cell(cell)
    assert spec.sensors["tracker"].mount == "base" and not spec.cameras
    assert parse_cell(cell_to_dict(spec)).sensors == spec.sensors
    o = parse_observations(obs)
    assert o.stations[0].poses[0].sensor_form
    assert o.to_dict()["stations"][0]["poses"] == obs["stations"][0]["poses"]


@pytest.mark.parametrize("edit, match", [
    (lambda c, o: o["stations"][0]["poses"][0].pop("T_sensor_target"), "T_sensor_target"),
    (lambda c, o: o["stations"][0]["poses"][0].update(camera="tracker"), "one of the two forms"),
    (lambda c, o: o["stations"][0]["poses"][0].update(sensor="trackr"), "did you mean 'tracker'"),
    (lambda c, o: c["sensors"]["tracker"].update(model="pinhole"), "model"),
    (lambda c, o: c["sensors"]["tracker"].update(kind="camera"), "kind"),
    (lambda c, o: o.update(cameras={"tracker": {"image_size": [64, 48]}}) or o["stations"][0].update(
        detections=[{"camera": "tracker", "target": "part", "point_index": [0], "pixels": [[1.0, 2.0]]}]),
     "pose sensor"),
])
def test_bad_sensor_input_is_refused_by_name(edit, match):
    cell, obs, _ = synthetic_positioner_cell(0, num_stations=3, num_heldout=0, form="sensor")
    edit(cell, obs)
    with pytest.raises(BadInputError, match=match):
        jcalib.calibrate(cell, obs)


def test_sensor_mounts_follow_the_rules_of_cameras():
    """``mount: world`` and ``robot:`` with several robots, ``fixed`` names a sensor and its transform, a fixed
    sensor's ``pose`` is read; wrong mounts are refused by name."""
    eye = np.eye(4).tolist()
    two = {"schema": "jcalib.cell/1", "robots": {"r1": {}, "r2": {}},
           "sensors": {"t1": {"kind": "pose", "mount": "world", "pose": eye}, "t2": {"kind": "pose", "mount": "flange",
                                                                                     "robot": "r2"}},
           "targets": {"m": {"type": "points", "mount": "flange", "robot": "r1"}}, "fixed": ["t1", "T_world_t1"]}
    spec = parse_cell(two)
    assert spec.sensors["t2"].robot == "r2" and np.array_equal(spec.sensors["t1"].pose, np.eye(4))
    for edit, match in ((lambda c: c["sensors"]["t1"].update(mount="base"), "ambiguous"),
                        (lambda c: c["sensors"]["t2"].pop("robot"), "robot"),
                        (lambda c: c["sensors"]["t1"].update(mount="free"), "mount"),
                        (lambda c: c["sensors"].update(m={"kind": "pose"}), "name")):
        bad = {**two, "sensors": {k: dict(v) for k, v in two["sensors"].items()}}
        edit(bad)
        with pytest.raises(BadInputError, match=match):
            parse_cell(bad)


def _point_sensor_cell(num: int = 16, noise_m: float = 2e-5, seed: int = 1):
    """A fixed laser tracker (kind: point) measuring a reflector on the flange (a tool): cell, observations, truth."""
    from jcalib.geometry.se3 import exp_so3, invert, make_pose

    rng = np.random.default_rng(seed)
    T_base_tracker = make_pose(exp_so3(np.array([0.3, -1.2, 0.5])), np.array([2.0, 0.5, 1.0]))
    p_flange_smr = np.array([0.01, -0.03, 0.12])
    stations = []
    for i in range(num):
        F = make_pose(exp_so3(rng.normal(0, 0.6, 3)), rng.normal([0.6, 0.0, 0.5], 0.2))
        p = (invert(T_base_tracker) @ F @ np.r_[p_flange_smr, 1.0])[:3] + noise_m * rng.normal(size=3)
        stations.append({"id": f"s{i:02d}", "T_base_flange": F.tolist(),
                         "positions": [{"sensor": "tracker", "tool": "smr", "p_sensor_tool": p.tolist()}]})
    cell = {"schema": "jcalib.cell/1", "sensors": {"tracker": {"kind": "point", "mount": "base"}},
            "tools": {"smr": {}}, "robot": {}}
    return cell, {"schema": "jcalib.observations/1", "stations": stations}, (T_base_tracker, p_flange_smr)


def test_point_sensor_closed_form_is_exact_on_noiseless_data():
    from jcalib.init.point_sensor import point_sensor_start

    _, obs, (T, p) = _point_sensor_cell(noise_m=0.0)
    F = np.array([s["T_base_flange"] for s in obs["stations"]])
    P = np.array([s["positions"][0]["p_sensor_tool"] for s in obs["stations"]])
    T_est, p_est = point_sensor_start(F, P)
    np.testing.assert_allclose(T_est, T, atol=1e-9)  # float64 identities on exact data
    np.testing.assert_allclose(p_est, p, atol=1e-9)
    with pytest.raises(jcalib.errors.NotObservableError, match="13"):
        point_sensor_start(F[:8], P[:8])
    with pytest.raises(jcalib.errors.NotObservableError, match="rotate"):
        point_sensor_start(np.broadcast_to(F[0], F.shape), P)


def test_point_sensor_calibrates_the_tracker_and_the_reflector_within_sigma():
    """A laser tracker measuring a reflector's position (3-D) at 16 stations, 20 µm per axis: the tracker's pose
    (6 DOF) and the reflector's position on the flange lie within their σ of the truth (χ²)."""
    from jcalib.geometry.se3 import invert, log_so3

    cell, obs, (T_true, p_true) = _point_sensor_cell()
    res = jcalib.calibrate(cell, obs, {"pose_sigma_m": 2e-5}).file
    tr = res.transforms["T_base_tracker"]
    D = invert(np.asarray(tr.matrix)) @ T_true
    e = np.r_[log_so3(D[:3, :3]), D[:3, 3]]
    assert float(e @ np.linalg.solve(np.asarray(tr.covariance), e)) < stats.chi2.ppf(0.999, 6), e
    tip = res.transforms["T_flange_smr"]
    assert tip.extra["calibrated"] == ["tx", "ty", "tz"]
    e = np.asarray(tip.matrix)[:3, 3] - p_true
    assert float(e @ np.linalg.solve(np.asarray(tip.covariance)[3:, 3:], e)) < stats.chi2.ppf(0.999, 3), e
    assert res.stats["position_rms_m"] < 1e-4 and not res.cameras


@pytest.mark.parametrize("edit, match", [
    (lambda c, o: o["stations"][0]["positions"][0].update(sensor="trackr"), "point sensor 'trackr'"),
    (lambda c, o: o["stations"][0]["positions"][0].update(tool="sm"), "tool 'sm'"),
    (lambda c, o: c["sensors"]["tracker"].update(kind="pose"), "point sensor 'tracker'"),
    (lambda c, o: o["stations"][0].update(poses=[{"sensor": "tracker", "target": "marker", "T_sensor_target":
                                                   np.eye(4).tolist()}]), "kind point"),
    (lambda c, o: o["stations"][0]["positions"][0].update(p_sensor_tool=[1200.0, 0.0, 0.0]), "millimetres"),
])
def test_bad_point_sensor_input_is_refused_by_name(edit, match):
    cell, obs, _ = _point_sensor_cell(num=3)
    cell["targets"] = {"marker": {"type": "points", "mount": "flange"}}
    edit(cell, obs)
    with pytest.raises(BadInputError, match=match):
        jcalib.calibrate(cell, obs)
