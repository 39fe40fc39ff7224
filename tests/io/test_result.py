"""The result file (jcalib.result/1): exact round trips, validation naming the key, atomic save."""

from __future__ import annotations

import copy
import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import jcalib
from jcalib.errors import BadInputError
from jcalib.io.result import (
    CAMERA_MODEL_DIST_NAMES,
    SCHEMA,
    CameraResult,
    PointResult,
    Provenance,
    ResultFile,
    TransformResult,
    hash_inputs,
    load_result,
)

GOLDEN = Path(__file__).parent / "golden"

# The example of docs/design.md ("Result"), with its descriptive covariance strings left out.
DESIGN_EXAMPLE = {
    "schema": "jcalib.result/1",
    "cameras": {
        "cam0": {
            "model": "opencv5",
            "image_size": [1600, 1200],
            "K": [[1400, 0, 800], [0, 1400, 600], [0, 0, 1]],
            "dist": [-0.25, 0.1, 0.001, -0.0005, -0.02],
            "std": {"fx": 0.8, "fy": 0.8, "cx": 0.9, "cy": 0.9, "k1": 0.002},
        }
    },
    "transforms": {
        "T_flange_cam0": {"matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}
    },
    "points": {"divot": {"position": [0.1, -0.2, 0.05], "frame": "base"}},
    "stats": {"rms_px": 0.21, "num_residuals": 4000, "sigma_px": 0.2},
}


def _golden_dict() -> dict:
    return json.loads((GOLDEN / "result.json").read_text(encoding="utf-8"))


# ---------------------------------------------------------------------------------------------
# Round trips
# ---------------------------------------------------------------------------------------------


def test_golden_file_round_trips_byte_for_byte():
    text = (GOLDEN / "result.json").read_text(encoding="utf-8")
    result = ResultFile.load(GOLDEN / "result.json")
    assert result.to_json() == text
    # The values are the literals of the file (independent of our parser: json.loads).
    raw = json.loads(text)
    assert result.cameras["cam0"].K[0, 0] == 1402.317
    assert result.cameras["cam1"].skew is True and result.cameras["cam1"].K[0, 1] == 0.35
    assert np.array_equal(
        result.transforms["T_flange_needle"].matrix, raw["transforms"]["T_flange_needle"]["matrix"]
    )
    assert result.cameras["cam0"].param_names == (
        "fx",
        "fy",
        "cx",
        "cy",
        "k1",
        "k2",
        "p1",
        "p2",
        "k3",
    )
    assert result.cameras["cam1"].param_names[:5] == ("fx", "fy", "cx", "cy", "skew")
    assert result.provenance.created == "2026-11-21T10:00:00Z"
    assert result.stats["num_stations"] == 21  # a stat this version does not know is kept


def test_design_example_loads_and_round_trips():
    result = ResultFile.from_dict(DESIGN_EXAMPLE)
    assert result.provenance is None
    out = result.to_dict()
    assert json.loads(json.dumps(out)) == {**DESIGN_EXAMPLE}
    assert result.cameras["cam0"].skew is False


def test_save_load_is_exact_and_atomic(tmp_path):
    result = ResultFile.load(GOLDEN / "result.json")
    path = result.save(tmp_path / "sub" / "result.json")
    assert sorted(p.name for p in path.parent.iterdir()) == ["result.json"]  # no temp file left
    again = load_result(path)
    for name, cam in result.cameras.items():
        assert np.array_equal(again.cameras[name].K, cam.K)
        assert np.array_equal(again.cameras[name].dist, cam.dist)
    assert np.array_equal(again.cameras["cam0"].covariance, result.cameras["cam0"].covariance)
    for name, tr in result.transforms.items():
        assert np.array_equal(again.transforms[name].matrix, tr.matrix)
    assert again.to_dict() == result.to_dict()


def test_unknown_keys_are_kept_through_a_round_trip():
    data = copy.deepcopy(DESIGN_EXAMPLE)
    data["solver_trace"] = {"iterations": 7}
    data["cameras"]["cam0"]["mrcal_model"] = "LENSMODEL_OPENCV5"
    data["transforms"]["T_flange_cam0"]["note"] = "hand-eye"
    result = ResultFile.from_dict(data)
    assert result.extra == {"solver_trace": {"iterations": 7}}
    assert result.to_dict() == json.loads(json.dumps(data))


_finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@st.composite
def _results(draw) -> dict:
    cameras = {}
    for i in range(draw(st.integers(0, 2))):
        model = draw(st.sampled_from(sorted(CAMERA_MODEL_DIST_NAMES)))
        n = len(CAMERA_MODEL_DIST_NAMES[model])
        skew = draw(st.floats(-2, 2, allow_nan=False)) if draw(st.booleans()) else 0.0
        fx, fy = draw(st.floats(10, 1e5)), draw(st.floats(10, 1e5))
        cam = {
            "model": model,
            "image_size": [draw(st.integers(1, 10000)), draw(st.integers(1, 10000))],
            "K": [[fx, skew, draw(_finite)], [0.0, fy, draw(_finite)], [0.0, 0.0, 1.0]],
            "dist": draw(st.lists(st.floats(-10, 10, allow_nan=False), min_size=n, max_size=n)),
        }
        if model == "splined":  # dist[0] is its horizontal field of view, in (0, 350] degrees
            cam["dist"][0] = draw(st.floats(1.0, 350.0))
        if skew != 0.0:
            cam["skew"] = True
        p = 4 + (skew != 0.0) + n
        if draw(st.booleans()):
            r = min(p, 12)  # a rank-r factor: a splined model has 421 intrinsics
            a = np.array(
                draw(st.lists(st.floats(-3, 3, allow_nan=False), min_size=p * r, max_size=p * r))
            )
            cam["covariance"] = (
                a.reshape(p, r) @ a.reshape(p, r).T
            ).tolist()  # exactly symmetric PSD
        cameras[f"cam{i}"] = cam
    transforms = {}
    for i in range(draw(st.integers(0, 3))):
        q = np.array(draw(st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4)))
        rot = Rotation.from_quat(q) if np.linalg.norm(q) > 0.1 else Rotation.identity()
        T = np.eye(4)
        T[:3, :3] = rot.as_matrix()
        T[:3, 3] = draw(st.lists(st.floats(-10, 10, allow_nan=False), min_size=3, max_size=3))
        transforms[f"T_base_f{i}"] = {"matrix": T.tolist()}
    return {
        "schema": SCHEMA,
        "cameras": cameras,
        "transforms": transforms,
        "points": {
            "p": {"position": draw(st.lists(_finite, min_size=3, max_size=3)), "frame": "base"}
        },
        "stats": {"rms_px": draw(st.floats(0, 100)), "num_residuals": draw(st.integers(0, 10**9))},
    }


