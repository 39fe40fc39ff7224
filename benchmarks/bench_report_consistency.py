"""Do the report's σ match the Monte-Carlo spread? Intrinsics (camera cell), hand-eye, the whole cell and TCP.

Fixed geometry, fresh Gaussian noise (corners, tips, robot poses) per trial, fixed seeds. Each trial is
calibrated and the report's linear model (:func:`jcalib.report.model.linear_model`: the covariance of
the solve's Solution, what the report's tables, weak directions and warnings use) gives the σ of every
unknown; the TCP rows use :mod:`jcalib.report.tcp` on the result file of a TCP calibration (σ of the
TCP per flange axis, and of the tool tip in the base frame at the file's reference flange pose).
Printed per unknown: empirical σ (RMS error against the truth), reported σ (RMS over trials), their
ratio (target 0.85-1.15), the result file's σ over the report's (1.0000: the report shows the solve's
numbers, it has no model of its own) and the RMS over the mean of the reported σ (1.00: the per-trial σ
hardly vary, so their RMS is a fair summary).

A last table checks "what would help" (``--predict``): for the whole cell, the σ the report predicts
after adding one candidate station (built by the one builder, linearised by the solve) against the
Monte-Carlo spread of calibrations that have that station (noisy like the others).

The sampling 99.9 % band of a ratio printed with each table is what a *perfect* σ would show with
that many trials: at 200 trials it is about [0.86, 1.19], as wide as the ±15 % target, so single
ratios near 0.85 at 200 trials are not evidence of a bug; use ``--trials 1000`` (band about
±7 %) to judge an outlier.

Run: ``.venv/bin/python benchmarks/bench_report_consistency.py [--trials 200] [--views 10 20 40]
[--skip-camera] [--skip-handeye] [--skip-cell] [--skip-tcp] [--predict]``
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import numpy as np
from scipy import stats

import jcalib
from jcalib.geometry import Checkerboard, camera_from_opencv
from jcalib.geometry import lie
from jcalib.geometry.conversions import pose_to_matrix
from jcalib.geometry.se3 import log_se3
from jcalib.report.model import linear_model, options_of
from jcalib.sim.scene import project_target, random_calibration_views

BOARD = Checkerboard(cols=9, rows=6, square=0.03)


def camera_trials(trials: int, num_views: int = 10):
    K = np.array([[800.0, 0, 330.0], [0, 805.0, 242.0], [0, 0, 1]])
    dist = np.array([-0.3, 0.12, 1e-3, -5e-4, -0.02])
    cam = camera_from_opencv(K, dist, (640, 480))
    views = random_calibration_views(cam, BOARD.points, num_views, rng=3)
    clean = [project_target(cam, T, BOARD.points)[0] for T in views]
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv5"}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}
    rng = np.random.default_rng(1003)
    truth = np.asarray(cam.params)
    err, sig, solver = [], [], []
    for _ in range(trials):
        obs = {"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [640, 480]}},
               "targets": {"board": {"points": BOARD.points.tolist()}},
               "stations": [{"id": f"v{i}", "detections": [{"camera": "cam", "target": "board",
                             "point_index": list(range(len(BOARD.points))),
                             "pixels": (p + 0.3 * rng.standard_normal(p.shape)).tolist()}]}
                            for i, p in enumerate(clean)]}
        result = jcalib.calibrate(cell, obs)
        model = linear_model(result.details, options_of(result.file))
        err.append(np.asarray(result.file.cameras["cam"].params) - truth)
        sig.append(model.sigma())
        solver.append(file_sigma(result.file, model))
    return [u.label for u in model.unknowns], np.array(err), np.array(sig), np.array(solver)


def se3_exp(delta: np.ndarray) -> np.ndarray:
    """``T = Exp(δ)`` (4, 4) of a tangent ``(rx, ry, rz, tx, ty, tz)`` (rad, m)."""
    import jax.numpy as jnp

    return np.asarray(pose_to_matrix(np.asarray(lie.se3_exp(jnp.asarray(delta)))))


def _handeye_helpers():
    path = Path(__file__).resolve().parents[1] / "tests" / "init" / "test_handeye.py"
    spec = importlib.util.spec_from_file_location("_handeye_scene_helpers_bench", path)
    H = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(H)
    return H


def file_sigma(file, model) -> np.ndarray:
    """The result file's σ of every unknown of the model (display units)."""
    out = []
    for u in model.unknowns:
        if u.block in file.cameras:
            out.append(file.cameras[u.block].std[u.coord])
        elif u.block.startswith("point "):
            p = file.points[u.block[6:]]
            out.append(1e3 * float(np.sqrt(p.covariance["xyz".index(u.coord)]["xyz".index(u.coord)])))
        else:
            k = ("rx", "ry", "rz", "tx", "ty", "tz").index(u.coord)
            out.append(u.scale * float(np.sqrt(np.asarray(file.transforms[u.block].covariance)[k, k])))
    return np.array(out)


