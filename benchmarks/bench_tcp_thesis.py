"""The TCP thesis' experiment in simulation: analytic three-pose method vs jcalib's joint TCP.

Toffano (2015) calibrates a TCP with a fixed camera: 2048x2048 px, ~0.021 mm/px at 300 mm, a robot
of +-0.03 mm repeatability, rotations of pi/8 about the camera z and x axes, each followed by a visual
servo that brings the tip back to the image centre; its closed form then gives the tip in the flange
(thesis eqs. 4.33/4.37/4.40, :func:`jcalib.init.tcp_analytic.tcp_three_pose`). The thesis reports
sigma = 0.059 / 0.089 / 0.068 mm per axis.

This script simulates both procedures over many trials with the same noise:

- robot: every reached flange pose differs from the reported one by a position error of sigma_t per
  axis (base frame) and an orientation error of sigma_r per axis (flange frame). "+-0.03 mm" is read
  as a +-2 sigma band per axis (sigma_t = 0.015 mm) unless ``--repeatability-sigmas`` says otherwise;
- tip detection: sigma_px per image coordinate. In the analytic procedure it is the servo's final
  error (the tip is where the detector says the image centre is); in the joint one it is the noise of
  each detected tip pixel.

Analytic: 3 poses exactly as in the thesis (initial; rotated by pi/8 about an axis parallel to the
camera z axis and servoed back; rotated by pi/8 about the camera x axis and servoed back), the true
camera orientation given (the thesis measures it beforehand).

Joint (:func:`jcalib.problems.tcp.calibrate_tcp`): at most 12 poses, each the initial orientation
rotated by pi/8 (the thesis' amplitude) about an axis 45 degrees from the viewing direction (12
azimuths), about the nominal (CAD, sigma 2 mm per axis off) TCP, plus a flange shift of up to 8 mm across the ray so
that the image measures distances. No servoing: the tip is detected wherever it is. The camera's
position is an unknown (started 20 mm off, no prior); its orientation is known to 0.05 degrees per
axis (a prior; the thesis measures it beforehand by flange translations, and its analytic method is
given it exactly here); the intrinsics are known. The robot's repeatability enters as the per-pose
flange correction model with the same sigma (:mod:`jcalib.problems.tcp`). A second joint row has
the camera pose fully unknown (orientation started 2 degrees off, no prior).

Prints per-axis sigma (flange frame, mm) of both methods over the trials, their ratio (target: joint
<= 0.5x analytic on every axis), the joint method's mean reported sigma (stated noise, and
a-posteriori) over the empirical sigma, and the mean NEES (chi2(3) mean 3).

    .venv/bin/python benchmarks/bench_tcp_thesis.py [--trials 200] [--poses 12] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

THESIS_SIGMA_MM = (0.059, 0.089, 0.068)


def _rotvec(w: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(w))
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * K @ K


class Cell:
    """Camera, tool and robot noise of the thesis' experiment."""

    def __init__(self, args):
        from jcalib.geometry.cameras import Pinhole

        self.size = 2048
        self.depth = 0.300
        self.f = self.depth / (args.mm_per_px * 1e-3)
        c = (self.size - 1) / 2.0
        self.camera = Pinhole((self.size, self.size), focal=(self.f, self.f), principal_point=(c, c))
        # the camera looks horizontally (along base +x, image y down) at a tool that points down
        # (flange z along base -z), so that the tool's silhouette is seen across its axis
        T = np.eye(4)
        T[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]) @ _rotvec(
            np.deg2rad(np.array([3.0, -4.0, 2.0])))
        T[:3, 3] = [0.5, 0.1, 0.4]
        self.T_base_cam = T
        self.x = np.array([0.012, -0.008, 0.165])  # true tip in the flange, m
        self.R0 = np.diag([1.0, -1.0, -1.0]) @ _rotvec(np.deg2rad(np.array([5.0, -3.0, 20.0])))
        self.P = T[:3, 3] + self.depth * T[:3, 2]  # image centre at 300 mm, base frame
        self.sigma_t = args.repeatability_mm * 1e-3 / args.repeatability_sigmas
        self.sigma_r = np.deg2rad(args.rotation_noise_deg)
        self.sigma_px = args.sigma_px
        self.cad_error = args.cad_error_mm * 1e-3
        self.angle = np.pi / 8

    def measured(self, R_true, t_true, rng):
        """Reported flange pose of a reached one: orientation error (flange frame), position error."""
        w = rng.normal(0.0, self.sigma_r, 3) if self.sigma_r > 0 else np.zeros(3)
        T = np.eye(4)
        T[:3, :3] = R_true @ _rotvec(w).T
        T[:3, 3] = t_true + rng.normal(0.0, self.sigma_t, 3)
        return T

    def project(self, p_base):
        import jax.numpy as jnp

        pc = (p_base - self.T_base_cam[:3, 3]) @ self.T_base_cam[:3, :3]
        return np.asarray(self.camera.project(jnp.asarray(pc)))


