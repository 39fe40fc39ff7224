"""`jcalib triangulate` and `jcalib frame` on files in tmp_path: formats, frames, σ, exports, exit statuses."""

import json
import subprocess
import sys

import cv2
import jax
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2
from typer.testing import CliRunner

from jcalib.app.cli import app
from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.lie import local, se3_from_matrix

SIZE = (1280, 1024)
K0 = np.array([[1100.0, 0.0, 640.0], [0.0, 1100.0, 512.0], [0.0, 0.0, 1.0]])
D0 = np.array([-0.2, 0.08, 0.0005, -0.0003, -0.01])
K1 = np.array([[1500.0, 0.0, 630.0], [0.0, 1500.0, 520.0], [0.0, 0.0, 1.0]])
D1 = np.array([-0.1, 0.02, 0.0, 0.0, 0.0])
# four points on the table (base frame, m): a work object 20 x 15 cm, the 4th point 1 mm off the plane
WOBJ = np.eye(4)
WOBJ[:3, :3] = Rotation.from_euler("z", 20, degrees=True).as_matrix()
WOBJ[:3, 3] = [0.8, 0.05, 0.02]
P_WOBJ = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.05, 0.15, 0.0], [0.18, 0.14, 0.001]])
P_BASE = P_WOBJ @ WOBJ[:3, :3].T + WOBJ[:3, 3]
NAMES = ["o", "x", "y", "q"]


def look_at(centre, target, up=(0.0, 0.0, 1.0)):
    z = np.asarray(target, float) - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = centre
    return T


T_FLANGE_CAM0 = np.eye(4)
T_FLANGE_CAM0[:3, 3] = [0.05, 0.0, 0.08]
T_BASE_FLANGE = {  # flange z (and cam0's optical axis) looking down at the table
    "s0": look_at(np.array([0.75, -0.05, 0.55]), [0.88, 0.12, 0.0], up=(1.0, 0.0, 0.0)),
    "s1": look_at(np.array([1.0, 0.25, 0.5]), [0.88, 0.12, 0.0], up=(1.0, 0.0, 0.0)),
}
T_BASE_CAM1 = look_at(np.array([1.4, -0.6, 0.7]), [0.88, 0.12, 0.0])
T_BASE_BOARD = np.eye(4)
T_BASE_BOARD[:3, 3] = [0.6, -0.2, 0.0]
C_HE = np.diag([2e-4, 2e-4, 3e-4, 1e-4, 1e-4, 2e-4]) ** 2
C_CAM1 = np.diag([1e-4, 1e-4, 1e-4, 2e-4, 2e-4, 2e-4]) ** 2

CELL = """schema: jcalib.cell/1
cameras:
  cam0: {model: opencv5, mount: flange}
  cam1: {model: opencv5, mount: base}
targets:
  board: {type: checkerboard, cols: 9, rows: 6, square: 0.025, mount: base}
robot:
  pose_noise: {translation_m: 0.00002, rotation_deg: 0.001}
"""


def result_doc():
    cam = lambda K, D: {"model": "opencv5", "image_size": list(SIZE), "K": K.tolist(), "dist": D.tolist(),
                        "std": {"fx": 0.6, "fy": 0.6, "cx": 0.5, "cy": 0.5, "k1": 0.001}}  # fmt: skip
    return {"schema": "jcalib.result/1", "cameras": {"cam0": cam(K0, D0), "cam1": cam(K1, D1)},
            "transforms": {"T_flange_cam0": {"matrix": T_FLANGE_CAM0.tolist(), "covariance": C_HE.tolist()},
                           "T_base_cam1": {"matrix": T_BASE_CAM1.tolist(), "covariance": C_CAM1.tolist()},
                           "T_base_board": {"matrix": T_BASE_BOARD.tolist()}},
            "points": {}, "stats": {}}  # fmt: skip


def project(T_base_cam, K, D, P):
    T = np.linalg.inv(T_base_cam)
    return cv2.projectPoints(P, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K, D)[0].reshape(-1, 2)


def pixels_doc(noise_px=0.0, seed=0):
    rng = np.random.default_rng(seed)
    stations = []
    for sid, T_bf in T_BASE_FLANGE.items():
        pix = {}
        for cam, T_bc, K, D in (("cam0", T_bf @ T_FLANGE_CAM0, K0, D0), ("cam1", T_BASE_CAM1, K1, D1)):
            uv = project(T_bc, K, D, P_BASE) + noise_px * rng.standard_normal((4, 2))
            assert ((uv > 0) & (uv < SIZE)).all()
            pix[cam] = {n: p.tolist() for n, p in zip(NAMES, uv)}
        if sid == "s1":
            del pix["cam1"]["q"]  # not every image sees every point
        stations.append({"id": sid, "T_base_flange": T_bf.tolist(), "pixels": pix})
    return {"schema": "jcalib.pixels/1", "sigma_px": 0.2, "stations": stations}