def model_errors(result, model, truth: dict) -> np.ndarray:
    """Estimate − truth of every unknown of the model, display units (transforms: δ with truth = est·Exp(δ))."""
    out = []
    deltas = {n: log_se3(np.linalg.inv(T) @ truth[n]) for n, T in result.details.transforms.items() if n in truth}
    for u in model.unknowns:
        if u.block in result.details.cameras:
            j = model.param_names[u.block].index(u.coord)
            out.append(float(np.asarray(result.details.cameras[u.block].params)[j] - truth[u.block][j]))
        else:
            out.append(u.scale * float(deltas[u.block][("rx", "ry", "rz", "tx", "ty", "tz").index(u.coord)]))
    return np.array(out)


def handeye_trials(trials: int):
    H = _handeye_helpers()
    size = (1600, 1200)
    params = np.array([1400.0, 1395.0, 801.5, 598.0, -0.12, 0.08, 0.0005, -0.0003, -0.02])
    from jcalib.geometry.cameras import camera_model_from_name

    camera = camera_model_from_name("opencv5", size, params)
    flip = np.diag([1.0, -1.0, -1.0, 1.0])  # the helper's boards face +z; jcalib's are printed on -z
    scene = np.random.default_rng(7)
    n = 15
    X, Y, T_bf, T_ct = H.make_scene(scene, n=n, mount="flange")
    T_ct, Y = T_ct @ flip, Y @ flip
    clean = [project_target(camera, Tc, H.BOARD) for Tc in T_ct]
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025, "mount": "base"}},
            "robot": {"pose_noise": {"translation_m": 1e-4, "rotation_deg": 0.01}}}
    truth = {"cam0": params, "T_flange_cam0": X, "T_base_board": Y}
    rng = np.random.default_rng(2024)
    err, sig, solver = [], [], []
    for _ in range(trials):
        T_meas = H.perturb_robot(T_bf, rng, sigma_m=1e-4, sigma_deg=0.01)
        stations = []
        for i, (pix, vis) in enumerate(clean):
            idx = np.flatnonzero(vis)
            noisy = pix[idx] + 0.2 * rng.standard_normal((len(idx), 2))
            stations.append({"id": f"s{i:03d}", "T_base_flange": T_meas[i].tolist(), "detections": [{
                "camera": "cam0", "target": "board", "point_index": idx.tolist(), "pixels": noisy.tolist()}]})
        obs = {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(size)}},
               "targets": {"board": {"points": H.BOARD.tolist()}}, "stations": stations}
        result = jcalib.calibrate(cell, obs)
        model = linear_model(result.details, options_of(result.file))
        err.append(model_errors(result, model, truth))
        sig.append(model.sigma())
        solver.append(file_sigma(result.file, model))
    return [u.label for u in model.unknowns], np.array(err), np.array(sig), np.array(solver)


def cell_trials(trials: int):
    """The synthetic whole cell of :func:`jcalib.sim.cells.synthetic_cell` (flange camera, fixed camera with
    known intrinsics, fixed board, needle tool; 0.2 px corners and tips, robot 0.1 mm / 0.01°, pose model):
    same layout every trial, fresh noise; every shared unknown of the solve."""
    from jcalib.sim.cells import synthetic_cell

    err, sig, solver = [], [], []
    for k in range(trials):
        cell, obs, truth = synthetic_cell(1000 + k, num_board_stations=12, num_tool_stations=14)
        result = jcalib.calibrate(cell, obs)
        model = linear_model(result.details, options_of(result.file))
        err.append(model_errors(result, model, truth))
        sig.append(model.sigma())
        solver.append(file_sigma(result.file, model))
    return [u.label for u in model.unknowns], np.array(err), np.array(sig), np.array(solver)