@given(_results())
def test_any_valid_result_round_trips_exactly_through_json_text(data):
    result = ResultFile.from_dict(data)
    again = ResultFile.from_dict(json.loads(result.to_json()))
    assert again.to_dict() == result.to_dict() == json.loads(json.dumps(data))


# ---------------------------------------------------------------------------------------------
# Validation: BadInputError naming the key, the value and what was expected
# ---------------------------------------------------------------------------------------------


def _set(path: tuple, value):
    def mutate(d):
        for key in path[:-1]:
            d = d[key]
        d[path[-1]] = value

    return mutate


def _delete(path: tuple):
    def mutate(d):
        for key in path[:-1]:
            d = d[key]
        del d[path[-1]]

    return mutate


BAD = [
    (_set(("schema",), "jcalib.result/2"), "schema: expected 'jcalib.result/1'"),
    (_delete(("schema",)), "schema"),
    (_set(("cameras", "cam0", "K"), [[1, 0], [0, 1]]), "cameras.cam0.K: expected shape (3, 3)"),
    (_delete(("cameras", "cam0", "K")), "cameras.cam0.K: missing"),
    (_set(("cameras", "cam0", "K"), [[1400, 0, 800], [0, 1400, 600], [0, 0, 2]]), "cameras.cam0.K"),
    (_set(("cameras", "cam0", "K"), [[-1, 0, 800], [0, 1400, 600], [0, 0, 1]]), "fx, fy > 0"),
    (
        _set(("cameras", "cam0", "model"), "opencv6"),
        "cameras.cam0.model: unknown camera model 'opencv6'",
    ),
    (
        _set(("cameras", "cam0", "dist"), [0.1, 0.2]),
        "cameras.cam0.dist (model 'opencv5'): expected shape (5,)",
    ),
    (_set(("cameras", "cam0", "image_size"), [1600.5, 1200]), "cameras.cam0.image_size"),
    (_set(("cameras", "cam0", "image_size"), [True, 1200]), "cameras.cam0.image_size"),
    (_set(("cameras", "cam0", "std", "k9"), 0.1), "cameras.cam0.std: unknown intrinsic 'k9'"),
    (_set(("cameras", "cam0", "std", "fx"), -0.1), "cameras.cam0.std.fx: expected a number >= 0"),
    (_set(("cameras", "cam0", "std", "fx"), "0.1"), "cameras.cam0.std.fx: expected a number"),
    (_set(("cameras", "cam0", "skew"), False), None),  # K[0][1] == 0: consistent
    (_set(("cameras", "cam0", "covariance"), np.eye(8).tolist()), "covariance (order"),
    (_set(("cameras", "cam0", "covariance"), (np.eye(9) + np.eye(9, k=1)).tolist()), "symmetric"),
    (
        _set(
            ("cameras", "cam0", "covariance"),
            (np.eye(9) - 2 * np.eye(9)[::-1] * (1 - np.eye(9))).tolist(),
        ),
        "semi-definite",
    ),
    (
        _set(("transforms", "T_flange_cam0", "matrix"), np.diag([2.0, 1, 1, 1]).tolist()),
        "transforms.T_flange_cam0.matrix: expected a proper rotation",
    ),
    (
        _set(("transforms", "T_flange_cam0", "matrix"), np.diag([-1.0, 1, 1, 1]).tolist()),
        "det = -1",
    ),
    (
        _set(
            ("transforms", "T_flange_cam0", "matrix"),
            [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]],
        ),
        "last row",
    ),
    (
        _set(("transforms", "T_flange_cam0", "covariance"), np.eye(3).tolist()),
        "transforms.T_flange_cam0.covariance (rx, ry, rz, tx, ty, tz): expected shape (6, 6)",
    ),
    (_set(("transforms", "T_flange_cam0"), [1, 2]), "transforms.T_flange_cam0: expected a mapping"),
    (
        _set(("points", "divot", "position"), [0.1, float("nan"), 0.0]),
        "points.divot.position: expected finite numbers, got nan at index [1]",
    ),
    (_delete(("points", "divot", "frame")), "points.divot.frame: missing"),
    (
        _set(("stats", "num_residuals"), -3),
        "stats.num_residuals: expected a non-negative integer, got -3",
    ),
    (_set(("stats", "rms_px"), float("inf")), "stats.rms_px: expected a finite number"),
    (_set(("stats", "per_camera"), {"cam0": float("nan")}), "stats.per_camera.cam0"),
    (
        _set(("provenance",), {"created": "yesterday"}),
        "provenance.created: expected an ISO 8601 time",
    ),
    (_set(("provenance",), {"options": [1]}), "provenance.options: expected a mapping"),
    (_set(("cameras",), []), "cameras: expected a mapping"),
]


