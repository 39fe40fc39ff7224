"""Triangulation: time per call (pixel-only vs camera uncertainty, one point vs batches), OpenCV
for reference, and Monte-Carlo consistency (NEES) of the reported covariance.

Three calibrated cameras (OpenCV5 lenses, two views share one camera) ~1.3 m from the points.
Prints: first-call time (compilation), then median time per call of ``triangulate_point``
(pixels only, and with intrinsics + pose covariances), ``triangulate_points`` for M points at once,
``cv2.triangulatePoints`` + ``cv2.undistortPoints`` (two views, no refinement, no covariance);
then the mean NEES (should be 3) and the fraction inside the 95 % chi2(3) ellipsoid (should be 0.95)
with pixel noise only and with pixel + camera errors.

    .venv/bin/python benchmarks/bench_triangulation.py [--trials 500] [--batch 50] [--runs 50]
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=500, help="Monte-Carlo trials")
    ap.add_argument("--batch", type=int, default=50, help="points per triangulate_points call")
    ap.add_argument("--runs", type=int, default=50, help="timing repetitions")
    args = ap.parse_args()

    import cv2
    from scipy.stats import chi2

    import jcalib  # noqa: F401  (float64)
    from jcalib.geometry.cameras import camera_from_opencv
    from jcalib.geometry.lie import se3_exp, se3_to_matrix
    from jcalib.init.triangulation import triangulate_point, triangulate_points

    size = (1280, 1024)
    K = [np.array([[1200.0, 0, 640], [0, 1200, 512], [0, 0, 1]]), np.array([[900.0, 0, 650], [0, 905, 500], [0, 0, 1]])]
    D = [np.array([-0.25, 0.1, 0.0008, -0.0006, -0.02]), np.array([-0.1, 0.02, 0.0, 0.0, 0.0])]
    sig_k = np.array([1.5, 1.5, 1.2, 1.2, 2e-3, 4e-3, 1e-4, 1e-4, 5e-3])
    sig_pose = np.array([4e-4, 4e-4, 4e-4, 3e-4, 3e-4, 3e-4])
    sigma_px = 0.3

    def look_at(c, t, roll):
        z = t - c
        z /= np.linalg.norm(z)
        x = np.cross([np.sin(roll), np.cos(roll), 0.3], z)
        x /= np.linalg.norm(x)
        T = np.eye(4)
        T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
        T[:3, 3] = c
        return T

    aim = np.array([0.1, 0.0, 0.0])
    T_base_cam = np.stack([look_at(np.array([-0.6, 0.1, -1.2]), aim, 0.1),
                           look_at(np.array([0.7, -0.2, -1.1]), aim, -0.2),
                           look_at(np.array([0.1, 0.8, -1.0]), aim, 0.4)])  # fmt: skip
    view_k = [0, 0, 1]

    def project(i, X):
        T = np.linalg.inv(T_base_cam[i])
        return cv2.projectPoints(X.reshape(-1, 3), cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K[view_k[i]],
                                 D[view_k[i]])[0].reshape(-1, 2)  # fmt: skip

    rng = np.random.default_rng(0)
    X = np.array([0.05, -0.02, 0.03])
    px_true = np.stack([project(i, X)[0] for i in range(3)])
    models = [camera_from_opencv(K[k], D[k], size) for k in range(2)]
    cams = [models[k] for k in view_k]
    cov_k = np.diag(sig_k**2)
    cov_pose = np.tile(np.diag(sig_pose**2), (3, 1, 1))
    batch = rng.uniform(-0.1, 0.1, (args.batch, 3)) + aim
    px_batch = np.stack([project(i, batch) for i in range(3)], axis=1)

    def timed(fn, runs):
        t0 = time.perf_counter()
        fn()
        first = time.perf_counter() - t0
        ts = []
        for _ in range(runs):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        return first, float(np.median(ts))

    rows = [
        ("triangulate_point, pixels only", 1, lambda: triangulate_point(cams, px_true, T_base_cam=T_base_cam)),
        ("triangulate_point, + intrinsics & poses", 1,
         lambda: triangulate_point(cams, px_true, T_base_cam=T_base_cam, intrinsics_covariance=[cov_k] * 3,
                                   pose_covariance=cov_pose)),
        (f"triangulate_points, M = {args.batch}", args.batch,
         lambda: triangulate_points(cams, px_batch, T_base_cam=T_base_cam, intrinsics_covariance=[cov_k] * 3,
                                    pose_covariance=cov_pose)),
    ]  # fmt: skip
    T_cb = [np.linalg.inv(T) for T in T_base_cam[:2]]

    def opencv():
        xn = [cv2.undistortPoints(px_true[i].reshape(1, 1, 2), K[view_k[i]], D[view_k[i]]).reshape(2, 1) for i in range(2)]
        cv2.triangulatePoints(T_cb[0][:3], T_cb[1][:3], xn[0], xn[1])

    print(f"{'call':44s} {'first (s)':>10s} {'median (ms)':>12s} {'per point (ms)':>15s}")
    for name, m, fn in rows:
        first, med = timed(fn, args.runs)
        print(f"{name:44s} {first:10.3f} {med * 1e3:12.3f} {med * 1e3 / m:15.4f}")
    first, med = timed(opencv, args.runs)
    print(f"{'cv2.undistortPoints + triangulatePoints (2)':44s} {first:10.3f} {med * 1e3:12.3f} {med * 1e3:15.4f}")

    print(f"\nMonte Carlo, {args.trials} trials, sigma_px = {sigma_px}, 3 views (chi2(3): mean 3, 95 % inside)")
    print(f"{'errors drawn':28s} {'covariance reported':34s} {'mean NEES':>10s} {'inside 95 %':>12s}")
    q95 = chi2.ppf(0.95, 3)
    for camera_errors in (False, True):
        nees = {"pixels only": [], "pixels + intrinsics + poses": []}
        for _ in range(args.trials):
            if camera_errors:
                est = []
                for k in range(2):
                    e = sig_k * rng.standard_normal(9)
                    Ke = K[k].copy()
                    Ke[0, 0] += e[0]
                    Ke[1, 1] += e[1]
                    Ke[0, 2] += e[2]
                    Ke[1, 2] += e[3]
                    est.append(camera_from_opencv(Ke, D[k] + e[4:], size))
                cams_e = [est[k] for k in view_k]
                poses = np.stack([T @ np.asarray(se3_to_matrix(se3_exp(sig_pose * rng.standard_normal(6))))
                                  for T in T_base_cam])  # fmt: skip
            else:
                cams_e, poses = cams, T_base_cam
            px = px_true + sigma_px * rng.standard_normal(px_true.shape)
            res = triangulate_point(cams_e, px, T_base_cam=poses, sigma_px=sigma_px,
                                    intrinsics_covariance=[cov_k] * 3, pose_covariance=cov_pose)  # fmt: skip
            e = res.p_base - X
            nees["pixels only"].append(e @ np.linalg.solve(res.covariance_px, e))
            nees["pixels + intrinsics + poses"].append(e @ np.linalg.solve(res.covariance, e))
        drawn = "pixels + intrinsics + poses" if camera_errors else "pixels only"
        for reported, v in nees.items():
            v = np.asarray(v)
            print(f"{drawn:28s} {reported:34s} {v.mean():10.2f} {np.mean(v < q95):12.3f}")


if __name__ == "__main__":
    main()