def predict_trials(trials: int, key: str = "cam1/needle tip_x"):
    """What would help, checked: the report's predicted σ after one more candidate station (from the first
    trial's calibration) against the spread of calibrations that have that station (its tip pixel with
    fresh noise and a noisy robot pose, like every other station)."""
    from jcalib.report.candidates import candidates, station_information
    from jcalib.sim.cells import synthetic_cell

    cell, obs, truth = synthetic_cell(2000, num_board_stations=12, num_tool_stations=14)
    result = jcalib.calibrate(cell, obs)
    model = linear_model(result.details, options_of(result.file))
    cand = {c.key: c for c in candidates(model)}[key]
    predicted = model.sigma(station_information(model, cand))
    # the candidate's flange pose, re-simulated with the truth (pixel from the true cell, fresh noise)
    F = np.asarray(cand.station.T_base_flange)
    from jcalib.geometry.cameras import camera_model_from_name
    from jcalib.sim.cells import SYNTH_IMAGE_SIZE

    cam1 = camera_model_from_name("opencv5", SYNTH_IMAGE_SIZE, truth["cam1"])
    tip = (F @ truth["T_flange_needle"])[:3, 3]
    p_cam = np.linalg.inv(truth["T_base_cam1"]) @ np.append(tip, 1.0)
    clean = np.asarray(cam1.project(p_cam[:3]))
    err, sig = [], []
    rng = np.random.default_rng(77)
    for k in range(trials):
        cell, obs, _ = synthetic_cell(3000 + k, num_board_stations=12, num_tool_stations=14)
        # the robot's pose noise as the cell states it (right perturbation, 0.01° and 0.1 mm per axis)
        F_meas = F @ se3_exp(np.concatenate([np.radians(0.01) * rng.normal(size=3), 1e-4 * rng.normal(size=3)]))
        extra = {"id": "extra", "T_base_flange": F_meas.tolist(), "detections": [
            {"camera": "cam1", "tool": "needle", "pixel": (clean + 0.2 * rng.normal(size=2)).tolist()}]}
        obs = {**obs, "stations": [*obs["stations"], extra]}
        result = jcalib.calibrate(cell, obs)
        m = linear_model(result.details, options_of(result.file))
        err.append(model_errors(result, m, truth))
        sig.append(m.sigma())
    labels = [u.label for u in model.unknowns]
    return labels, np.array(err), np.array(sig), predicted


def tcp_trials(trials: int):
    """The thesis-like TCP cell of ``bench_tcp_thesis.py`` (2048² px at 0.021 mm/px, 12 poses rotated
    π/8, tip σ 0.25 px, robot 0.015 mm / 0.001° per axis with the pose model, camera position free,
    orientation known to 0.05°), through the report: the result file of each calibration
    (:func:`jcalib.report.tcp.tcp_result_file`) and the report's σ of the TCP per flange axis and of
    the tool tip in the base frame at the file's reference pose (TCP uncertainty only)."""
    import types

    from jcalib.problems.tcp import calibrate_tcp
    from jcalib.report import tcp as R

    path = Path(__file__).resolve().parent / "bench_tcp_thesis.py"
    spec = importlib.util.spec_from_file_location("_bench_tcp_thesis_consistency", path)
    B = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(B)
    cell = B.Cell(types.SimpleNamespace(mm_per_px=0.021, repeatability_mm=0.03, repeatability_sigmas=2.0,
                                        rotation_noise_deg=0.001, sigma_px=0.25, cad_error_mm=2.0))
    rng = np.random.default_rng(77)
    s = np.deg2rad(0.05)
    err, sig, solver = [], [], []
    for _ in range(trials):
        x_nom = cell.x + rng.normal(0.0, cell.cad_error, 3)
        T_cmd = B.joint_poses(cell, 12, x_nom)
        px = []
        for T in T_cmd:  # the robot reaches T_true, reports the commanded T
            R_true = T[:3, :3] @ B._rotvec(rng.normal(0.0, cell.sigma_r, 3))
            tip = R_true @ cell.x + T[:3, 3] + rng.normal(0.0, cell.sigma_t, 3)
            px.append(cell.project(tip) + rng.normal(0.0, cell.sigma_px, 2))
        T_cam0 = cell.T_base_cam.copy()
        T_cam0[:3, 3] += np.array([0.012, -0.01, 0.012])
        T_cam0[:3, :3] = T_cam0[:3, :3] @ B._rotvec(rng.normal(0.0, s, 3))
        cal = calibrate_tcp(cell.camera, T_cam0, T_cmd, np.stack(px), free_camera_pose=True,
                            T_base_cam_covariance=np.diag([s**2] * 3 + [np.inf] * 3)[None],
                            pose_noise_translation_m=cell.sigma_t,
                            pose_noise_rotation_deg=float(np.rad2deg(cell.sigma_r)), sigma_px=cell.sigma_px)
        file = R.tcp_result_file(cal, "tool", sigma_px=cell.sigma_px)
        tr = file.transforms["T_flange_tool"]
        Rb = np.asarray(file.extra[R.GRIP_REFERENCE_KEY])[:3, :3]
        e = cal.p_flange_tip - cell.x  # flange frame, m
        err.append(1e3 * np.concatenate([e, Rb @ e]))
        s_base = 1e3 * np.sqrt(np.diag(R.gripped_point_covariance(tr, file.extra[R.GRIP_REFERENCE_KEY])))
        sig.append(np.concatenate([R.tcp_std_mm(tr), s_base]))
        solver.append(np.concatenate([cal.tip_std_mm, 1e3 * np.sqrt(np.diag(Rb @ cal.tip_covariance @ Rb.T))]))
    labels = [f"TCP {a} (flange) [mm]" for a in "xyz"] + [f"tool tip {a} (base) [mm]" for a in "xyz"]
    return labels, np.array(err), np.array(sig), np.array(solver)