@pytest.fixture()
def files(tmp_path):
    (tmp_path / "cell.yaml").write_text(CELL)
    (tmp_path / "result.json").write_text(json.dumps(result_doc()))
    (tmp_path / "clean.json").write_text(json.dumps(pixels_doc()))
    (tmp_path / "noisy.json").write_text(json.dumps(pixels_doc(0.2, seed=4)))
    return tmp_path


def invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


_local = jax.jit(lambda A, B: local(se3_from_matrix(A), se3_from_matrix(B)))


def test_triangulate_noise_free_in_every_frame(files):
    common = ["--cell", files / "cell.yaml", "--result", files / "result.json"]
    r = invoke("triangulate", files / "clean.json", *common, "-o", files / "base.json")
    assert r.exit_code == 0, r.output
    doc = json.loads((files / "base.json").read_text())
    assert doc["schema"] == "jcalib.pipeline.points/1" and doc["frame"] == "base" and list(doc["points"]) == NAMES
    got = np.array([doc["points"][n]["position"] for n in NAMES])
    np.testing.assert_allclose(got, P_BASE, atol=1e-9)  # exact pixels, float64: 1e-9 m
    assert doc["points"]["q"]["num_views"] == 3 and doc["points"]["o"]["num_views"] == 4
    assert np.array(doc["joint_covariance"]["matrix"]).shape == (12, 12)
    d = {(e["a"], e["b"]): e for e in doc["distances"]}
    assert len(d) == 6
    np.testing.assert_allclose(d[("o", "x")]["distance_m"], 0.2, atol=1e-9)
    assert 0 < d[("o", "x")]["std_m"] < 1e-3
    # the same points in the flange frame (station s0), in cam1's frame and in the board's frame
    expected = {
        "flange": np.linalg.inv(T_BASE_FLANGE["s0"]),
        "cam1": np.linalg.inv(T_BASE_CAM1),
        "board": np.linalg.inv(T_BASE_BOARD),
        "cam0": np.linalg.inv(T_BASE_FLANGE["s0"] @ T_FLANGE_CAM0),
    }
    for frame, T in expected.items():
        out = files / f"{frame}.json"
        r = invoke("triangulate", files / "clean.json", *common, "-o", out, "--frame", frame, "--station", "s0")
        assert r.exit_code == 0, r.output
        doc = json.loads(out.read_text())
        got = np.array([doc["points"][n]["position"] for n in NAMES])
        np.testing.assert_allclose(got, P_BASE @ T[:3, :3].T + T[:3, 3], atol=1e-9, err_msg=frame)
        assert doc.get("station") == (None if frame in ("cam1", "board") else "s0")  # fixed frames: no station
        assert doc["points"]["o"]["frame"] == frame


def test_triangulate_noisy_within_sigma_then_frames_and_exports(files):
    r = invoke("triangulate", files / "noisy.json", "--cell", files / "cell.yaml", "--result", files / "result.json",
               "-o", files / "points.json")  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "o:" in r.output and "mm" in r.output
    doc = json.loads((files / "points.json").read_text())
    C = np.array(doc["joint_covariance"]["matrix"])
    e = (np.array([doc["points"][n]["position"] for n in NAMES]) - P_BASE).reshape(-1)
    assert e @ np.linalg.solve(C, e) < chi2.ppf(0.999, 12)  # one fixed-seed draw, all four points jointly
    assert 1e-6 < np.sqrt(np.diag(C)).max() < 2e-3  # sub-millimetre σ, not zero

    # three-point frame (o, x, y) with RAPID export; the tangent error is consistent with its covariance
    r = invoke("frame", files / "points.json", "-o", files / "frame.json", "--points", "o,x,y", "--name", "table",
               "--export", "rapid")  # fmt: skip
    assert r.exit_code == 0, r.output
    res = json.loads((files / "frame.json").read_text())
    assert res["schema"] == "jcalib.result/1"
    T = np.array(res["transforms"]["T_base_table"]["matrix"])
    C6 = np.array(res["transforms"]["T_base_table"]["covariance"])
    e6 = np.asarray(_local(WOBJ, T))
    assert e6 @ np.linalg.solve(C6, e6) < chi2.ppf(0.999, 6)
    mod = (files / "frame.mod").read_text()
    assert "PERS wobjdata table :=" in mod and "T_base_table" in mod
    x_mm = float(mod.split("PERS wobjdata table := [FALSE, TRUE, \"\", [[")[1].split(",")[0])
    assert abs(x_mm - WOBJ[0, 3] * 1e3) < 2.0  # origin x in mm, within a few σ

    # plane fit over all four points with KRL export; the frame's Z is the table normal (+z)
    r = invoke("frame", files / "points.json", "-o", files / "plane.json", "--method", "plane", "--export", "krl",
               "--export-out", files / "base_data.txt")  # fmt: skip
    assert r.exit_code == 0, r.output
    plane = json.loads((files / "plane.json").read_text())
    Tp = np.array(plane["transforms"]["T_base_wobj"]["matrix"])
    assert Tp[:3, 2] @ WOBJ[:3, 2] > 0.9999 and plane["stats"]["num_points"] == 4
    assert 1e-4 < plane["stats"]["plane_rms_m"] < 1e-3  # the 4th point is 1 mm off the plane
    assert "BASE_DATA[1]={X " in (files / "base_data.txt").read_text()


