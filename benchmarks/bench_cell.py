"""Whole-cell joint solve vs sequential calibration (intrinsics, then hand-eye, then TCP), and the
re-optimisation false-alarm rate on unchanged cells.

Cell (:func:`jcalib.sim.cells.synthetic_cell`): flange camera cam0, fixed camera cam1 (intrinsics
known), fixed board, tool tip seen by cam1; 0.2 px corners and tips, robot 0.1 mm / 0.01°.
Sequential: cam0 intrinsics (camera-only cell, board as a free target), hand-eye with those intrinsics
held (robot pose model on), T_base_cam1 = T_base_board · PnP(cam1), TCP from the tips with the
camera pose held (robot pose model on, :func:`jcalib.calibrate_tcp`); each step a cell of the one
builder. Joint: the whole cell at once (:func:`jcalib.calibrate_cell`). The false-alarm rate: a cell
calibrated once (the old result), then unchanged cells calibrated from it and compared by
:func:`jcalib.problems.reoptimise.compare_results`.

    .venv/bin/python benchmarks/bench_cell.py --trials 50 --repeats 100
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def _errors(T, T_true):
    dR = T[:3, :3].T @ T_true[:3, :3]
    ang = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
    return ang, 1e3 * np.linalg.norm(T[:3, 3] - T_true[:3, 3])


def sequential(cell, obs):
    import cv2

    import jcalib
    from jcalib.io.cell import load_cell
    from jcalib.io.observations import load_observations

    board_obs = dict(obs, stations=[dict(s, detections=[d for d in s["detections"] if d["camera"] == "cam0"])
                                    for s in obs["stations"] if any(d["camera"] == "cam0" for d in s["detections"])])
    free = {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5"}},
            "targets": {"board": dict(cell["targets"]["board"], mount="free")}}
    intr = jcalib.calibrate_cell(load_cell(free), load_observations(board_obs), jcalib.CalibrationOptions(sigma_px=0.2))
    K, dist = (np.asarray(a) for a in intr.cameras["cam0"].to_opencv())
    he_cell = {"schema": "jcalib.cell/1", "robot": cell["robot"],
               "cameras": {"cam0": {"model": "opencv5", "mount": "flange", "intrinsics": {"K": K.tolist(), "dist": dist.tolist()},
                                    "fix": ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]}},
               "targets": {"board": cell["targets"]["board"]}}
    he = jcalib.calibrate_cell(load_cell(he_cell), load_observations(board_obs), jcalib.CalibrationOptions(sigma_px=0.2))
    T_base_board = he.transforms["T_base_board"]
    pts = np.asarray(obs["targets"]["board"]["points"])
    K1 = np.asarray(cell["cameras"]["cam1"]["intrinsics"]["K"])
    d1 = np.asarray(cell["cameras"]["cam1"]["intrinsics"]["dist"])
    P, U = [], []
    for s in obs["stations"]:
        for d in s["detections"]:
            if d["camera"] == "cam1" and d.get("target") == "board":
                P.append(pts[d["point_index"]])
                U.append(np.asarray(d["pixels"]))
    ok, rvec, tvec = cv2.solvePnP(np.concatenate(P), np.concatenate(U), K1, d1, flags=cv2.SOLVEPNP_ITERATIVE)
    T_c1_b = np.eye(4)
    T_c1_b[:3, :3] = cv2.Rodrigues(rvec)[0]
    T_c1_b[:3, 3] = tvec.ravel()
    T_base_cam1 = T_base_board @ np.linalg.inv(T_c1_b)
    tips = [(np.asarray(s["T_base_flange"]), d["pixel"]) for s in obs["stations"] for d in s["detections"] if d.get("tool")]
    from jcalib.geometry.cameras import camera_from_opencv

    cam1 = camera_from_opencv(K1, d1, tuple(obs["cameras"]["cam1"]["image_size"]))
    noise = cell["robot"]["pose_noise"]
    tcp = jcalib.calibrate_tcp(cam1, T_base_cam1, np.stack([t[0] for t in tips]), np.asarray([t[1] for t in tips]),
                               sigma_px=0.2, pose_noise_translation_m=noise["translation_m"],
                               pose_noise_rotation_deg=noise["rotation_deg"])
    return {"cam0": np.asarray(he.cameras["cam0"].params), "T_flange_cam0": he.transforms["T_flange_cam0"],
            "T_base_board": T_base_board,
            "T_base_cam1": T_base_cam1, "T_flange_needle": tcp.T_flange_tcp}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=50, help="simulated cells for joint vs sequential")
    ap.add_argument("--repeats", type=int, default=100, help="unchanged-cell repeats for the false-alarm rate")
    ap.add_argument("--alpha", type=float, default=0.05, help="family-wise significance of the change tests")
    args = ap.parse_args()

    import jcalib
    from jcalib.io.cell import load_cell
    from jcalib.io.observations import load_observations
    from jcalib.problems.calibrate import result_file
    from jcalib.problems.reoptimise import compare_results
    from jcalib.sim.cells import synthetic_cell

    options = jcalib.CalibrationOptions(sigma_px=0.2, tip_sigma_px=0.2)
    names = ("T_flange_cam0", "T_base_board", "T_base_cam1", "T_flange_needle")
    err = {"joint": {n: [] for n in names}, "sequential": {n: [] for n in names}}
    err["joint"]["cam0 fx"], err["sequential"]["cam0 fx"] = [], []
    for trial in range(args.trials):
        cell, obs, truth = synthetic_cell(1000 + trial)
        cal = jcalib.calibrate_cell(load_cell(cell), load_observations(obs), options)
        seq = sequential(cell, obs)
        for label, T, fx in (("joint", cal.transforms, float(cal.cameras["cam0"].params[0])),
                             ("sequential", seq, float(seq["cam0"][0]))):
            for n in names:
                err[label][n].append(_errors(T[n], truth[n]))
            err[label]["cam0 fx"].append((abs(fx - truth["cam0"][0]), 0.0))
    print(f"joint vs sequential over {args.trials} simulated cells (median errors)")
    print(f"{'unknown':18s} {'joint deg':>10s} {'seq deg':>10s} {'joint mm/px':>12s} {'seq mm/px':>12s}")
    for n in (*names, "cam0 fx"):
        j, s = np.median(np.asarray(err["joint"][n]), axis=0), np.median(np.asarray(err["sequential"][n]), axis=0)
        print(f"{n:18s} {j[0]:10.4f} {s[0]:10.4f} {j[1]:12.4f} {s[1]:12.4f}")

    cell, obs, _ = synthetic_cell(5000)
    old = result_file(jcalib.calibrate_cell(load_cell(cell), load_observations(obs), options), options, "old")
    flagged = 0
    for r in range(args.repeats):
        cell, obs, _ = synthetic_cell(6000 + r)
        new = result_file(jcalib.calibrate_cell(load_cell(cell), load_observations(obs), options, start=old), options,
                          "new")
        flagged += any(c.moved for c in compare_results(old, new, alpha=args.alpha))
    print(json.dumps({"unchanged_repeats": args.repeats, "flagged": flagged,
                      "not_flagged_fraction": 1 - flagged / max(args.repeats, 1), "alpha": args.alpha}))


if __name__ == "__main__":
    main()
