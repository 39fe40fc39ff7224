"""Record golden outputs of jcalib's calibration paths on fixed inputs (run once, before a rebuild).

    .venv/bin/python tests/golden/record.py [--only NAME ...]

Every case stores its *inputs* (cell spec + observations, or the arrays a Python preset takes) and
the outputs (estimates, standard deviations / covariances, statuses, or the error class and the
unknowns it names) in ``tests/golden/cases/<name>.json``. ``tests/golden/test_golden.py`` runs the
same inputs through today's code and compares in units of σ. Inputs are stored, not regenerated,
so the comparison does not depend on simulators that may change.

It imports the pre-rebuild modules (``jcalib.problems.camera``, ``.handeye``, ``.cell``), so it runs on
a checkout of the commit before the single-builder rebuild (428809f), not on today's tree; the cases it
wrote are the record. pytest does not collect it.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
CASES = HERE / "cases"
REAL = ROOT / "tests" / "data" / "real"


def _load(rel: str, name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "tests" / rel)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def jsonable(x):
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else str(v)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


# ------------------------------------------------------------------------------------ inputs


def camera_inputs():
    T = _load("problems/test_camera_calibration.py", "_gc_cam")
    from jcalib.geometry import camera_from_opencv
    from jcalib.sim.scene import project_target, random_calibration_views

    rng = np.random.default_rng(11)
    K = np.array([[1200.0, 0.0, 640.3], [0.0, 1198.0, 481.2], [0.0, 0.0, 1.0]])
    dist = np.array([-0.21, 0.09, 0.0004, -0.0006, -0.02])
    model = camera_from_opencv(K, dist, (1280, 960))
    views = [{"cam0": V} for V in random_calibration_views(model, T.BOARD.points, 25, rng=rng)]
    obs = T.make_obs({"cam0": model}, views, rng, sigma_px=0.2).to_dict()
    out = {"camera_synthetic": (_cell({"cam0": "opencv5"}), obs, None)}
    # a stereo rig, as the camera test builds it
    rng = np.random.default_rng(12)
    right = camera_from_opencv(np.array([[1190.0, 0, 630.0], [0, 1191.0, 470.0], [0, 0, 1]]),
                               np.array([-0.18, 0.07, 0.0, 0.0, 0.0]), (1280, 960))
    T_r_l = np.eye(4)
    T_r_l[:3, 3] = [-0.12, 0.002, 0.001]
    views = []
    for V in random_calibration_views(model, T.BOARD.points, 30, rng=rng, fill=(0.25, 0.45)):
        _, vis = project_target(right, T_r_l @ V, T.BOARD.points)
        if vis.all():
            views.append({"left": V, "right": T_r_l @ V})
    obs = T.make_obs({"left": model, "right": right}, views, rng, sigma_px=0.2).to_dict()
    cell = _cell({"left": "opencv5", "right": "opencv5"})
    out["camera_stereo_synthetic"] = (cell, obs, None)
    return out


def _cell(models):
    return {"schema": "jcalib.cell/1", "cameras": {n: {"model": m} for n, m in models.items()},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}


def handeye_inputs():
    H = _load("problems/test_handeye_joint.py", "_gc_he")
    out = {}
    cell, obs, _ = H.make_data(21, mount="flange", n=15, sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
    out["handeye_eye_in_hand_pose_model"] = (cell, obs, None)
    cell, obs, _ = H.make_data(22, mount="base", n=15, sigma_px=0.2)
    out["handeye_eye_to_hand"] = (cell, obs, None)
    cell, obs, _ = H.make_data(23, mount="flange", n=15, sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
    out["handeye_eye_in_hand_no_pose_model"] = (cell, obs, {"type": "HandEyeOptions", "pose_model": False})
    out["handeye_huber"] = (cell, obs, {"type": "HandEyeOptions", "loss": "huber"})
    return out


def cell_inputs():
    from jcalib.problems.cell import synthetic_cell, synthetic_two_robot_cell

    C = _load("problems/test_cell.py", "_gc_cell")
    out = {}
    cell, obs, _ = synthetic_cell(31, num_board_stations=10, num_tool_stations=20)
    out["cell_synthetic"] = (cell, obs, {"type": "CellOptions"})
    cell, obs, _ = synthetic_two_robot_cell(32)
    out["cell_two_robots"] = (cell, obs, {"type": "CellOptions"})
    rng = np.random.default_rng(33)
    cell, obs = C._pivot_data(rng)
    out["cell_pivot_contacts"] = (cell, obs, {"type": "CellOptions"})
    return out


def real_camera_inputs():
    out = {}
    # Zhang 1998: model corners (inches) and pixels of 5 images
    d = REAL / "zhang1998"
    model = np.loadtxt(d / "Model.txt").reshape(-1, 2) * 0.0254
    pts = np.c_[model, np.zeros(len(model))]
    stations = []
    for i in range(1, 6):
        pix = np.loadtxt(d / f"data{i}.txt").reshape(-1, 2)
        stations.append({"id": f"img{i}", "detections": [{"camera": "cam", "target": "board",
                         "point_index": list(range(len(pix))), "pixels": pix.tolist()}]})
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [640, 480]}},
           "targets": {"board": {"points": pts.tolist()}}, "stations": stations}
    # recorded with a stand-in checkerboard (the old cell format had no target of given points); the
    # case file now says type: points, the same data
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv5", "skew": True, "fix": ["p1", "p2", "k3"]}},
            "targets": {"board": {"type": "points"}}}
    out["camera_zhang1998"] = (cell, obs, {"type": "CameraCalibrationOptions", "outlier_threshold": None})
    # OpenCV left images: corners detected here once, stored with the case
    import cv2

    d = REAL / "opencv_left_right_chessboard"
    objp = np.zeros((54, 3))
    objp[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2) * 0.03
    stations = []
    for p in sorted((d / "images").glob("left*.jpg")):
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        ok, c = cv2.findChessboardCorners(img, (9, 6))
        if not ok:
            continue
        c = cv2.cornerSubPix(img, c, (11, 11), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-6))
        stations.append({"id": p.stem, "detections": [{"camera": "left", "target": "board",
                         "point_index": list(range(54)), "pixels": c.reshape(-1, 2).tolist()}]})
    obs = {"schema": "jcalib.observations/1", "cameras": {"left": {"image_size": [640, 480]}},
           "targets": {"board": {"points": objp.tolist()}}, "stations": stations}
    cell = {"schema": "jcalib.cell/1", "cameras": {"left": {"model": "opencv5", "fix": ["aspect"]}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}
    out["camera_opencv_left"] = (cell, obs, None)
    # mrcal's wide-angle set, OPENCV8 (weights: inliers only)
    rows = np.genfromtxt(REAL / "mrcal_figueroa" / "board_observations.csv", delimiter=",",
                         names=["view", "row_i", "col_j", "u_px", "v_px", "weight"])
    stations = []
    for v in np.unique(rows["view"]):
        r = rows[(rows["view"] == v) & (rows["weight"] > 0)]
        idx = (r["row_i"] * 10 + r["col_j"]).astype(int)
        stations.append({"id": f"v{int(v):03d}", "detections": [{"camera": "cam", "target": "board",
                         "point_index": idx.tolist(), "pixels": np.c_[r["u_px"], r["v_px"]].tolist()}]})
    ij = np.mgrid[0:10, 0:10].reshape(2, -1).T  # (i, j) row-major
    pts = np.c_[ij[:, 1] * 0.077, ij[:, 0] * 0.077, np.zeros(100)]
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [6016, 4016]}},
           "targets": {"board": {"points": pts.tolist()}}, "stations": stations}
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv8"}},
            "targets": {"board": {"type": "checkerboard", "cols": 10, "rows": 10, "square": 0.077}}}
    out["camera_mrcal_figueroa"] = (cell, obs, {"type": "CameraCalibrationOptions", "sigma_px": 0.5})
    return out


def degenerate_inputs():
    H = _load("problems/test_handeye_joint.py", "_gc_he2")
    out = {}
    # every flange rotation about one axis: the hand-eye translation along it is not observable
    cell, obs, _ = H.make_data(41, mount="flange", n=12, sigma_px=0.1)
    rng = np.random.default_rng(41)
    T0 = np.asarray(obs["stations"][0]["T_base_flange"])
    from scipy.spatial.transform import Rotation

    for i, st in enumerate(obs["stations"]):
        R = Rotation.from_rotvec([0, 0, np.radians(20.0 * i - 100.0)]).as_matrix()
        T = T0.copy()
        T[:3, :3] = R @ T0[:3, :3]
        T[:3, 3] = T0[:3, 3] + rng.uniform(-0.05, 0.05, 3)
        st["T_base_flange"] = T.tolist()
    out["error_one_axis_handeye"] = (cell, obs, None)
    # a view with too few points
    C = camera_inputs()["camera_synthetic"]
    cell, obs = json.loads(json.dumps(C[0])), json.loads(json.dumps(C[1]))
    det = obs["stations"][0]["detections"][0]
    det["point_index"], det["pixels"] = det["point_index"][:4], det["pixels"][:4]
    out["error_too_few_points"] = (cell, obs, None)
    return out


# ------------------------------------------------------------------------------------ outputs


def make_options(spec):
    if spec is None:
        return None
    spec = dict(spec)
    kind = spec.pop("type")
    if kind == "HandEyeOptions":
        from jcalib.problems.handeye import HandEyeOptions as cls
    elif kind == "CellOptions":
        from jcalib.problems.cell import CellOptions as cls
    else:
        from jcalib.problems.camera import CameraCalibrationOptions as cls
    return cls(**spec)


def result_outputs(file) -> dict:
    d = file.to_dict()
    out = {"cameras": {}, "transforms": {}, "points": {}, "stats": {}}
    for name, cam in file.cameras.items():
        out["cameras"][name] = {"model": cam.model, "param_names": list(cam.param_names),
                                "params": np.asarray(cam.params).tolist(),
                                "covariance": None if cam.covariance is None else np.asarray(cam.covariance).tolist()}
    for name, tr in file.transforms.items():
        out["transforms"][name] = {"matrix": np.asarray(tr.matrix).tolist(),
                                   "covariance": None if tr.covariance is None else np.asarray(tr.covariance).tolist()}
    for name, p in file.points.items():
        out["points"][name] = {"position": np.asarray(p.position).tolist(), "frame": p.frame,
                               "covariance": None if p.covariance is None else np.asarray(p.covariance).tolist()}
    for k in ("rms_px", "sigma_px", "tip_rms_px", "contact_rms_m", "num_residuals", "num_outliers", "status",
              "variance_components", "robot", "num_stations"):
        if k in d.get("stats", {}):
            out["stats"][k] = d["stats"][k]
    return out


def run_calibrate(cell, obs, options):
    import jcalib
    from jcalib.errors import JcalibError

    try:
        res = jcalib.calibrate(cell, obs, make_options(options))
    except JcalibError as err:
        return {"error": type(err).__name__, "exit_code": err.exit_code,
                "unknowns": list(getattr(err, "unknowns", []) or []), "message": str(err)}
    return result_outputs(res.file)


def preset_cases() -> dict:
    """Python presets that are not reached through a cell spec today: TCP, pivot, pose pairs."""
    out = {}
    T = _load("problems/test_tcp.py", "_gc_tcp")
    from jcalib.geometry.cameras import Pinhole
    from jcalib.problems.tcp import calibrate_tcp

    rng = np.random.default_rng(51)
    cams = [T._camera(), Pinhole((1024, 1024), focal=(2000.0, 2000.0), principal_point=(511.5, 511.5))]
    Tcs = np.stack([T._T_base_cam(0.0), T._T_base_cam(70.0)])
    a_true = np.array([0.05, -0.08, 1.0]) / np.linalg.norm([0.05, -0.08, 1.0])
    Ttrue = T._poses(rng, n=14)
    tips = np.einsum("nab,b->na", Ttrue[:, :3, :3], T.X_TRUE) + Ttrue[:, :3, 3]
    px = np.stack([T._observe(c, Tc, Ttrue, rng, 0.3) for c, Tc in zip(cams, Tcs)], axis=1)
    s = np.array([-0.005, -0.015, -0.04])
    axis_base = np.einsum("nab,b->na", Ttrue[:, :3, :3], a_true)
    lines = np.stack([np.stack([T._project(c, Tc, tips + si * axis_base) for si in s], axis=1)
                      for c, Tc in zip(cams, Tcs)], axis=1) + rng.normal(0, 0.5, (14, 2, 3, 2))
    Tmeas = np.stack([C @ _small(rng, 2e-5, 0.002) for C in Ttrue])
    inputs = {"cameras": [{"image_size": list(c.image_size), "params": np.asarray(c.params).tolist()} for c in cams],
              "T_base_cam": Tcs, "T_base_flange": Tmeas, "tip_pixels": px, "axis_lines": lines,
              "pose_noise_translation_m": 2e-5, "pose_noise_rotation_deg": 0.002, "sigma_px": 0.3}
    res = calibrate_tcp(cams, Tcs, Tmeas, px, axis_lines=lines, pose_noise_translation_m=2e-5,
                        pose_noise_rotation_deg=0.002, sigma_px=0.3)
    out["tcp_two_cameras_axis"] = {"kind": "calibrate_tcp", "inputs": inputs, "outputs": {
        "p_flange_tip": res.p_flange_tip, "tip_covariance": res.tip_covariance, "axis_flange": res.axis_flange,
        "axis_covariance": res.axis_covariance, "rms_px": res.rms_px, "sigma2": res.sigma2, "status": res.status}}
    inputs2 = dict(inputs, tip_pixels=px[:, :1], cameras=inputs["cameras"][:1], T_base_cam=Tcs[:1], axis_lines=None,
                   free_camera_pose=True)
    res = calibrate_tcp(cams[:1], Tcs[:1], Tmeas, px[:, :1], free_camera_pose=True, pose_noise_translation_m=2e-5,
                        pose_noise_rotation_deg=0.002, sigma_px=0.3)
    out["tcp_one_camera_free_pose"] = {"kind": "calibrate_tcp", "inputs": inputs2, "outputs": {
        "p_flange_tip": res.p_flange_tip, "tip_covariance": res.tip_covariance, "T_base_cam": res.T_base_cam,
        "T_base_cam_covariance": res.T_base_cam_covariance, "rms_px": res.rms_px, "sigma2": res.sigma2,
        "status": res.status}}

    from jcalib.problems.pivot import refine_pivot

    mats = sorted((REAL / "pivot_ucl_ndi" / "matrices").glob("*.txt"))
    Tp = np.stack([np.loadtxt(p).reshape(4, 4) for p in mats])
    Tp[:, :3, 3] *= 1e-3  # mm -> m
    for serial in (False, True):
        res = refine_pivot(Tp, serial_correlation=serial)
        out[f"pivot_ucl_serial_{serial}".lower()] = {"kind": "refine_pivot", "inputs": {
            "files": "pivot_ucl_ndi/matrices (mm, converted to m)", "serial_correlation": serial}, "outputs": {
            "p_flange_tip": res.p_flange_tip, "p_base_pivot": res.p_base_pivot, "covariance": res.covariance,
            "rms": res.rms, "status": res.status}}

    from jcalib.io.importers.opencv_pairs import read_transform_pairs
    from jcalib.problems.handeye_pairs import calibrate_hand_eye_pairs

    T1, T2 = read_transform_pairs(REAL / "handeye_camodocal_example" / "TransformPairsInput.yml")
    res = calibrate_hand_eye_pairs(T1, T2, mode="eye_to_hand")
    out["pairs_camodocal"] = {"kind": "calibrate_hand_eye_pairs", "inputs": {"mode": "eye_to_hand"}, "outputs": {
        "X": res.T_hand_eye, "Y": res.T_other, "X_covariance": res.T_hand_eye_covariance,
        "Y_covariance": res.T_other_covariance, "noise": [res.noise.rotation_deg, res.noise.translation_m],
        "status": res.status}}
    return out


def _small(rng, sigma_m, sigma_deg):
    from scipy.spatial.transform import Rotation

    d = np.eye(4)
    d[:3, :3] = Rotation.from_rotvec(np.radians(sigma_deg) * rng.standard_normal(3)).as_matrix()
    d[:3, 3] = sigma_m * rng.standard_normal(3)
    return d


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", nargs="*")
    args = ap.parse_args()
    CASES.mkdir(parents=True, exist_ok=True)
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    groups = {}
    for fn in (camera_inputs, handeye_inputs, cell_inputs, real_camera_inputs, degenerate_inputs):
        groups.update(fn())
    for name, (cell, obs, options) in groups.items():
        if args.only and name not in args.only:
            continue
        print(name, flush=True)
        case = {"kind": "calibrate", "recorded_at": commit, "cell": cell, "observations": obs, "options": options,
                "outputs": run_calibrate(cell, obs, options)}
        (CASES / f"{name}.json").write_text(json.dumps(jsonable(case)))
    for name, case in preset_cases().items():
        if args.only and name not in args.only:
            continue
        print(name, flush=True)
        case["recorded_at"] = commit
        (CASES / f"{name}.json").write_text(json.dumps(jsonable(case)))


if __name__ == "__main__":
    main()