def analytic_trial(cell: Cell, rng) -> np.ndarray:
    """The thesis' three-pose procedure; returns the estimated tip (m)."""
    from jcalib.init.tcp_analytic import tcp_three_pose

    Rc = cell.T_base_cam[:3, :3]
    mpp = cell.depth / cell.f  # metres per pixel at the tip
    x_nom = cell.x + rng.normal(0.0, cell.cad_error, 3)
    Rs = [cell.R0, _rotvec(Rc[:, 2] * cell.angle) @ cell.R0, _rotvec(Rc[:, 0] * cell.angle) @ cell.R0]
    tips = []
    P_hat = cell.P  # the nominal TCP is put on the image centre first
    for k, R in enumerate(Rs):
        # rotation about the nominal TCP, then the servo: the tip ends on the centre pixel's ray
        # (only as well as the detector sees it) at the depth the rotation left it
        tip = P_hat + R @ (cell.x - x_nom)
        depth = (tip - cell.T_base_cam[:3, 3]) @ Rc[:, 2]
        on_ray = cell.T_base_cam[:3, 3] + depth * Rc[:, 2]
        lateral = Rc[:, :2] @ rng.normal(0.0, cell.sigma_px * mpp, 2)
        tips.append(on_ray + lateral)
    T_meas = []
    for R, tip in zip(Rs, tips):
        w = rng.normal(0.0, cell.sigma_r, 3) if cell.sigma_r > 0 else np.zeros(3)
        R_true = R @ _rotvec(w)  # the robot reports the commanded orientation R
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = tip - R_true @ cell.x + rng.normal(0.0, cell.sigma_t, 3)
        T_meas.append(T)
    return tcp_three_pose(np.stack(T_meas), Rc).p_flange_tip


def joint_poses(cell: Cell, n: int, x_nom: np.ndarray):
    """Commanded joint-method poses: rotations about the nominal TCP plus mm translations.

    Pose ``k`` is the initial orientation rotated by pi/8 about an axis 45 degrees from the viewing
    direction (azimuth ``k * 30`` degrees, alternately towards and away from the camera), so that
    every pose moves the tip both across and along the viewing ray; the rotation centre is the
    nominal TCP and each pose is shifted by up to 8 mm across the ray (the image measures
    distances through these known translations).
    """
    Rc = cell.T_base_cam[:3, :3]
    shifts_mm = [(0, 0), (8, 0), (-8, 0), (0, 8), (0, -8), (6, 6), (-6, -6), (6, -6), (-6, 6), (0, 0),
                 (8, 8), (-8, 8)]
    out = []
    for k in range(n):
        phi = k * np.pi / 6.0
        a = np.array([np.cos(phi) * np.sin(np.pi / 4), np.sin(phi) * np.sin(np.pi / 4),
                      np.cos(np.pi / 4) * (1.0 if k % 2 else -1.0)])
        R = _rotvec(Rc @ a * cell.angle) @ cell.R0
        shift = Rc[:, :2] @ (np.asarray(shifts_mm[k], float) * 1e-3)
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = cell.P + shift - R @ x_nom
        out.append(T)
    return np.stack(out)