@pytest.mark.parametrize("mutate, message", BAD)
def test_bad_input_names_the_key(mutate, message):
    data = copy.deepcopy(DESIGN_EXAMPLE)
    mutate(data)
    if message is None:
        ResultFile.from_dict(data)
        return
    with pytest.raises(BadInputError) as err:
        ResultFile.from_dict(data, source="result.json")
    assert str(err.value).startswith("result.json: ")
    assert message in str(err.value)


def test_skew_flag_must_agree_with_K():
    with pytest.raises(BadInputError, match=r"skew: is false but K\[0\]\[1\] = 0.5"):
        CameraResult(
            "opencv5",
            (640, 480),
            [[500, 0.5, 320], [0, 500, 240], [0, 0, 1]],
            np.zeros(5),
            skew=False,
        )


def test_nan_in_the_file_text_is_rejected(tmp_path):
    text = json.dumps(DESIGN_EXAMPLE).replace("0.21", "NaN")
    (tmp_path / "r.json").write_text(text)
    with pytest.raises(BadInputError, match="NaN"):
        ResultFile.load(tmp_path / "r.json")


def test_unreadable_files_are_bad_input(tmp_path):
    with pytest.raises(BadInputError, match="does not exist"):
        ResultFile.load(tmp_path / "missing.json")
    (tmp_path / "broken.json").write_text('{"schema": "jcalib.result/1",\n "cameras": {\n}')
    with pytest.raises(BadInputError, match="line 3 column 2: not valid JSON"):
        ResultFile.load(tmp_path / "broken.json")
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(BadInputError, match="a result must be a JSON object"):
        ResultFile.load(tmp_path / "list.json")


