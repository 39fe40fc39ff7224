"""Robot kinematic calibration inside the joint problem: accuracy against the nominal model, consistency
of the reported σ, and a positioner measured by a pose sensor.

Part 1, a simulated 6-axis arm (``kuka_kr10_r1100_sixx``, ``jcalib.sim.kinematic_cells.synthetic_arm_cell``)
whose joint offsets, link lengths and twists differ from the nominal by realistic errors (σ 0.05°,
0.5 mm, 0.05°, on the identifiable parameters), a camera on the flange (opencv5, 1600x1200) seeing a 9x6
board fixed in the base, ``--stations`` stations (default 30) at 0.2 px, repeatability 0.02 mm / 0.002°,
and ``--heldout`` held-out stations (default 20) per trial, ``--trials`` trials (default 50). Per trial
the same observations are calibrated
  - with the kinematics calibrated (``calibrate_kinematics: [joint_offsets, link_lengths, twists]``);
  - with today's per-station pose-noise model and the nominal kinematics (the controller's flange
    poses), stating the robot's pose error as 0.1 mm / 0.01° (a repeatability-like figure) and as
    0.5 mm / 0.05° (an accuracy-like figure).
Held-out error: the position of the flange camera in the board frame predicted at the held-out joint
values (``T_base_board⁻¹ · FK(q) · T_flange_cam0``, each model with its own estimates) against the truth;
gauge-free, and what a cell would get wrong when it moves to a new pose. Median over held-out stations
and trials. Hand-eye error: ``T_flange_cam0`` translation against the truth, RMS over trials. χ²: the
recovered free kinematic parameters against the truth with their reported covariance; the sum over
trials is χ²(trials · dof), its two-sided 99 % interval printed beside it.

Part 2, a 2-axis positioner (``positioner_2axis``) carrying a target whose pose a fixed 6-DOF sensor
measures (``synthetic_positioner_cell``): noiseless (errors 20x the realistic σ): largest error of the
identifiable DH parameters, of the sensor pose and of the target pose; noisy (sensor 0.005° / 0.02 mm):
held-out error of the target position in the sensor frame, calibrated against nominal.

Part 3: wall time of one kinematic calibration (first call in the process, which compiles, and later).

Run: ``.venv/bin/python benchmarks/bench_kinematics.py [--trials 50] [--stations 30] [--heldout 20]``
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np
from scipy import stats

from jcalib.geometry import kinematic_models
from jcalib.geometry.se3 import invert
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.problems import CalibrationOptions, calibrate_cell
from jcalib.problems.kinematics import generic_joints, select_parameters
from jcalib.sim.kinematic_cells import synthetic_arm_cell, synthetic_positioner_cell

GROUPS = ("joint_offsets", "link_lengths", "twists")


def structural_mask(preset: str) -> np.ndarray:
    model = kinematic_models.PRESETS[preset]()
    return select_parameters(model, GROUPS, generic_joints(model), np.eye(6) * 1e4, "robot").free


def calibrate(cell, obs):
    return calibrate_cell(parse_cell(cell), parse_observations(obs), CalibrationOptions())


def rotation_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def part1(args) -> None:
    preset = "kuka_kr10_r1100_sixx"
    model = kinematic_models.PRESETS[preset]()
    mask = structural_mask(preset)
    rows = {"kinematics calibrated": [], "pose noise 0.1 mm / 0.01°": [], "pose noise 0.5 mm / 0.05°": []}
    he = {k: [] for k in rows}
    chi2, dof, times = [], int(mask.sum()), []
    for trial in range(args.trials):
        cell, obs, truth = synthetic_arm_cell(1000 + trial, args.stations, args.heldout, error_mask=mask)
        q = truth["heldout"]["q"]
        true = invert(truth["T_base_board"]) @ truth["heldout"]["T_base_flange"] @ truth["T_flange_cam0"]
        variants = {"kinematics calibrated": cell}
        for key, (t, r) in (("pose noise 0.1 mm / 0.01°", (1e-4, 0.01)), ("pose noise 0.5 mm / 0.05°", (5e-4, 0.05))):
            c = copy.deepcopy(cell)
            del c["robot"]["calibrate_kinematics"]
            c["robot"]["pose_noise"] = {"translation_m": t, "rotation_deg": r}
            variants[key] = c
        for key, c in variants.items():
            t0 = time.perf_counter()
            cal = calibrate(c, obs)
            if key == "kinematics calibrated":
                times.append(time.perf_counter() - t0)
                k = cal.kinematics["robot"]
                params = k["params"]
                free = k["free"]
                e = (params - truth["params"])[free]
                C = np.asarray(k["covariance"])[np.ix_(free, free)]
                chi2.append(float(e @ np.linalg.solve(C, e)))
            else:
                params = truth["nominal"]
            T_bf = np.asarray(kinematic_models.forward(model, params, q))
            pred = invert(cal.transforms["T_base_board"]) @ T_bf @ cal.transforms["T_flange_cam0"]
            rows[key].append(np.linalg.norm(pred[:, :3, 3] - true[:, :3, 3], axis=1))
            he[key].append(np.linalg.norm(cal.transforms["T_flange_cam0"][:3, 3] - truth["T_flange_cam0"][:3, 3]))
        print(f"  trial {trial + 1}/{args.trials}", end="\r", flush=True)
    print()
    base = np.median(np.concatenate(rows["pose noise 0.5 mm / 0.05°"]))
    base_he = float(np.sqrt(np.mean(np.square(he["pose noise 0.5 mm / 0.05°"]))))
    print(f"Part 1: {preset}, {args.stations} stations, {args.heldout} held-out, {args.trials} trials, 0.2 px")
    print("| model | held-out camera position error, median mm | 95th pct mm | ratio to nominal (0.5 mm) "
          "| hand-eye translation error RMS mm | ratio |")
    print("|---|---|---|---|---|---|")
    for key in rows:
        e = np.concatenate(rows[key])
        h = float(np.sqrt(np.mean(np.square(he[key]))))
        print(f"| {key} | {1e3 * np.median(e):.4f} | {1e3 * np.percentile(e, 95):.4f} | {np.median(e) / base:.3f} "
              f"| {1e3 * h:.4f} | {h / base_he:.3f} |")
    total, n = float(np.sum(chi2)), len(chi2) * dof
    lo, hi = stats.chi2.ppf([0.005, 0.995], n)
    print(f"χ² of the {dof} free parameters over {len(chi2)} trials: {total:.1f} (dof {n}, 99 % interval "
          f"[{lo:.1f}, {hi:.1f}]); mean per trial {np.mean(chi2):.2f} vs {dof}")
    print(f"kinematic calibration wall time: first {times[0]:.2f} s, median of the others "
          f"{np.median(times[1:]) if len(times) > 1 else float('nan'):.2f} s")


def part2(args) -> None:
    mask = structural_mask("positioner_2axis")
    model = kinematic_models.PRESETS["positioner_2axis"]()
    cell, obs, truth = synthetic_positioner_cell(7, 24, 4, sigma_deg=0.0, sigma_m=0.0, scatter=False, error_mask=mask,
                                                 error_scale=20.0)
    cal = calibrate(cell, obs)
    k = cal.kinematics["robot"]
    dp = np.abs(k["params"] - truth["params"])[k["free"]]
    errs = {}
    for n in ("T_base_tracker", "T_flange_part"):
        D = invert(truth[n]) @ cal.transforms[n]
        errs[n] = (np.linalg.norm(D[:3, 3]), np.radians(rotation_deg(D[:3, :3])))
    print(f"\nPart 2: positioner_2axis + fixed pose sensor, noiseless, 24 stations; free: "
          f"{', '.join(np.array(truth['names'])[k['free']])}")
    print("| quantity | largest error |")
    print("|---|---|")
    print(f"| DH parameters (m, rad) | {dp.max():.2e} |")
    for n, (t, r) in errs.items():
        print(f"| {n} translation m / rotation rad | {t:.2e} / {r:.2e} |")
    e_cal, e_nom = [], []
    for trial in range(max(args.trials // 5, 5)):
        cell, obs, truth = synthetic_positioner_cell(2000 + trial, 24, args.heldout, error_mask=mask)
        cal = calibrate(cell, obs)
        base = copy.deepcopy(cell)
        del base["robot"]["calibrate_kinematics"]
        base["robot"]["pose_noise"] = {"translation_m": 5e-4, "rotation_deg": 0.05}
        nom = calibrate(base, obs)
        q = truth["heldout"]["q"]
        true = invert(truth["T_base_tracker"]) @ truth["heldout"]["T_base_flange"] @ truth["T_flange_part"]
        for c, p, out in ((cal, cal.kinematics["robot"]["params"], e_cal), (nom, truth["nominal"], e_nom)):
            pred = invert(c.transforms["T_base_tracker"]) @ np.asarray(kinematic_models.forward(model, p, q)) \
                @ c.transforms["T_flange_part"]
            out.append(np.linalg.norm(pred[:, :3, 3] - true[:, :3, 3], axis=1))
    a, b = np.median(np.concatenate(e_cal)), np.median(np.concatenate(e_nom))
    print("\n| positioner, sensor 0.005° / 0.02 mm | held-out target position error, median mm |")
    print("|---|---|")
    print(f"| kinematics calibrated | {1e3 * a:.4f} |")
    print(f"| nominal kinematics, pose noise 0.5 mm / 0.05° | {1e3 * b:.4f} |")
    print(f"| ratio | {a / b:.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--stations", type=int, default=30)
    ap.add_argument("--heldout", type=int, default=20)
    args = ap.parse_args()
    part1(args)
    part2(args)


if __name__ == "__main__":
    main()