def joint_trial(cell: Cell, n: int, rng, camera_rotation_prior_deg: float | None):
    """Joint TCP with the robot pose model; returns (tip error, cov a-posteriori, sigma2).

    The camera position is unknown (started 20 mm off, no prior). ``camera_rotation_prior_deg``: the
    camera orientation is known to this sigma per axis (the start is drawn from it and used as the
    prior mean); None: the orientation is unknown too (started 2 degrees off, no prior).
    """
    from jcalib.problems.tcp import calibrate_tcp

    x_nom = cell.x + rng.normal(0.0, cell.cad_error, 3)
    T_cmd = joint_poses(cell, n, x_nom)
    T_meas, px = [], []
    for T in T_cmd:
        # the robot reaches T_true and reports the commanded T
        w = rng.normal(0.0, cell.sigma_r, 3) if cell.sigma_r > 0 else np.zeros(3)
        R_true = T[:3, :3] @ _rotvec(w)
        t_true = T[:3, 3] + rng.normal(0.0, cell.sigma_t, 3)
        tip = R_true @ cell.x + t_true
        px.append(cell.project(tip) + rng.normal(0.0, cell.sigma_px, 2))
        T_meas.append(T)
    T_cam0 = cell.T_base_cam.copy()
    T_cam0[:3, 3] += np.array([0.012, -0.01, 0.012])
    cov = None
    if camera_rotation_prior_deg is None:
        T_cam0[:3, :3] = _rotvec(np.deg2rad(2.0) * np.array([0.6, -0.8, 0.0])) @ T_cam0[:3, :3]
    else:
        s = np.deg2rad(camera_rotation_prior_deg)
        T_cam0[:3, :3] = T_cam0[:3, :3] @ _rotvec(rng.normal(0.0, s, 3))
        cov = np.diag([s**2] * 3 + [np.inf] * 3)[None]  # orientation known, position free
    res = calibrate_tcp(
        cell.camera, T_cam0, np.stack(T_meas), np.stack(px),
        free_camera_pose=True,
        T_base_cam_covariance=cov,
        pose_noise_translation_m=cell.sigma_t,
        pose_noise_rotation_deg=float(np.rad2deg(cell.sigma_r)) if cell.sigma_r > 0 else None,
        sigma_px=cell.sigma_px,
    )
    return res.p_flange_tip - cell.x, res.tip_covariance, res.sigma2


