"""Data of the report tests: a camera, a weak hand-eye cell, the synthetic whole cell and two-robot cell
(:mod:`jcalib.sim.cells`), and helpers. ``conftest.py`` calibrates them once per session."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np

from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.geometry.cameras import camera_model_from_name
from jcalib.sim.scene import project_target

_path = Path(__file__).resolve().parents[1] / "init" / "test_handeye.py"
_spec = importlib.util.spec_from_file_location("_handeye_scene_helpers_report", _path)
H = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(H)

BOARD = Checkerboard(cols=9, rows=6, square=0.025)
K_TRUE = np.array([[1000.0, 0, 640], [0, 1000, 480], [0, 0, 1]])
DIST_TRUE = np.array([-0.2, 0.05, 0, 0, 0])
SIZE = (1280, 960)
CAMERA = camera_from_opencv(K_TRUE, DIST_TRUE, SIZE)
CAMERA_CELL = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5"}},
               "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025}}}
#: Stated noise equal to the simulated noise: covariances without a variance factor, so that a re-solve
#: with one more exactly consistent station has exactly the predicted covariance.
STATED = {"noise": "stated", "sigma_px": 0.2}
STATED_TIPS = {**STATED, "tip_sigma_px": 0.2}

HE_SIZE = (1600, 1200)
HE_PARAMS = np.array([1400.0, 1395.0, 801.5, 598.0, -0.12, 0.08, 0.0005, -0.0003, -0.02])
HE_CAMERA = camera_model_from_name("opencv5", HE_SIZE, HE_PARAMS)
FLIP = np.diag([1.0, -1.0, -1.0, 1.0])  # the helper's boards face +z; jcalib's are printed on -z


def camera_observations(views, rng, sigma=0.2) -> dict:
    stations = []
    for i, T in enumerate(views):
        pix, _ = project_target(CAMERA, T, BOARD.points)
        pix = pix + sigma * rng.standard_normal(pix.shape)
        stations.append({"id": f"s{i:02d}", "detections": [{
            "camera": "cam0", "target": "board", "point_index": list(range(54)), "pixels": pix.tolist()}]})
    return {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(SIZE)}},
            "targets": {"board": {"points": BOARD.points.tolist()}}, "stations": stations}


def weak_handeye(seed: int = 5, n: int = 12) -> tuple[dict, dict]:
    """Eye-in-hand, ``n`` stations: the camera rolls ±60° about its optical axis but tilts only ±1.5°, so
    the relative rotations are nearly all about camera Z; intrinsics known, robot pose model on."""
    rng = np.random.default_rng(seed)
    _X, Y, T_bf, T_ct = H.make_scene(rng, n=n, mount="flange", tilt_deg=1.5, roll_deg=60.0)
    T_ct = T_ct @ FLIP
    T_meas = H.perturb_robot(T_bf, rng, sigma_m=1e-4, sigma_deg=0.01)
    stations = []
    for i in range(n):
        pix, vis = project_target(HE_CAMERA, T_ct[i], H.BOARD)
        pix = pix + 0.2 * rng.normal(size=pix.shape)
        idx = np.flatnonzero(vis)
        stations.append({"id": f"s{i:03d}", "T_base_flange": T_meas[i].tolist(), "detections": [{
            "camera": "cam0", "target": "board", "point_index": idx.tolist(), "pixels": pix[idx].tolist()}]})
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(HE_SIZE)}},
           "targets": {"board": {"points": H.BOARD.tolist()}}, "stations": stations}
    K, dist = HE_CAMERA.to_opencv()
    cell = {"schema": "jcalib.cell/1",
            "cameras": {"cam0": {"model": "opencv5", "mount": "flange",
                                 "fix": ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"],
                                 "intrinsics": {"K": np.asarray(K).tolist(), "dist": np.asarray(dist).tolist()}}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025, "mount": "base"}},
            "robot": {"pose_noise": {"translation_m": 1e-4, "rotation_deg": 0.01}}}
    return cell, obs


def with_station(obs: dict, station) -> dict:
    """``obs`` with one more station (a :class:`jcalib.io.observations.Station`), as JSON data."""
    extra = json.loads(json.dumps(station.to_dict()))
    extra["id"] = f"extra{len(obs['stations'])}"
    return {**obs, "stations": [*obs["stations"], extra]}


def scara_handeye(seed: int = 7, n: int = 10) -> tuple[dict, dict]:
    """SCARA-like eye-in-hand data: flange z down, every rotation about the base z, so the hand-eye
    translation along that axis is not observable (``fix_unobservable`` holds it at a prior); 0.2 px."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    X = H.pose(Rotation.from_euler("xz", [20.0, 35.0], degrees=True).as_matrix(), [0.04, -0.03, 0.08])
    target = H.pose(Rotation.from_euler("zx", [25.0, 180.0], degrees=True).as_matrix(), [0.6, 0.1, 0.0])
    down = Rotation.from_euler("x", 180.0, degrees=True).as_matrix()
    stations = []
    for i, ang in enumerate(np.linspace(-80.0, 80.0, n) + rng.uniform(-5.0, 5.0, n)):
        R = Rotation.from_euler("z", ang, degrees=True).as_matrix() @ down
        h = 0.45 + rng.uniform(-0.05, 0.05)
        T_bc = H.pose(R, [0.0, 0.0, h]) @ X
        c, dz = T_bc[:3, 3], T_bc[:3, 2]
        look = c - c[2] / dz[2] * dz  # where the optical axis meets the table
        T_bf = H.pose(R, np.array([*(target[:2, 3] + rng.uniform(-0.06, 0.06, 2) - look[:2]), h]))
        pix, vis = project_target(HE_CAMERA, H.inv(T_bf @ X) @ target, H.BOARD)
        idx = np.flatnonzero(vis)
        stations.append({"id": f"s{i:03d}", "T_base_flange": T_bf.tolist(), "detections": [{
            "camera": "cam0", "target": "board", "point_index": idx.tolist(),
            "pixels": (pix[idx] + 0.2 * rng.normal(size=(idx.size, 2))).tolist()}]})
    cell, _ = weak_handeye(n=2)
    del cell["robot"]
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(HE_SIZE)}},
           "targets": {"board": {"points": H.BOARD.tolist()}}, "stations": stations}
    return cell, obs
