"""Zoom lenses: one joint calibration over the lens's settings against per-setting calibrations
interpolated linearly between settings (today's practice), at the same images.

The simulated cell (:func:`jcalib.sim.zoom.synthetic_zoom_cell`): an eye-in-hand camera with the simulated
motorised zoom lens (:class:`jcalib.sim.zoom.ZoomLensModel`: focal length 1x-6x over Zoom 0..1000, k1 from
barrel to pincushion, principal point drift, entrance pupil 20 mm forward), a fixed 0.35 m x 0.25 m checkerboard
(``--square``, default 12.5 mm: 28x20 corners, so the narrow tele views keep enough of them), ``--stations`` robot stations (exact flange poses), each captured at every captured setting;
corner noise ``--sigma-px``. Eleven settings 100..900 (step 80); ``--held-out`` of them are left out of
both fits and predicted.

- joint: the cell with ``lens: {settings: [Zoom]}`` (the default cubic): ``Result.camera_at`` at each
  setting (intrinsics, ``T_flange_cam0`` and their covariances);
- per-setting: one ordinary hand-eye calibration per captured setting (its stations only), intrinsics
  and hand-eye interpolated linearly in the setting between the two neighbouring captured settings
  (translation linearly, rotation by slerp).

Per trial (a fresh noise draw, the same stations) and setting: the projection error of the predicted
camera against the truth (RMS over a 16x12 pixel grid covering the image of the distance between each
pixel and the predicted camera's projection of the true ray there, px: intrinsics only) and the hand-eye
error against the true camera frame at that setting (translation mm, rotation deg). The tables give RMS
over trials; "ratio" = per-setting / joint. The joint model's σ are tested by Monte Carlo: the
Mahalanobis distance d² of the hand-eye error (6 dof) and of the intrinsics error (9 dof) with the
reported covariance, whose mean over trials should be the dof (and 95 % of them inside the χ² 95 % quantile).

Run: ``.venv/bin/python benchmarks/bench_zoom.py [--trials 20] [--stations 8]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

SETTINGS_ALL = tuple(float(s) for s in range(100, 901, 80))


def interpolate(values: dict[float, object], s: float, pose: bool):
    from jcalib.geometry.se3 import interpolate_pose

    keys = sorted(values)
    j = int(np.clip(np.searchsorted(keys, s) - 1, 0, len(keys) - 2))
    a, b = keys[j], keys[j + 1]
    t = (s - a) / (b - a)
    if pose:
        return interpolate_pose(values[a], values[b], t)
    return (1 - t) * values[a] + t * values[b]


#: Working distance (m): the stations see the board from 0.28-0.42 m.
WORKING_DISTANCE_M = 0.35


def pose_error(T_est, T_true) -> tuple[np.ndarray, float, float, float]:
    """``(δ (6,), translation mm, rotation deg, mm at the working distance)`` with ``T_true = T_est · Exp(δ)``;
    the last is the displacement in the flange frame of the point on the optical axis at the working distance
    (where the hand-eye places what the camera sees: its translation and rotation errors together)."""
    from jcalib.geometry.se3 import invert, log_se3

    d = log_se3(invert(T_est) @ T_true)
    p = np.array([0.0, 0.0, WORKING_DISTANCE_M, 1.0])
    wd = float(np.linalg.norm((T_est @ p - T_true @ p)[:3]) * 1e3)
    return d, float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]) * 1e3), float(np.degrees(np.linalg.norm(d[:3]))), wd


def trial(seed: int, args, captured, held_out) -> dict:
    import jcalib
    from jcalib.sim.zoom import heldout_projection_rms_px, mount_at, synthetic_zoom_cell

    cell, obs, truth = synthetic_zoom_cell(seed, settings=captured, num_stations=args.stations, sigma_px=args.sigma_px,
                                           square=args.square)
    lens = truth["lens"]
    t0 = time.perf_counter()
    joint = jcalib.calibrate(cell, obs)
    t_joint = time.perf_counter() - t0
    per_params, per_pose = {}, {}
    t0 = time.perf_counter()
    plain = {**cell, "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}}}
    for s in captured:
        sub = {**obs, "stations": [st for st in obs["stations"] if st["lens"]["cam0"]["Zoom"] == s]}
        r = jcalib.calibrate(plain, sub)
        per_params[s] = np.asarray(r.file.cameras["cam0"].params)
        per_pose[s] = np.asarray(r.file.transforms["T_flange_cam0"].matrix)
    t_per = time.perf_counter() - t0
    out = {"time_joint": t_joint, "time_per": t_per, "rows": []}
    for s in sorted(set(captured) | set(held_out)):
        T_true = mount_at(truth["T_flange_cam0_wide"], lens, s)
        cam, T = joint.camera_at("cam0", Zoom=s)
        d, tmm, rdeg, wd = pose_error(T.matrix, T_true)
        C = np.asarray(cam.covariance)
        e = np.asarray(cam.params) - lens.params(s)
        free = np.diag(C) > 0
        row = {"setting": s, "held_out": s in held_out,
               "joint_px": heldout_projection_rms_px(lens, s, cam.params), "joint_mm": tmm, "joint_deg": rdeg, "joint_wd": wd,
               "d2_pose": float(d @ np.linalg.solve(T.covariance, d)),
               "d2_intr": float(e[free] @ np.linalg.solve(C[np.ix_(free, free)], e[free])), "dof_intr": int(free.sum()),
               "max_z_pose": float(np.max(np.abs(d) / np.sqrt(np.diag(T.covariance))))}
        p_lin = per_params[s] if s in per_params else interpolate(per_params, s, False)
        T_lin = per_pose[s] if s in per_pose else interpolate(per_pose, s, True)
        _, tmm, rdeg, wd = pose_error(T_lin, T_true)
        row.update(per_px=heldout_projection_rms_px(lens, s, p_lin), per_mm=tmm, per_deg=rdeg, per_wd=wd)
        out["rows"].append(row)
    return out


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=20, help="noise draws (default 20)")
    parser.add_argument("--stations", type=int, default=8, help="robot stations, each at every captured setting")
    parser.add_argument("--sigma-px", type=float, default=0.2, help="corner noise σ (px)")
    parser.add_argument("--square", type=float, default=0.0125, help="checkerboard square (m); the board is about "
                                                                   "0.35 m x 0.25 m whatever the square")
    parser.add_argument("--held-out", type=float, nargs="+", default=[260.0, 500.0, 740.0],
                        help="settings left out of the fits (among 100, 180, ..., 900)")
    args = parser.parse_args()
    from scipy.stats import chi2

    held_out = sorted(float(s) for s in args.held_out)
    captured = [s for s in SETTINGS_ALL if s not in held_out]
    print(f"zoom lens 1x-6x (Zoom 0..1000), captured {[int(s) for s in captured]}, held out {[int(s) for s in held_out]}; "
          f"{args.stations} stations x {len(captured)} settings = {args.stations * len(captured)} images per fit; "
          f"σ {args.sigma_px} px; {args.trials} trials")
    trials = [trial(seed, args, captured, held_out) for seed in range(args.trials)]
    rows = [r for t in trials for r in t["rows"]]
    print(f"time per trial (s, after the first): joint {np.median([t['time_joint'] for t in trials[1:] or trials]):.1f}, "
          f"per-setting (all {len(captured)}) {np.median([t['time_per'] for t in trials[1:] or trials]):.1f}")
    print()
    print("RMS over trials; px: projection error of the predicted camera vs truth over the image; hand-eye: mm "
          f"(translation), deg (rotation), wd mm (the point on the optical axis at {WORKING_DISTANCE_M} m)")
    head = (f"{'Zoom':>6} {'held':>5} {'joint px':>9} {'per px':>8} {'ratio':>6} {'joint mm':>9} {'per mm':>8} "
            f"{'ratio':>6} {'joint deg':>9} {'per deg':>8} {'ratio':>6} {'joint wd':>9} {'per wd':>8} {'ratio':>6}")
    print(head)
    summary = {}
    for s in sorted({r["setting"] for r in rows}):
        sel = [r for r in rows if r["setting"] == s]
        v = {k: rms([r[k] for r in sel]) for k in ("joint_px", "per_px", "joint_mm", "per_mm", "joint_deg", "per_deg",
                                                 "joint_wd", "per_wd")}
        summary[s] = v
        print(f"{int(s):>6} {'yes' if sel[0]['held_out'] else '':>5} {v['joint_px']:>9.3f} {v['per_px']:>8.3f} "
              f"{v['per_px'] / v['joint_px']:>6.1f} {v['joint_mm']:>9.3f} {v['per_mm']:>8.3f} "
              f"{v['per_mm'] / v['joint_mm']:>6.1f} {v['joint_deg']:>9.4f} {v['per_deg']:>8.4f} "
              f"{v['per_deg'] / v['joint_deg']:>6.1f} {v['joint_wd']:>9.3f} {v['per_wd']:>8.3f} "
              f"{v['per_wd'] / v['joint_wd']:>6.1f}")
    held = [r for r in rows if r["held_out"]]
    jp, pp = rms([r["joint_px"] for r in held]), rms([r["per_px"] for r in held])
    jm, pm = rms([r["joint_mm"] for r in held]), rms([r["per_mm"] for r in held])
    jd, pd = rms([r["joint_deg"] for r in held]), rms([r["per_deg"] for r in held])
    jw, pw = rms([r["joint_wd"] for r in held]), rms([r["per_wd"] for r in held])
    print(f"{'held-out':>12} {jp:>9.3f} {pp:>8.3f} {pp / jp:>6.1f} {jm:>9.3f} {pm:>8.3f} {pm / jm:>6.1f} {jd:>9.4f} "
          f"{pd:>8.4f} {pd / jd:>6.1f} {jw:>9.3f} {pw:>8.3f} {pw / jw:>6.1f}")
    print()
    print("Monte Carlo test of the joint model's σ (all settings, all trials): mean d² / dof (1 expected), share "
          "inside the χ² 95 % quantile (0.95 expected), worst hand-eye coordinate |error| / σ")
    n = len(rows)
    for what, key, dof in (("hand-eye (6 dof)", "d2_pose", 6), ("intrinsics", "d2_intr", rows[0]["dof_intr"])):
        d2 = np.array([r[key] for r in rows])
        inside = float(np.mean(d2 < chi2.ppf(0.95, dof)))
        lo, hi = chi2.ppf([0.025, 0.975], n * dof) / (n * dof)
        print(f"  {what:<18} mean d²/dof {d2.mean() / dof:.2f} (95 % band for {n} draws if independent: "
              f"{lo:.2f}-{hi:.2f}), inside {inside:.2f}")
    worst = max(r["max_z_pose"] for r in rows)
    print(f"  hand-eye worst |error|/σ over every setting and trial: {worst:.2f}; settings with one beyond 3σ: "
          f"{sum(r['max_z_pose'] > 3 for r in rows)} of {n}")
    print()
    print(f"acceptance: held-out projection ≤ 0.3 px: {jp:.3f} px -> {'met' if jp <= 0.3 else 'NOT met'}; "
          f"≥ 3x smaller than per-setting: {pp / jp:.1f}x -> {'met' if pp / jp >= 3 else 'NOT met'}; "
          f"held-out hand-eye ≥ 2x smaller: translation {pm / jm:.1f}x -> {'met' if pm / jm >= 2 else 'NOT met'}, "
          f"rotation {pd / jd:.1f}x -> {'met' if pd / jd >= 2 else 'NOT met'}, at the working distance {pw / jw:.1f}x -> "
          f"{'met' if pw / jw >= 2 else 'NOT met'}")


if __name__ == "__main__":
    main()
