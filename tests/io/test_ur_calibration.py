"""Universal Robots' calibration file (delta DH): read as a robot's nominal kinematics (its FK checked against a
DH chain written out here from UR's published table), exported as ``ur-calibration`` and read back, refusals."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
import yaml

from jcalib.errors import BadInputError
from jcalib.geometry import kinematic_models as km
from jcalib.geometry import kinematic_tables as kt
from jcalib.io.cell import cell_to_dict, load_cell, parse_cell
from jcalib.io.export import export_result
from jcalib.io.export.formats import DEFAULT_FILE_NAMES, EXPORT_FORMATS, FORMAT_DESCRIPTIONS, export_options
from jcalib.io.result import KinematicsResult, ResultFile
from jcalib.io.ur_calibration import parse_ur_calibration, read_ur_calibration

#: FK through six 4x4 products with d of hundreds of metres that cancel: 1e-9 m is ~1e-11 relative.
FK_TOL = 1e-9
#: A calibration.conf as a UR5e controller writes it (numbers made up, with the large cancelling d of a real one).
CONF = """[mounting]
delta_theta = [ 3.1e-08, -0.21734, 6.47012, 0.0129, -7.1e-08, -6.2e-07]
delta_a = [ 0.000151, 0.0121, -7.7e-05, 0.000186, 1.4e-06, 0]
delta_d = [ 0.000211, -198.3104, 197.6293, 0.68112, -0.000131, -0.000122]
delta_alpha = [ 0.000244, 0.000511, 0.00702, 0.000233, 0.00171, 0]
joint_checksum = [ 0x1, 0x2, 0x3, 0x4, 0x5, 0x6]
calibration_status = 2 # 0 == notInitialized / 1 == notLinearised / 2 == Linearised
joint_raw_offset = [ 1.1, 1.2, -5.1, 3.1, 3.0, 3.1]
"""


def _ur_fk(q, theta, a, d, alpha) -> np.ndarray:
    """UR's standard DH chain, T = prod Rz(q + theta) Tz(d) Tx(a) Rx(alpha), written out (not jcalib's)."""
    T = np.eye(4)
    for i in range(6):
        t = q[i] + theta[i]
        ct, st, ca, sa = np.cos(t), np.sin(t), np.cos(alpha[i]), np.sin(alpha[i])
        T = T @ np.array([[ct, -st * ca, st * sa, a[i] * ct], [st, ct * ca, -ct * sa, a[i] * st],
                          [0.0, sa, ca, d[i]], [0.0, 0.0, 0.0, 1.0]])  # fmt: skip
    return T


def _effective(delta: dict) -> tuple:
    a0, d0 = [0.0, -0.425, -0.3922, 0.0, 0.0, 0.0], [0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996]
    alpha0 = [np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0]
    return (np.array(delta["theta"]), np.add(a0, delta["a"]), np.add(d0, delta["d"]), np.add(alpha0, delta["alpha"]))


def test_a_ur_calibration_file_is_the_nominal_kinematics_with_urs_fk(tmp_path):
    delta = parse_ur_calibration(CONF)
    assert delta["d"][1] == -198.3104 and delta["theta"][2] == 6.47012
    model = kt.from_spec({"preset": "ur5e", "delta_dh": delta}, "arm")
    nominal = kt.from_spec("ur5e", "arm")
    rng = np.random.default_rng(0)
    for q in rng.uniform(-np.pi, np.pi, size=(5, 6)):
        T = np.asarray(km.forward(model, model.nominal, jnp.asarray(q)))
        assert np.abs(T - _ur_fk(q, *_effective(delta))).max() < FK_TOL
        T0 = np.asarray(km.forward(nominal, nominal.nominal, jnp.asarray(q)))
        assert np.abs(T0 - _ur_fk(q, *_effective({k: [0.0] * 6 for k in delta}))).max() < FK_TOL
    # named in a cell spec, relative to the cell file; the parsed cell carries the deltas, not the path
    (tmp_path / "calibration.conf").write_text(CONF)
    cell = tmp_path / "cell.yaml"
    cell.write_text(yaml.safe_dump({
        "schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025, "mount": "base"}},
        "robot": {"model": "ur5e", "kinematics": {"preset": "ur5e", "ur_calibration": "calibration.conf"},
                  "calibrate_kinematics": ["joint_offsets"]}}))  # fmt: skip
    spec = load_cell(cell)
    q = rng.uniform(-np.pi, np.pi, 6)
    kin = spec.robot.kinematics
    assert np.abs(np.asarray(km.forward(kin, kin.nominal, jnp.asarray(q))) - _ur_fk(q, *_effective(delta))).max() < FK_TOL
    stored = cell_to_dict(spec)
    assert stored["robot"]["kinematics"] == {"preset": "ur5e", "delta_dh": delta}
    (tmp_path / "calibration.conf").unlink()
    again = parse_cell(stored).robot.kinematics  # a session's copy of the cell needs no file
    assert np.array_equal(np.asarray(again.nominal), np.asarray(kin.nominal))


@pytest.mark.parametrize("text, match", [
    (CONF.replace("calibration_status = 2", "calibration_status = 1"), "notLinearised"),
    (CONF.replace("delta_d =", "delta_x ="), "no delta_d"),
    (CONF.replace("delta_a = [ 0.000151, ", "delta_a = ["), "entries"),
    (CONF.replace("0.000244", "nan"), "finite"),
    (CONF.replace("[mounting]", "[other]"), r"\[mounting\]"),
    ("not an ini file at all", "not a UR calibration file"),
])  # fmt: skip
def test_malformed_calibration_files_are_refused(text, match):
    with pytest.raises(BadInputError, match=match):
        parse_ur_calibration(text)


def test_missing_file_and_misplaced_keys_are_refused(tmp_path):
    with pytest.raises(BadInputError, match="cannot read"):
        read_ur_calibration(tmp_path / "nope.conf")
    with pytest.raises(BadInputError, match="delta_dh"):
        kt.from_spec({"preset": "ur5e", "delta_dh": {"theta": [0.0] * 5}}, "arm")
    with pytest.raises(BadInputError, match="unknown key"):
        kt.from_spec({"preset": "ur5e", "delta_dh": {"beta": [0.0] * 6}}, "arm")
    with pytest.raises(BadInputError, match="preset"):
        parse_cell({"schema": "jcalib.cell/1", "cameras": {"c": {"model": "opencv5", "mount": "flange"}},
                    "robot": {"kinematics": {"ur_calibration": "x.conf"}}})  # fmt: skip


def _result(params: np.ndarray, model: km.Kinematics, calibrated=("shoulder_lift.theta", "elbow.a")) -> ResultFile:
    extra = {"table": kt.table(model, params), "spec": kt.to_spec(model, params)}
    entry = KinematicsResult("dh", tuple(model.param_names), params, np.asarray(model.nominal), tuple(calibrated),
                             np.eye(len(calibrated)) * 1e-8, extra)  # fmt: skip
    return ResultFile(kinematics={"arm": entry}, stats={"num_residuals": 10})


def test_export_ur_calibration_reads_back_as_the_calibrated_arm(tmp_path):
    assert "ur-calibration" in EXPORT_FORMATS and "ur-calibration" in FORMAT_DESCRIPTIONS
    assert DEFAULT_FILE_NAMES["ur-calibration"].endswith(".conf")
    assert export_options("ur-calibration", robot="arm") == {"robot": "arm"}
    # the calibrated arm: the UR file's deltas plus small changes of every joint parameter
    model = kt.from_spec("ur5e", "arm")
    rng = np.random.default_rng(1)
    base = np.asarray(kt.from_spec({"preset": "ur5e", "delta_dh": parse_ur_calibration(CONF)}, "arm").nominal)
    params = base.copy()
    params[:24] += 1e-4 * rng.normal(size=24)
    path = export_result(_result(params, model), "ur-calibration", tmp_path / "ur_calibration.conf")
    text = path.read_text()
    assert "[mounting]" in text and "not a controller file" in text and text.isascii()
    delta = read_ur_calibration(path)
    back = kt.from_spec({"preset": "ur5e", "delta_dh": delta}, "arm")
    for q in rng.uniform(-np.pi, np.pi, size=(4, 6)):
        want = np.asarray(km.forward(model, params, jnp.asarray(q)))
        assert np.abs(np.asarray(km.forward(back, back.nominal, jnp.asarray(q))) - want).max() < FK_TOL
        assert np.abs(_ur_fk(q, *_effective(delta)) - want).max() < FK_TOL


def test_export_refuses_what_ur_calibration_cannot_hold(tmp_path):
    model = kt.from_spec("ur5e", "arm")
    moved_base = np.asarray(model.nominal).copy()
    moved_base[model.param_names.index("base.tx")] = 1e-3
    with pytest.raises(BadInputError, match="base frame.*joint_offsets, link_lengths and twists"):
        export_result(_result(moved_base, model), "ur-calibration", tmp_path / "a.conf")
    kuka = km.PRESETS["kuka_kr10_r1100_sixx"]()
    with pytest.raises(BadInputError, match="sign -1|not the DH table of a UR type"):
        export_result(_result(np.asarray(kuka.nominal), kuka, ("A2.theta",)), "ur-calibration", tmp_path / "b.conf")
    with pytest.raises(BadInputError, match="no 'kinematics' section"):
        export_result(ResultFile(stats={"num_residuals": 1}), "ur-calibration", tmp_path / "c.conf")
    assert not any(tmp_path.iterdir())