def test_bad_inputs_are_named(files, tmp_path):
    cell = files / "cell.yaml"
    doc = pixels_doc()
    doc["stations"][0]["pixels"]["cam7"] = {"o": [1.0, 2.0]}
    (tmp_path / "bad_cam.json").write_text(json.dumps(doc))
    r = invoke("triangulate", tmp_path / "bad_cam.json", "--cell", cell, "--result", files / "result.json", "-o",
               tmp_path / "p.json")  # fmt: skip
    assert isinstance(r.exception, BadInputError) and r.exception.exit_code == 2
    assert "cam7" in str(r.exception)
    # no result: the cell has no hand-eye pose (nor intrinsics) for cam0
    r = invoke("triangulate", files / "clean.json", "--cell", cell, "-o", tmp_path / "p.json")
    assert isinstance(r.exception, BadInputError) and "T_flange_cam0 is unknown" in str(r.exception)
    # a point seen once
    doc = {"schema": "jcalib.pixels/1", "stations": [{"id": "a", "T_base_flange": np.eye(4).tolist(),
                                                      "pixels": {"cam1": {"lonely": [10.0, 20.0]}}}]}  # fmt: skip
    (tmp_path / "once.json").write_text(json.dumps(doc))
    r = invoke("triangulate", tmp_path / "once.json", "--cell", cell, "--result", files / "result.json", "-o",
               tmp_path / "p.json")  # fmt: skip
    assert isinstance(r.exception, BadInputError) and "'lonely' is seen in 1 image" in str(r.exception)
    # frame flange needs a station when there are two
    r = invoke("triangulate", files / "clean.json", "--cell", cell, "--result", files / "result.json", "-o",
               tmp_path / "p.json", "--frame", "flange")  # fmt: skip
    assert isinstance(r.exception, BadInputError) and "--station" in str(r.exception)
    assert not (tmp_path / "p.json").exists()
    # collinear points -> not observable (exit status 3), named
    pts = {"points": {n: {"position": [0.1 * i, 0.2 * i, 0.0], "frame": "base"} for i, n in enumerate("abc")}}
    (tmp_path / "line.json").write_text(json.dumps(pts))
    r = invoke("frame", tmp_path / "line.json", "-o", tmp_path / "f.json")
    assert isinstance(r.exception, NotObservableError) and r.exception.exit_code == 3
    assert "collinear" in str(r.exception)
    r = invoke("frame", tmp_path / "line.json", "-o", tmp_path / "f.json", "--method", "three-point", "--points", "a,b")
    assert isinstance(r.exception, BadInputError) and "exactly three" in str(r.exception)


def test_exit_statuses_of_the_installed_command(tmp_path):
    """The real entry point: status 2 / 3 with a one-paragraph message, no traceback."""
    pts = {"points": {n: {"position": [0.1 * i, 0.2 * i, 0.0]} for i, n in enumerate("abc")}}
    (tmp_path / "line.json").write_text(json.dumps(pts))
    (tmp_path / "broken.json").write_text('{"schema": "jcalib.pixels/1", "stations": [}')
    (tmp_path / "cell.yaml").write_text(CELL)
    jcalib = [sys.executable, "-c", "from jcalib.app.cli import main; main()"]
    proc = subprocess.run([*jcalib, "frame", "line.json", "-o", "f.json"], capture_output=True, text=True, cwd=tmp_path, check=False)
    assert proc.returncode == 3 and "collinear" in proc.stderr and "Traceback" not in proc.stderr
    proc = subprocess.run([*jcalib, "triangulate", "broken.json", "--cell", "cell.yaml", "-o", "p.json"],
                          capture_output=True, text=True, cwd=tmp_path, check=False)  # fmt: skip
    assert proc.returncode == 2 and "broken.json line 1" in proc.stderr and "Traceback" not in proc.stderr
