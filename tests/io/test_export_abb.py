"""ABB RAPID export: golden module, a small independent parser of the tooldata/wobjdata literals,
and the round trip back to the 4x4 transform through scipy's quaternion."""

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
from jcalib.io.export import ToolLoad, abb_rapid_module, abb_tooldata, abb_wobjdata, write_abb_rapid
from jcalib.io.result import ResultFile, TransformResult

GOLDEN = Path(__file__).parent / "golden"

# Rounding of the export: 0.001 mm and 1e-6 per quaternion component. A quaternion moved by at
# most |dq| <= 2 * 0.5e-6 turns the rotation by at most 2 * |dq| = 2e-6 rad (+ float64 noise).
POS_TOL_MM = 0.5e-3 + 1e-9
ROT_TOL_RAD = 2e-6 + 1e-9


def check_golden(name: str, text: str) -> None:
    """Compare with the golden file; JCALIB_UPDATE_GOLDEN=1 rewrites it (review the diff)."""
    path = GOLDEN / name
    if os.environ.get("JCALIB_UPDATE_GOLDEN"):
        path.write_text(text, encoding="utf-8")
    assert text == path.read_text(encoding="utf-8")


# ---------------------------------------------------------------- a small RAPID literal parser

_TOKEN = re.compile(
    r'\s*(?:(\[)|(\])|(,)|("[^"]*")|(TRUE|FALSE)|([-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?))'
)


def parse_rapid_literal(text: str):
    """A RAPID aggregate literal -> nested lists of float / bool / str."""
    tokens, pos = [], 0
    text = text.strip()
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        assert m, f"cannot parse RAPID at {text[pos : pos + 20]!r}"
        tokens.append(m)
        pos = m.end()

    def value(i):
        m = tokens[i]
        if m.group(1):
            items, i = [], i + 1
            while not tokens[i].group(2):
                item, i = value(i)
                items.append(item)
                if tokens[i].group(3):
                    i += 1
            return items, i + 1
        if m.group(4):
            return m.group(4)[1:-1], i + 1
        if m.group(5):
            return m.group(5) == "TRUE", i + 1
        return float(m.group(6)), i + 1

    parsed, end = value(0)
    assert end == len(tokens)
    return parsed


def parse_module(text: str) -> dict[str, tuple[str, object]]:
    lines = text.strip().splitlines()
    assert re.fullmatch(r"MODULE [A-Za-z]\w*", lines[0]) and lines[-1] == "ENDMODULE"
    out = {}
    for line in lines:
        m = re.fullmatch(r"\s*PERS (tooldata|wobjdata) ([A-Za-z]\w*) := (.*);", line)
        if m:
            out[m.group(2)] = (m.group(1), parse_rapid_literal(m.group(3)))
    return out


def pose_to_matrix(pose) -> np.ndarray:
    """[[x, y, z] mm, [q1..q4] wxyz] -> 4x4 (m), through scipy (xyzw)."""
    (x, y, z), (w, qx, qy, qz) = pose
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([qx, qy, qz, w]).as_matrix()  # scipy normalises
    T[:3, 3] = np.array([x, y, z]) * 1e-3
    return T


def assert_pose_close(pose, T_expected):
    (_, quat) = pose
    assert quat[0] >= 0.0  # q1 >= 0
    assert abs(np.linalg.norm(quat) - 1.0) <= 2.5e-6  # within RAPID's normalisation check
    T = pose_to_matrix(pose)
    np.testing.assert_allclose(T[:3, 3] * 1e3, T_expected[:3, 3] * 1e3, rtol=0, atol=POS_TOL_MM)
    angle = Rotation.from_matrix(T[:3, :3].T @ T_expected[:3, :3]).magnitude()
    assert angle <= ROT_TOL_RAD


# ---------------------------------------------------------------- tests


@pytest.fixture(scope="module")
def result() -> ResultFile:
    return ResultFile.load(GOLDEN / "result.json")


