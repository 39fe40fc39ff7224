"""KUKA KRL export: golden $config.dat lines, parse-back, and A/B/C checked against scipy's
intrinsic Z-Y'-X'' ('ZYX') Euler angles."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jcalib.errors import BadInputError
from jcalib.io.export import kuka_config_lines, kuka_frame_literal, write_kuka_krl
from jcalib.io.result import ResultFile, TransformResult

GOLDEN = Path(__file__).parent / "golden"

# Rounding of the export: 0.001 mm and 1e-4 degree per angle; three angles each off by at most
# 0.5e-4 deg turn the rotation by at most 3 * 0.5e-4 deg (+ float64 noise).
POS_TOL_MM = 0.5e-3 + 1e-9
ROT_TOL_RAD = np.deg2rad(3 * 0.5e-4) + 1e-9

_NUM = r"(-?\d+\.\d+)"
_FRAME = re.compile(rf"\{{X {_NUM}, Y {_NUM}, Z {_NUM}, A {_NUM}, B {_NUM}, C {_NUM}\}}")


def check_golden(name: str, text: str) -> None:
    """Compare with the golden file; JCALIB_UPDATE_GOLDEN=1 rewrites it (review the diff)."""
    path = GOLDEN / name
    if os.environ.get("JCALIB_UPDATE_GOLDEN"):
        path.write_text(text, encoding="utf-8")
    assert text == path.read_text(encoding="utf-8")


def parse_config(text: str) -> dict:
    """``{("TOOL", 1): (xyzabc, name), ...}`` from TOOL_DATA/TOOL_NAME/BASE_DATA/BASE_NAME lines."""
    frames, names = {}, {}
    for line in text.splitlines():
        if not line or line.startswith(";"):
            continue
        m = re.fullmatch(r"(TOOL|BASE)_DATA\[(\d+)\]=(.*)", line)
        if m:
            f = _FRAME.fullmatch(m.group(3))
            assert f, line
            frames[(m.group(1), int(m.group(2)))] = [float(v) for v in f.groups()]
            continue
        m = re.fullmatch(r'(TOOL|BASE)_NAME\[(\d+),\]="([^"]*)"', line)
        assert m, f"unexpected line {line!r}"
        names[(m.group(1), int(m.group(2)))] = m.group(3)
    assert frames.keys() == names.keys()
    return {k: (frames[k], names[k]) for k in frames}


def xyzabc_to_matrix(v) -> np.ndarray:
    """Independent reference: scipy's intrinsic 'ZYX' (capital letters = intrinsic)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", v[3:], degrees=True).as_matrix()
    T[:3, 3] = np.asarray(v[:3]) * 1e-3
    return T


def assert_frame_close(v, T_expected):
    assert -90.0 <= v[4] <= 90.0 and -180.0 <= v[3] <= 180.0 and -180.0 <= v[5] <= 180.0
    T = xyzabc_to_matrix(v)
    np.testing.assert_allclose(T[:3, 3] * 1e3, T_expected[:3, 3] * 1e3, rtol=0, atol=POS_TOL_MM)
    angle = Rotation.from_matrix(T[:3, :3].T @ T_expected[:3, :3]).magnitude()
    assert angle <= ROT_TOL_RAD


@pytest.fixture(scope="module")
def result() -> ResultFile:
    return ResultFile.load(GOLDEN / "result.json")


def test_golden_and_round_trip(result, tmp_path):
    text = kuka_config_lines(result, tools={"needle": 3, "gripper": None}, bases=["board"])
    check_golden("kuka_config.dat", text)
    path = write_kuka_krl(
        GOLDEN / "result.json",
        tmp_path / "cfg.dat",
        tools={"needle": 3, "gripper": None},
        bases=["board"],
    )
    assert path.read_text() == text
    parsed = parse_config(text)
    # gripper takes the lowest index not given to another tool
    assert sorted(parsed) == [("BASE", 1), ("TOOL", 1), ("TOOL", 3)]
    for key, frame in (
        (("TOOL", 3), "T_flange_needle"),
        (("TOOL", 1), "T_flange_gripper"),
        (("BASE", 1), "T_base_board"),
    ):
        v, name = parsed[key]
        assert name == frame.split("_", 2)[2]
        assert_frame_close(v, result.transforms[frame].matrix)
    # the needle was built as Z-Y'-X'' = (12.5, -30, 5.25) deg: the same angles come back
    assert parsed[("TOOL", 3)][0][3:] == [12.5, -30.0, 5.25]
    # the gripper is Ry(90 deg): gimbal lock, C = 0 by convention
    assert parsed[("TOOL", 1)][0][3:] == [0.0, 90.0, 0.0]


_unit = st.floats(-1.0, 1.0, allow_nan=False)


@given(
    q=st.lists(_unit, min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
    t=st.lists(st.floats(-3.0, 3.0, allow_nan=False), min_size=3, max_size=3),
)
def test_any_frame_round_trips_within_the_printed_precision(q, t):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q).as_matrix()
    T[:3, 3] = t
    v = [float(x) for x in _FRAME.fullmatch(kuka_frame_literal(T)).groups()]
    assert_frame_close(v, T)


@pytest.mark.parametrize("b_deg", [90.0, -90.0, 89.99999, -89.99999])
@pytest.mark.parametrize("a_deg, c_deg", [(30.0, 10.0), (-170.0, 175.0)])
def test_near_and_at_gimbal_lock(a_deg, b_deg, c_deg):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [a_deg, b_deg, c_deg], degrees=True).as_matrix()
    v = [float(x) for x in _FRAME.fullmatch(kuka_frame_literal(T)).groups()]
    assert_frame_close(v, T)


def test_bad_requests(result):
    with pytest.raises(BadInputError, match="integer 1..16"):
        kuka_config_lines(result, tools={"needle": 17})
    with pytest.raises(BadInputError, match="integer 1..32"):
        kuka_config_lines(result, bases={"board": 0})
    with pytest.raises(BadInputError, match="index 2 is given to two frames"):
        kuka_config_lines(result, tools={"needle": 2, "gripper": 2})
    with pytest.raises(BadInputError, match="no transform T_base_table"):
        kuka_config_lines(result, bases=["table"])
    long_name = ResultFile(transforms={"T_flange_" + "x" * 25: TransformResult(np.eye(4))})
    with pytest.raises(BadInputError, match="cannot be a KUKA name"):
        kuka_config_lines(long_name)
    with pytest.raises(BadInputError, match="nothing to export"):
        kuka_config_lines(result, tools=[], bases=[])
