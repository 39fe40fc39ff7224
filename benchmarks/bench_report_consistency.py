"""Do the report's σ match the Monte-Carlo spread? Intrinsics (camera cell), hand-eye and TCP.

Fixed geometry, fresh Gaussian corner noise (and robot pose noise for hand-eye / TCP) per trial,
fixed seeds. Each trial is calibrated and the report's analysis gives the σ of every unknown:
:func:`jcalib.report.analysis.linear_models` (intrinsics, hand-eye: the σ the report's tables and
warnings use) and :mod:`jcalib.report.tcp` on the result file of a TCP calibration (σ of the TCP
per flange axis, and of the tool tip in the base frame at the file's reference flange pose).
Printed per unknown: empirical σ (RMS error against the truth), reported σ (RMS over trials),
their ratio (target 0.85-1.15), the solver's own σ over the report's (the report rebuilds the
information itself: 1.000 means the same linear model) and the RMS over the mean of the reported σ
(1.00: the per-trial σ hardly vary, so their RMS is a fair summary).

The sampling 99.9 % band of a ratio printed with each table is what a *perfect* σ would show with
that many trials: at 200 trials it is about [0.86, 1.19], as wide as the ±15 % target, so single
ratios near 0.85 at 200 trials are not evidence of a bug; use ``--trials 1000`` (band about
±7 %) to judge an outlier.

Run: ``.venv/bin/python benchmarks/bench_report_consistency.py [--trials 200] [--views 10 20 40]
[--skip-handeye] [--skip-tcp]``
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path

import numpy as np
from scipy import stats

import jcalib
from jcalib.geometry import Checkerboard, camera_from_opencv, lie
from jcalib.report import analysis as A
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
        model = A.linear_models(result, obs)["cam"]
        err.append(np.asarray(result.file.cameras["cam"].params) - truth)
        sig.append(model.sigma())
        solver.append([result.file.cameras["cam"].std[u.coord] for u in model.unknowns])
    return [u.label for u in model.unknowns], np.array(err), np.array(sig), np.array(solver)


def handeye_trials(trials: int):
    path = Path(__file__).resolve().parents[1] / "tests" / "problems" / "test_handeye_joint.py"
    spec = importlib.util.spec_from_file_location("_handeye_joint_helpers_bench", path)
    T = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(T)
    H = T.H
    scene = np.random.default_rng(7)
    n = 15
    X, Y, T_bf, T_ct = H.make_scene(scene, n=n, mount="flange")
    T_ct, Y = T_ct @ T.FLIP, Y @ T.FLIP
    clean = [project_target(T.CAMERA, Tc, H.BOARD) for Tc in T_ct]
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025, "mount": "base"}},
            "robot": {"pose_noise": {"translation_m": 1e-4, "rotation_deg": 0.01}}}
    rng = np.random.default_rng(2024)
    err, sig, solver = [], [], []
    X7 = lie.se3_from_matrix(X)
    for _ in range(trials):
        T_meas = H.perturb_robot(T_bf, rng, sigma_m=1e-4, sigma_deg=0.01)
        stations = []
        for i, (pix, vis) in enumerate(clean):
            idx = np.flatnonzero(vis)
            noisy = pix[idx] + 0.2 * rng.standard_normal((len(idx), 2))
            stations.append({"id": f"s{i:03d}", "T_base_flange": T_meas[i].tolist(), "detections": [{
                "camera": "cam0", "target": "board", "point_index": idx.tolist(), "pixels": noisy.tolist()}]})
        obs = {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(T.IMAGE_SIZE)}},
               "targets": {"board": {"points": H.BOARD.tolist()}}, "stations": stations}
        result = jcalib.calibrate(cell, obs)
        model = A.linear_models(result, obs)["T_flange_cam0"]
        he = [i for i, u in enumerate(model.unknowns) if u.block == "T_flange_cam0"]
        intr = [i for i, u in enumerate(model.unknowns) if u.block == "cam0"]
        est = result.file.transforms["T_flange_cam0"].matrix
        delta = np.asarray(lie.local(lie.se3_from_matrix(est), X7))  # truth = est · Exp(δ)
        e_he = np.concatenate([np.degrees(delta[:3]), 1e3 * delta[3:]])
        e_in = np.asarray(result.file.cameras["cam0"].params) - T.TRUE_PARAMS
        err.append(np.concatenate([e_in, e_he]))
        s = model.sigma()
        sig.append(np.concatenate([s[intr], s[he]]))
        C = result.file.transforms["T_flange_cam0"].covariance
        solver.append(np.concatenate([[result.file.cameras["cam0"].std[model.unknowns[i].coord] for i in intr],
                                      np.degrees(np.sqrt(np.diag(C)[:3])), 1e3 * np.sqrt(np.diag(C)[3:])]))
    labels = [model.unknowns[i].label for i in intr + he]
    return labels, np.array(err), np.array(sig), np.array(solver)


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
    print("| unknown                        | empirical σ | report σ   | ratio | within ±15 % | solver/report | RMS/mean σ |")
    print("|--------------------------------|-------------|------------|-------|--------------|---------------|------------|")
    for k, lab in enumerate(labels):
        emp = float(np.sqrt(np.mean(err[:, k] ** 2)))
        rep = float(np.sqrt(np.mean(sig[:, k] ** 2)))
        ratio = rep / emp
        sol = "–" if solver is None else f"{float(np.sqrt(np.mean(solver[:, k] ** 2))) / rep:.4f}"
        spread = rep / float(np.mean(sig[:, k]))
        print(f"| {lab:<30} | {emp:11.4g} | {rep:10.4g} | {ratio:5.3f} | {'yes' if abs(ratio - 1) <= 0.15 else 'NO':<12} "
              f"| {sol:>13} | {spread:10.4f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--views", type=int, nargs="+", default=[10],
                        help="numbers of views of the intrinsics study (e.g. 10 20 40)")
    parser.add_argument("--skip-camera", action="store_true")
    parser.add_argument("--skip-handeye", action="store_true")
    parser.add_argument("--skip-tcp", action="store_true")
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
    if not args.skip_tcp:
        t0 = time.perf_counter()
        report("TCP (thesis-like: 2048² px, 12 poses, 0.25 px, robot 0.015 mm / 0.001°, camera position free)",
               *tcp_trials(args.trials))
        print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