def test_golden_module_and_round_trip(result, tmp_path):
    text = abb_rapid_module(result, wobjs=["board"])
    check_golden("abb_jcalib_cal.mod", text)
    path = write_abb_rapid(GOLDEN / "result.json", tmp_path / "cal.mod", wobjs=["board"])
    assert path.read_text() == text
    decls = parse_module(text)
    assert sorted(decls) == ["tool_gripper", "tool_needle", "wobj_board"]
    for tool in ("needle", "gripper"):
        kind, (robhold, tframe, tload) = decls[f"tool_{tool}"]
        T = result.transforms[f"T_flange_{tool}"].matrix
        assert kind == "tooldata" and robhold is True
        assert_pose_close(tframe, T)
        mass, cog, aom, ix, iy, iz = tload
        assert mass == 1.0 and aom == [1.0, 0.0, 0.0, 0.0] and (ix, iy, iz) == (0.0, 0.0, 0.0)
        np.testing.assert_allclose(cog, T[:3, 3] * 1e3, atol=POS_TOL_MM)  # default: 1 kg at the TCP
    kind, (robhold, ufprog, ufmec, uframe, oframe) = decls["wobj_board"]
    assert (kind, robhold, ufprog, ufmec) == ("wobjdata", False, True, "")
    assert_pose_close(uframe, result.transforms["T_base_board"].matrix)
    assert oframe == [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]]


def test_gripper_quaternion_is_exactly_90_deg_about_y(result):
    # T_flange_gripper = Ry(+90 deg): q = [cos 45, 0, sin 45, 0]
    _, (_, (trans, quat), _) = ("", parse_rapid_literal(abb_tooldata(result, "gripper")))
    assert trans == [105.0, -2.1, 133.3]
    assert quat == [0.707107, 0.0, 0.707107, 0.0]


_unit = st.floats(-1.0, 1.0, allow_nan=False)


@given(
    q=st.lists(_unit, min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
    t=st.lists(st.floats(-3.0, 3.0, allow_nan=False), min_size=3, max_size=3),
)
def test_any_pose_round_trips_within_the_printed_precision(q, t):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q).as_matrix()
    T[:3, 3] = t
    result = ResultFile(
        transforms={"T_flange_t": TransformResult(T), "T_base_w": TransformResult(T)}
    )
    assert_pose_close(parse_rapid_literal(abb_tooldata(result, "t"))[1], T)
    assert_pose_close(parse_rapid_literal(abb_wobjdata(result, "w"))[3], T)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_half_turns_keep_q1_non_negative(axis):
    rotvec = np.zeros(3)
    rotvec[axis] = np.pi
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    result = ResultFile(transforms={"T_flange_t": TransformResult(T)})
    pose = parse_rapid_literal(abb_tooldata(result, "t"))[1]
    assert "-0.000000" not in abb_tooldata(result, "t")
    assert_pose_close(pose, T)


def test_given_load_names_and_module(result):
    load = ToolLoad(mass_kg=2.5, cog_mm=(0.0, 0.0, 80.0), inertia_kgm2=(0.01, 0.01, 0.002))
    text = abb_rapid_module(
        result, tools={"needle": "tNeedle"}, wobjs=[], module="CalibData", loads={"needle": load}
    )
    decls = parse_module(text)
    assert list(decls) == ["tNeedle"]
    assert decls["tNeedle"][1][2] == [
        2.5,
        [0.0, 0.0, 80.0],
        [1.0, 0.0, 0.0, 0.0],
        0.01,
        0.01,
        0.002,
    ]
    assert text.startswith("MODULE CalibData\n")


def test_bad_requests(result):
    with pytest.raises(BadInputError, match="mass_kg"):
        ToolLoad(mass_kg=0.0)
    with pytest.raises(BadInputError, match="no transform T_flange_drill.*gripper, needle"):
        abb_rapid_module(result, tools=["drill"])
    with pytest.raises(BadInputError, match="expected an identifier"):
        abb_rapid_module(result, tools={"needle": "2fast"})
    with pytest.raises(BadInputError, match="expected an identifier"):
        abb_rapid_module(result, tools={"needle": "t" * 33})
    with pytest.raises(BadInputError, match="would both be called"):
        abb_rapid_module(result, tools={"needle": "tA", "gripper": "TA"}, wobjs=[])
    with pytest.raises(BadInputError, match="used twice"):
        abb_rapid_module(result, tools={"needle": "x1"}, wobjs={"board": "X1"})
    with pytest.raises(BadInputError, match="nothing to export"):
        abb_rapid_module(ResultFile(transforms={"T_cam0_board": TransformResult(np.eye(4))}))
    with pytest.raises(BadInputError, match="loads: 'board'"):
        abb_rapid_module(result, loads={"board": ToolLoad()})