def test_save_refuses_nothing_invalid_because_construction_validates():
    with pytest.raises(BadInputError, match=r"matrix: expected finite numbers"):
        TransformResult(np.full((4, 4), np.nan))
    with pytest.raises(BadInputError, match="frame: expected a non-empty name"):
        PointResult([0.0, 0.0, 0.0], frame="")
    with pytest.raises(BadInputError, match=r"cameras.cam0: expected a CameraResult"):
        ResultFile(cameras={"cam0": {"model": "opencv5"}})
    with pytest.raises(BadInputError, match="extra: keys \\['cameras'\\]"):
        ResultFile(extra={"cameras": {}})


def test_entries_are_read_only_copies_of_their_inputs():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    cam = CameraResult("pinhole", (640, 480), K, [])
    K[0, 0] = 1.0  # the caller's array changes, the entry does not
    assert cam.K[0, 0] == 500.0
    with pytest.raises(ValueError):
        cam.K[0, 0] = 2.0


# ---------------------------------------------------------------------------------------------
# Agreement with the camera models, queries, helpers
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("model", sorted(CAMERA_MODEL_DIST_NAMES))
@pytest.mark.parametrize("skew", [False, True])
def test_intrinsic_names_agree_with_the_camera_models(model, skew):
    """The result's table is a NumPy-only mirror of jcalib.geometry.cameras: check they agree,
    and that CameraResult.from_model gives OpenCV's (K, dist) of the model."""
    from jcalib.geometry.cameras import camera_model_from_name

    if model == "splined" and skew:  # it has no skew parameter, and says so
        with pytest.raises(BadInputError, match="skew"):
            camera_model_from_name(model, (640, 480), skew=skew)
        return
    cam_model = camera_model_from_name(model, (640, 480), skew=skew)
    n = len(cam_model.param_names)
    params = np.concatenate([[500.0, 510.0, 320.0, 240.0], [0.01] * (n - 4)])
    cam_model = cam_model.with_params(params)
    cov = np.diag(np.arange(1.0, n + 1.0))
    entry = CameraResult.from_model(cam_model, covariance=cov)
    assert entry.param_names == tuple(cam_model.param_names)
    assert np.array_equal(entry.params, np.asarray(cam_model.params))
    K, dist = cam_model.to_opencv()
    assert np.array_equal(entry.K, K) and np.array_equal(entry.dist, dist)
    assert entry.std == {name: math.sqrt(i + 1.0) for i, name in enumerate(cam_model.param_names)}


def _inv(T):
    return np.linalg.inv(T)


def test_transform_between_direct_inverse_and_common_parent():
    result = ResultFile.load(GOLDEN / "result.json")
    base_cam0 = result.transforms["T_base_cam0"].matrix
    base_cam1 = result.transforms["T_base_cam1"].matrix
    # 1e-12: float64 products of 4x4 rigid transforms with unit-scale entries
    np.testing.assert_allclose(
        result.transform_between("cam1", "cam0"), _inv(base_cam1) @ base_cam0, atol=1e-12
    )
    np.testing.assert_allclose(result.transform_between("base", "cam0"), base_cam0, atol=0)
    np.testing.assert_allclose(
        result.transform_between("cam0", "base"), _inv(base_cam0), atol=1e-12
    )
    assert result.frames_under("flange") == ["gripper", "needle"]
    with pytest.raises(BadInputError, match="cannot form T_cam0_needle"):
        result.transform_between("cam0", "needle")
    with pytest.raises(BadInputError, match="no camera 'cam7'.*cam0, cam1"):
        result.camera("cam7")


def test_hash_inputs_is_sha256_of_length_prefixed_parts(tmp_path):
    (tmp_path / "a").write_bytes(b"abc")
    expected = hashlib.sha256(b"\x03\0\0\0\0\0\0\0abc\x01\0\0\0\0\0\0\0d").hexdigest()
    assert hash_inputs(tmp_path / "a", b"d") == "sha256:" + expected
    assert hash_inputs(b"ab", b"c") != hash_inputs(b"a", b"bc")
    with pytest.raises(BadInputError, match="is not a file"):
        hash_inputs(tmp_path / "nope")


def test_provenance_now_is_stamped_and_round_trips():
    prov = Provenance.now("sha256:00", {"max_iterations": 50})
    assert prov.jcalib_version == jcalib.__version__
    assert prov.created.endswith("Z")
    result = ResultFile.from_dict({**DESIGN_EXAMPLE, "provenance": prov.to_dict()})
    assert result.provenance.to_dict() == prov.to_dict()