def report(title: str, labels, err, sig, solver=None) -> None:
    n = len(err)
    band = np.sqrt(stats.chi2(n).ppf([0.0005, 0.9995]) / n)
    print(f"\n## {title}  ({n} trials; 99.9 % sampling band of the ratio [{1 / band[1]:.3f}, {1 / band[0]:.3f}])")
    print("| unknown                        | empirical σ | report σ   | ratio | within ±15 % |   file/report | RMS/mean σ |")
    print("|--------------------------------|-------------|------------|-------|--------------|---------------|------------|")
    for k, lab in enumerate(labels):
        emp = float(np.sqrt(np.mean(err[:, k] ** 2)))
        rep = float(np.sqrt(np.mean(sig[:, k] ** 2)))
        ratio = rep / emp
        sol = "–" if solver is None else f"{float(np.sqrt(np.mean(solver[:, k] ** 2))) / rep:.4f}"
        spread = rep / float(np.mean(sig[:, k]))
        print(f"| {lab:<30} | {emp:11.4g} | {rep:10.4g} | {ratio:5.3f} | {'yes' if abs(ratio - 1) <= 0.15 else 'NO':<12} "
              f"| {sol:>13} | {spread:10.4f} |")


def report_prediction(labels, err, sig, predicted) -> None:
    n = len(err)
    band = np.sqrt(stats.chi2(n).ppf([0.0005, 0.9995]) / n)
    print(f"\n## what would help: one more tool-tip station (cam1/needle tip_x) predicted from one calibration vs "
          f"{n} calibrations with it (99.9 % band of empirical/predicted [{1 / band[1]:.3f}, {1 / band[0]:.3f}])")
    print("| unknown                        | predicted σ | empirical σ | report σ with it | empirical / predicted |")
    print("|--------------------------------|-------------|-------------|------------------|-----------------------|")
    for k, lab in enumerate(labels):
        emp = float(np.sqrt(np.mean(err[:, k] ** 2)))
        rep = float(np.sqrt(np.mean(sig[:, k] ** 2)))
        print(f"| {lab:<30} | {predicted[k]:11.4g} | {emp:11.4g} | {rep:16.4g} | {emp / predicted[k]:21.3f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--views", type=int, nargs="+", default=[10],
                        help="numbers of views of the intrinsics study (e.g. 10 20 40)")
    parser.add_argument("--skip-camera", action="store_true")
    parser.add_argument("--skip-handeye", action="store_true")
    parser.add_argument("--skip-cell", action="store_true")
    parser.add_argument("--skip-tcp", action="store_true")
    parser.add_argument("--predict", action="store_true", help="also check the what-would-help prediction")
    args = parser.parse_args()
    if not args.skip_camera:
        for views in args.views:
            t0 = time.perf_counter()
            report(f"intrinsics: 640x480, {views} views, σ 0.3 px, a-posteriori noise", *camera_trials(args.trials, views))
            print(f"({time.perf_counter() - t0:.0f} s)")
    if not args.skip_handeye:
        t0 = time.perf_counter()
        report("hand-eye (eye-in-hand, free intrinsics, robot pose model): 15 stations, 0.2 px, 0.1 mm / 0.01°",
               *handeye_trials(args.trials))
        print(f"({time.perf_counter() - t0:.0f} s)")
    if not args.skip_cell:
        t0 = time.perf_counter()
        report("whole cell (synthetic_cell: flange camera, fixed camera, board, needle; 12 + 14 stations, 0.2 px, "
               "robot 0.1 mm / 0.01°, pose model, variance components)", *cell_trials(args.trials))
        print(f"({time.perf_counter() - t0:.0f} s)")
    if args.predict:
        t0 = time.perf_counter()
        labels, err, sig, predicted = predict_trials(args.trials)
        report_prediction(labels, err, sig, predicted)
        print(f"({time.perf_counter() - t0:.0f} s)")
    if not args.skip_tcp:
        t0 = time.perf_counter()
        report("TCP (thesis-like: 2048² px, 12 poses, 0.25 px, robot 0.015 mm / 0.001°, camera position free)",
               *tcp_trials(args.trials))
        print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