def run_joint(cell: Cell, args, rng, camera_rotation_prior_deg):
    err, cov, s2 = [], [], []
    t0 = time.perf_counter()
    for _ in range(args.trials):
        e, c, v = joint_trial(cell, args.poses, rng, camera_rotation_prior_deg)
        err.append(e)
        cov.append(c)
        s2.append(v)
    return np.stack(err), np.stack(cov), np.asarray(s2), time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--poses", type=int, default=12, help="joint-method poses (<= 12)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--mm-per-px", type=float, default=0.021)
    ap.add_argument("--repeatability-mm", type=float, default=0.03, help="robot repeatability +- (mm)")
    ap.add_argument("--repeatability-sigmas", type=float, default=2.0,
                    help="how many sigma the +- band is (sigma_t = repeatability / this)")
    ap.add_argument("--rotation-noise-deg", type=float, default=0.001, help="flange orientation sigma per axis")
    ap.add_argument("--sigma-px", type=float, default=0.25, help="tip detection sigma per coordinate (px)")
    ap.add_argument("--camera-rotation-prior-deg", type=float, default=0.05,
                    help="sigma per axis of the camera orientation the joint method is given (the thesis "
                         "measures it by flange translations; its analytic method gets it exact)")
    ap.add_argument("--cad-error-mm", type=float, default=2.0, help="sigma of the nominal TCP error per axis")
    args = ap.parse_args()
    if not 3 <= args.poses <= 12:
        ap.error("--poses must be between 3 and 12")

    import jcalib  # noqa: F401  (float64)

    cell = Cell(args)
    rng = np.random.default_rng(args.seed)
    print(f"camera 2048x2048 px, f = {cell.f:.0f} px ({args.mm_per_px} mm/px at 300 mm); robot sigma_t = "
          f"{cell.sigma_t * 1e3:.4f} mm/axis (+-{args.repeatability_mm} mm as +-{args.repeatability_sigmas:g} sigma), "
          f"sigma_r = {args.rotation_noise_deg} deg/axis; tip sigma = {args.sigma_px} px; rotations pi/8; "
          f"{args.trials} trials")

    t0 = time.perf_counter()
    err_a = np.stack([analytic_trial(cell, rng) - cell.x for _ in range(args.trials)])
    t_a = time.perf_counter() - t0
    err_j, cov_j, s2_j, t_j = run_joint(cell, args, rng, args.camera_rotation_prior_deg)
    err_f, _, _, _ = run_joint(cell, args, rng, None)

    sd_a = 1e3 * err_a.std(axis=0, ddof=1)
    sd_j = 1e3 * err_j.std(axis=0, ddof=1)
    sd_f = 1e3 * err_f.std(axis=0, ddof=1)
    cov_stated = cov_j / s2_j[:, None, None]
    rep_ap = 1e3 * np.sqrt(np.diagonal(cov_j, axis1=1, axis2=2)).mean(axis=0)
    rep_st = 1e3 * np.sqrt(np.diagonal(cov_stated, axis1=1, axis2=2)).mean(axis=0)
    nees = np.einsum("ni,nij,nj->n", err_j, np.linalg.inv(cov_stated), err_j)
    # standard error of a sigma estimate from n samples: sigma / sqrt(2 (n - 1))
    se = 1.0 / np.sqrt(2.0 * (args.trials - 1))

    jl = f"joint ({args.poses} poses, cam. orient. {args.camera_rotation_prior_deg:g} deg)"
    print()
    print(f"{'':44s}{'x':>9s}{'y':>9s}{'z':>9s}   (flange frame, mm)")
    print(f"{'thesis (real robot, 3 poses)':44s}" + "".join(f"{v:9.3f}" for v in THESIS_SIGMA_MM))
    print(f"{'analytic sigma (3 poses, R_base_cam exact)':44s}" + "".join(f"{v:9.4f}" for v in sd_a))
    print(f"{'analytic mean error':44s}" + "".join(f"{v:9.4f}" for v in 1e3 * err_a.mean(axis=0)))
    print(f"{jl + ' sigma':44s}" + "".join(f"{v:9.4f}" for v in sd_j))
    print(f"{'joint mean error':44s}" + "".join(f"{v:9.4f}" for v in 1e3 * err_j.mean(axis=0)))
    print(f"{'joint / analytic sigma':44s}" + "".join(f"{v:9.3f}" for v in sd_j / sd_a)
          + f"   (target <= 0.5; each sigma +-{100 * se:.0f} % (1 s.e.))")
    print(f"{'joint reported / empirical sigma (stated)':44s}" + "".join(f"{v:9.3f}" for v in rep_st / sd_j))
    print(f"{'joint reported / empirical sigma (a-post.)':44s}" + "".join(f"{v:9.3f}" for v in rep_ap / sd_j))
    print(f"{'joint, camera pose fully unknown: sigma':44s}" + "".join(f"{v:9.4f}" for v in sd_f))
    print(f"{'  ... / analytic sigma':44s}" + "".join(f"{v:9.3f}" for v in sd_f / sd_a))
    print(f"joint NEES (stated covariance): mean {nees.mean():.3f} (chi2(3): 3), 95th percentile "
          f"{np.percentile(nees, 95):.2f} (chi2(3): 7.81); mean a-posteriori variance factor {s2_j.mean():.3f}")
    ok = bool(np.all(sd_j <= 0.5 * sd_a))
    print(f"target joint <= 0.5 x analytic on every axis: {'met' if ok else 'NOT met'}")
    print(f"time: analytic {1e3 * t_a / args.trials:.1f} ms/trial, joint {1e3 * t_j / args.trials:.1f} ms/trial "
          "(first trials include compilation)")


if __name__ == "__main__":
    main()
