"""Do the report's σ match the Monte-Carlo spread? Intrinsics (camera cell) and hand-eye.

Fixed geometry, fresh Gaussian corner noise (and robot pose noise for hand-eye) per trial, fixed
seeds. Each trial is calibrated with :func:`jcalib.calibrate` and the report's analysis
(:func:`jcalib.report.analysis.linear_models`, the σ the report's tables and warnings use) gives the
σ of every unknown. Printed per unknown: reported σ (RMS over trials), empirical σ (RMS error
against the truth), their ratio (target 0.85-1.15) and the sampling 99.9 % band of the ratio.

Run: ``.venv/bin/python benchmarks/bench_report_consistency.py [--trials 200] [--skip-handeye]``
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


def camera_trials(trials: int) -> tuple[list[str], np.ndarray, np.ndarray]:
    K = np.array([[800.0, 0, 330.0], [0, 805.0, 242.0], [0, 0, 1]])
    dist = np.array([-0.3, 0.12, 1e-3, -5e-4, -0.02])
    cam = camera_from_opencv(K, dist, (640, 480))
    views = random_calibration_views(cam, BOARD.points, 10, rng=3)
    clean = [project_target(cam, T, BOARD.points)[0] for T in views]
    cell = {"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv5"}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03}}}
    rng = np.random.default_rng(1003)
    truth = np.asarray(cam.params)
    err, sig = [], []
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
    return [u.label for u in model.unknowns], np.array(err), np.array(sig)


def handeye_trials(trials: int) -> tuple[list[str], np.ndarray, np.ndarray]:
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
    err, sig = [], []
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
    labels = [model.unknowns[i].label for i in intr + he]
    return labels, np.array(err), np.array(sig)


def report(title: str, labels, err, sig) -> None:
    n = len(err)
    band = np.sqrt(stats.chi2(n).ppf([0.0005, 0.9995]) / n)
    print(f"\n## {title}  ({n} trials; 99.9 % sampling band of the ratio [{1 / band[1]:.3f}, {1 / band[0]:.3f}])")
    print("| unknown                        | empirical σ | report σ   | ratio | within ±15 % |")
    print("|--------------------------------|-------------|------------|-------|--------------|")
    for k, lab in enumerate(labels):
        emp = float(np.sqrt(np.mean(err[:, k] ** 2)))
        rep = float(np.sqrt(np.mean(sig[:, k] ** 2)))
        ratio = rep / emp
        print(f"| {lab:<30} | {emp:11.4g} | {rep:10.4g} | {ratio:5.3f} | {'yes' if abs(ratio - 1) <= 0.15 else 'NO':<12} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--skip-handeye", action="store_true")
    args = parser.parse_args()
    t0 = time.perf_counter()
    report("intrinsics: 640x480, 10 views, σ 0.3 px, a-posteriori noise", *camera_trials(args.trials))
    print(f"({time.perf_counter() - t0:.0f} s)")
    if not args.skip_handeye:
        t0 = time.perf_counter()
        report("hand-eye (eye-in-hand, free intrinsics, robot pose model): 15 stations, 0.2 px, 0.1 mm / 0.01°",
               *handeye_trials(args.trials))
        print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
