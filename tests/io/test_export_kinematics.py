"""Export of calibrated robot kinematics: the cell-spec YAML (read back by ``from_spec``), the URDF (its
FK computed independently from the parsed XML), the refusals, and ``jcalib export -f kinematics/urdf``."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import jax.numpy as jnp
import numpy as np
import pytest
import yaml

from jcalib.errors import BadInputError
from jcalib.geometry import kinematic_models as km
from jcalib.geometry import kinematic_tables as kt
from jcalib.io.export import export_result, kinematics_urdf, kinematics_yaml
from jcalib.io.export.kinematics import CONTROLLER_OFFSET_CONVENTION, rpy_from_matrix
from jcalib.io.result import CameraResult, KinematicsResult, ResultFile, load_result

#: FK identities in float64 through a few 4x4 products and a deg <-> rad round trip: 1e-9 (m, unitless).
FK_TOL = 1e-9

TRACK_TABLE = {  # a prismatic axis moving by -q, then a revolute one turning by -q: joint signs in the URDF
    "convention": "dh",
    "joints": [
        {"name": "travel", "type": "prismatic", "a_m": 0.05, "alpha_deg": -90.0, "d_m": 0.2, "theta_deg": 90.0,
         "sign": -1, "limits_mm": [-500.0, 2500.0]},
        {"name": "A1", "a_m": 0.3, "alpha_deg": 90.0, "d_m": 0.4, "theta_deg": 10.0, "sign": -1,
         "limits_deg": [-170.0, 170.0]},
        {"name": "A2", "a_m": 0.7, "alpha_deg": 0.0, "d_m": 0.0, "theta_deg": -90.0, "limits_deg": [-90.0, 150.0]},
    ],
    "base": [[1.0, 0.0, 0.0, 0.1], [0.0, 1.0, 0.0, -0.2], [0.0, 0.0, 1.0, 0.3], [0.0, 0.0, 0.0, 1.0]],
}


def _model(case: str) -> km.Kinematics:
    if case == "track":
        return kt.from_spec(TRACK_TABLE, "cell7")
    kuka = km.PRESETS["kuka_kr10_r1100_sixx"]()
    return kuka if case == "dh" else km.convert(kuka, case)


def _entry(model: km.Kinematics, seed: int = 0, spec: bool = False) -> tuple[KinematicsResult, np.ndarray]:
    """A result entry with every per-joint parameter and the base/flange perturbed, half of them calibrated."""
    rng = np.random.default_rng(seed)
    params = np.asarray(model.nominal) + 2e-3 * rng.normal(size=model.num_params)
    names = list(model.param_names)
    calibrated = names[1::2]
    std = 1e-4 * (1.0 + np.arange(len(calibrated)))
    held = {n: f"not separable from something ({i})" for i, n in enumerate(names[0::2])}
    extra = {"held": held, "repeatability": "pose_noise",
             "controller_offsets": km.controller_offsets(model, params), "table": kt.table(model, params),
             "correction_rms_translation_m": [1e-5, 2e-5, 3e-5], "correction_rms_rotation_deg": [1e-3, 2e-3, 3e-3]}
    if spec:
        extra["spec"] = kt.to_spec(model, params)
    entry = KinematicsResult(model.convention, tuple(names), params, np.asarray(model.nominal), tuple(calibrated),
                             np.diag(std**2), extra)
    return entry, params


def _file(**entries: KinematicsResult) -> ResultFile:
    return ResultFile(kinematics=entries, stats={"num_residuals": 10})


def _joint_values(model: km.Kinematics, rng, num: int) -> np.ndarray:
    lo, hi = np.asarray(model.lower), np.asarray(model.upper)
    return rng.uniform(lo, hi, size=(num, model.num_joints))


# ---------------------------------------------------------------------------------------------- YAML


@pytest.mark.parametrize("case", ["dh", "mdh", "track"])
def test_yaml_table_reads_back_with_the_calibrated_fk(case):
    model = _model(case)
    entry, params = _entry(model)
    doc = yaml.safe_load(kinematics_yaml(_file(arm=entry)))
    assert doc["schema"] == "jcalib.kinematics/1"
    back = kt.from_spec(doc["robots"]["arm"]["kinematics"], "arm")
    q = _joint_values(model, np.random.default_rng(1), 50)
    want = np.asarray(km.forward(model, jnp.asarray(params), jnp.asarray(q)))
    got = np.asarray(km.forward(back, back.nominal, jnp.asarray(q)))
    assert np.max(np.abs(got - want)) < FK_TOL
    assert np.max(np.abs(want - np.asarray(km.forward(model, model.nominal, jnp.asarray(q))))) > 1e-3  # it moved


def test_yaml_sigma_held_and_controller_offsets():
    model = _model("dh")
    entry, params = _entry(model)
    text = kinematics_yaml(_file(arm=entry))
    robot = yaml.safe_load(text)["robots"]["arm"]
    assert list(robot["parameters"]) == list(entry.calibrated)
    for name, sigma in entry.std.items():
        row = robot["parameters"][name]
        i = entry.names.index(name)
        unit, scale = ("mm", 1e3) if name.rsplit(".", 1)[1] in ("a", "d", "tx", "ty", "tz") else ("deg", 180 / math.pi)
        assert row[f"std_{unit}"] == pytest.approx(sigma * scale, rel=1e-12)
        assert row[f"calibrated_{unit}"] == pytest.approx(params[i] * scale, rel=1e-12)
        change = (params[i] - float(model.nominal[i])) * scale
        assert row[f"change_{unit}"] == pytest.approx(change, rel=1e-9, abs=1e-12)
    assert robot["held"] == entry.extra["held"]
    offsets = km.controller_offsets(model, params)
    for joint, row in robot["controller_offsets"].items():
        assert row["offset_deg"] == pytest.approx(offsets[joint], rel=1e-12)
        name = f"{joint}.theta"
        if name in entry.calibrated:
            assert row["std_deg"] == pytest.approx(math.degrees(entry.std[name]), rel=1e-12)
        else:  # a held zero is said to be held, never exported as if it were calibrated
            assert row["held"] == entry.extra["held"][name]
    assert "reading q is the nominal arm at q + offset" in CONTROLLER_OFFSET_CONVENTION
    comment = " ".join(line.strip("# ") for line in text.splitlines() if line.lstrip().startswith("#"))
    assert "at the controller reading q is the nominal arm at q + offset" in comment
    assert "never both" in comment


def test_poe_needs_its_spec():
    model = _model("poe")
    entry, params = _entry(model, spec=True)
    back = kt.from_spec(yaml.safe_load(kinematics_yaml(_file(arm=entry)))["robots"]["arm"]["kinematics"], "arm")
    q = _joint_values(model, np.random.default_rng(2), 20)
    want = np.asarray(km.forward(model, jnp.asarray(params), jnp.asarray(q)))
    assert np.max(np.abs(np.asarray(km.forward(back, back.nominal, jnp.asarray(q))) - want)) < FK_TOL
    bare, _ = _entry(model)
    with pytest.raises(BadInputError, match="poe model.*'spec'"):
        kinematics_yaml(_file(arm=bare))


# ---------------------------------------------------------------------------------------------- URDF


def _rpy_matrix(rpy) -> np.ndarray:
    r, p, y = rpy
    Rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    Ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    Rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _axis_motion(kind: str, axis: np.ndarray, q: float) -> np.ndarray:
    T = np.eye(4)
    a = axis / np.linalg.norm(axis)
    if kind in ("revolute", "continuous"):
        W = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        T[:3, :3] = np.eye(3) + math.sin(q) * W + (1 - math.cos(q)) * W @ W
    elif kind == "prismatic":
        T[:3, 3] = a * q
    return T


def urdf_fk(text: str, values: dict[str, float], tip: str = "tool0", root: str = "base_link") -> np.ndarray:
    """``T_root_tip`` of a URDF at joint values by name, from the XML alone (URDF semantics)."""
    robot = ET.fromstring(text)
    by_child = {j.find("child").get("link"): j for j in robot.findall("joint")}
    chain, link = [], tip
    while link != root:
        joint = by_child[link]
        chain.append(joint)
        link = joint.find("parent").get("link")
    T = np.eye(4)
    for joint in reversed(chain):
        origin = joint.find("origin")
        O = np.eye(4)
        O[:3, :3] = _rpy_matrix([float(v) for v in origin.get("rpy").split()])
        O[:3, 3] = [float(v) for v in origin.get("xyz").split()]
        kind = joint.get("type")
        axis = joint.find("axis")
        a = np.array([float(v) for v in axis.get("xyz").split()]) if axis is not None else np.array([1.0, 0, 0])
        T = T @ O @ _axis_motion(kind, a, values.get(joint.get("name"), 0.0) if kind != "fixed" else 0.0)
    return T


@pytest.mark.parametrize("case", ["dh", "mdh", "track", "poe"])
def test_urdf_fk_matches_the_calibrated_model(case):
    model = _model(case)
    entry, params = _entry(model, seed=3, spec=case == "poe")
    text = kinematics_urdf(_file(arm=entry))
    robot = ET.fromstring(text)
    joints = {j.get("name"): j for j in robot.findall("joint")}
    for i, name in enumerate(model.joint_names):
        assert joints[name].get("type") == model.joint_types[i]
        assert joints[name].find("axis").get("xyz") == f"0 0 {int(model.joint_sign[i])}"
        limit = joints[name].find("limit")
        assert float(limit.get("lower")) == float(model.lower[i]) and float(limit.get("upper")) == float(model.upper[i])
    rng = np.random.default_rng(4)
    for q in _joint_values(model, rng, 25):
        want = np.asarray(km.forward(model, jnp.asarray(params), jnp.asarray(q)))
        values = dict(zip(model.joint_names, q.tolist()))
        assert np.max(np.abs(urdf_fk(text, values) - want)) < FK_TOL
        assert np.max(np.abs(urdf_fk(text, values, tip="flange") - want)) < FK_TOL


def test_rpy_is_exact_at_and_near_gimbal_lock():
    rng = np.random.default_rng(5)
    angles = [rng.uniform(-math.pi, math.pi, 3) for _ in range(50)]
    angles += [(r, s * (math.pi / 2 - e), y) for r, y in rng.uniform(-3, 3, (6, 2))
               for s in (1, -1) for e in (0.0, 1e-13, 1e-8, 1e-4)]
    for rpy in angles:
        R = _rpy_matrix(rpy)
        assert np.max(np.abs(_rpy_matrix(rpy_from_matrix(R)) - R)) < 1e-14


# ---------------------------------------------------------------------------------------------- refusals and CLI


def test_result_without_kinematics_is_refused(tmp_path):
    cam = CameraResult("pinhole", (640, 480), np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), np.zeros(0))
    path = tmp_path / "camera.json"
    ResultFile(cameras={"cam0": cam}).save(path)
    for fmt in ("kinematics", "urdf"):
        with pytest.raises(BadInputError, match="no 'kinematics' section: no robot kinematics was calibrated"):
            export_result(path, fmt, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    two = _file(r1=_entry(_model("dh"))[0], r2=_entry(_model("track"))[0])
    with pytest.raises(BadInputError, match="2 robots .*r1, r2.*name the one"):
        kinematics_urdf(two)
    with pytest.raises(BadInputError, match="no calibrated kinematics for 'r3'"):
        kinematics_yaml(two, "r3")
    assert set(yaml.safe_load(kinematics_yaml(two))["robots"]) == {"r1", "r2"}


def test_an_edited_table_is_refused():
    model = _model("dh")
    entry, _ = _entry(model)
    table = [dict(r) for r in entry.extra["table"]]
    table[0]["a_m"] += 1e-3
    edited = KinematicsResult(entry.convention, entry.names, entry.values, entry.nominal, entry.calibrated,
                              entry.covariance, {**entry.extra, "table": table})
    with pytest.raises(BadInputError, match=r"table's A1.a differs from the parameter value"):
        kinematics_urdf(_file(arm=edited))


def test_cli_export_kinematics_and_urdf(tmp_path, run_cli):
    model = _model("track")
    entry, params = _entry(model)
    path = tmp_path / "result.json"
    _file(cell7=entry).save(path)
    assert load_result(path).kinematics["cell7"].calibrated == entry.calibrated
    code, text = run_cli("export", path, "-f", "kinematics", "-o", tmp_path / "k.yaml")
    assert code == 0, text
    spec = yaml.safe_load((tmp_path / "k.yaml").read_text(encoding="utf-8"))["robots"]["cell7"]["kinematics"]
    back = kt.from_spec(spec, "cell7")
    q = _joint_values(model, np.random.default_rng(6), 10)
    want = np.asarray(km.forward(model, jnp.asarray(params), jnp.asarray(q)))
    assert np.max(np.abs(np.asarray(km.forward(back, back.nominal, jnp.asarray(q))) - want)) < FK_TOL
    code, text = run_cli("export", path, "-f", "urdf", "--robot", "cell7", "-o", tmp_path / "cell7.urdf")
    assert code == 0, text
    urdf = (tmp_path / "cell7.urdf").read_text(encoding="utf-8")
    assert np.max(np.abs(urdf_fk(urdf, dict(zip(model.joint_names, q[0].tolist()))) - want[0])) < FK_TOL
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell7.urdf", "k.yaml", "result.json"]  # atomic writes
    code, text = run_cli("export", path, "-f", "opencv", "--robot", "cell7", "-o", tmp_path / "x.yaml")
    assert code == 2 and "--robot applies to the kinematics, urdf and ur-calibration formats" in text
    empty = tmp_path / "empty.json"
    ResultFile(stats={"num_residuals": 1}).save(empty)
    code, text = run_cli("export", empty, "-f", "urdf", "-o", tmp_path / "y.urdf")
    assert code == 2 and "no 'kinematics' section" in text and "Traceback" not in text
    assert not (tmp_path / "y.urdf").exists()
