"""Board warp (``warp: true`` on a target): jcalib against mrcal on mrcal's wide-angle set, and what a
bowed board does to a hand-eye cell with and without the warp estimated.

Part 1, ``tests/data/real/mrcal_figueroa`` (186 views, 10x10 corners, 0.077 m, 6016x4016), OPENCV8 from
jcalib's own cold start, every corner given (the file's outlier marks are not used: each tool rejects
its own), equal weights (``jcalib.observations/1`` has no per-corner σ; mrcal weights corners by their
detector level, 1 / 0.5 / 0.25 / 0.125, from the file):
  - jcalib flat, jcalib with the warp estimated;
  - mrcal 2.2's own pipeline (``mrcal-calibrate-cameras --corners-cache``, LENSMODEL_OPENCV8, board warp
    estimated as it does by default), its solution also evaluated with its warp ignored.
  The RMS is the unweighted RMS per coordinate (px), over each solution's own inliers and over the
  corners that every solution keeps (the same set for all). Warp ``(c0, c1)`` in mm, mrcal's definition
  (``calobject_warp``). Wall time: jcalib's first call in this process (compiles) and a second call;
  mrcal's whole command.

Part 2, a bowed board in simulation: the demo-like synthetic cell (``jcalib.sim.cells.synthetic_cell``,
flange camera cam0, fixed camera cam1 with known intrinsics, 15 board stations, 9x6 board 0.03 m) whose
board sags 0.5 mm at its centre (``c0 = 0.3 mm, c1 = 0.2 mm``). For each of ``--trials`` seeds the same
observations are calibrated with the board taken as flat and with its warp estimated; the table gives
the RMS over trials of the errors against the truth (cam0 fx, cx; the hand-eye ``T_flange_cam0``
rotation and translation), and the ratio with / without, at 0.05 px and 0.2 px of corner noise (robot
0.1 mm / 0.01° as the demo states) and practically noise-free (the bias alone).

Run: ``.venv/bin/python benchmarks/bench_board_warp.py [--trials 20] [--skip-mrcal]``
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import jcalib
from jcalib.geometry.se3 import invert, log_se3
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations
from jcalib.sim.cells import synthetic_cell

DATA = Path(__file__).resolve().parents[1] / "tests" / "data" / "real" / "mrcal_figueroa" / "board_observations.csv"
SYSTEM_PYTHON = "/usr/bin/python3"
N, SPACING, SIZE = 10, 0.077, (6016, 4016)

MRCAL_RESIDUALS = r'''
import json, sys
import numpy as np
import mrcal

m = mrcal.cameramodel(sys.argv[1])
oi = m.optimization_inputs()
obs = oi["observations_board"]                       # (views, H, W, 3): x, y, weight (< 0: outlier)
frames = oi["frames_rt_toref"]                       # board -> reference (= this camera)
lensmodel, intr = oi["lensmodel"], oi["intrinsics"][0]
H, W = obs.shape[1:3]
out = {"warp": [float(v) for v in oi["calobject_warp"]], "intrinsics": intr.tolist()}
for key, warp in (("warped", oi["calobject_warp"]), ("flat", None)):
    board = mrcal.ref_calibration_object(W, H, oi["calibration_object_spacing"], calobject_warp=warp)
    q = mrcal.project(mrcal.transform_point_rt(frames[:, None, None, :], board[None]), lensmodel, intr)
    out[key] = (q - obs[..., :2]).reshape(len(obs), H * W, 2).tolist()
out["inlier"] = (obs[..., 2] > 0).reshape(len(obs), H * W).tolist()
print(json.dumps(out))
'''


def load_figueroa():
    raw = np.loadtxt(DATA, delimiter=",", comments="#")
    return raw


def figueroa_observations(raw):
    view, row, col, u, v, _ = raw.T
    points = np.array([[j * SPACING, i * SPACING, 0.0] for i in range(N) for j in range(N)])
    stations = []
    for k in np.unique(view).astype(int):
        m = view == k
        idx = (row[m] * N + col[m]).astype(int)
        stations.append({"id": f"{k:03d}", "detections": [{"camera": "cam", "target": "board",
                         "point_index": idx.tolist(), "pixels": np.c_[u[m], v[m]].tolist()}]})
    return parse_observations({"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": list(SIZE)}},
                               "targets": {"board": {"points": points.tolist()}}, "stations": stations})


def jcalib_figueroa(obs, warp: bool):
    """``(calibration, residuals (views, 100, 2), inlier (views, 100), first s, second s)``."""
    cell = parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam": {"model": "opencv8"}},
                       "targets": {"board": {"type": "checkerboard", "cols": N, "rows": N, "square": SPACING,
                                             "warp": warp}}})
    t0 = time.perf_counter()
    jcalib.calibrate_cell(cell, obs)
    t1 = time.perf_counter()
    cal = jcalib.calibrate_cell(cell, obs)
    t2 = time.perf_counter()
    res = np.full((186, N * N, 2), np.nan)
    inlier = np.zeros((186, N * N), bool)
    for gr in cal.built.groups:
        views = np.asarray([int(cal.station_ids[int(k)]) for k in gr.stations])
        res[views, gr.index] = cal.residuals[gr.name]
        inlier[views, gr.index] = cal.weights[gr.name] > 0
    return cal, res, inlier, t1 - t0, t2 - t1


def mrcal_figueroa(raw):
    """mrcal's own calibration of the same corners: ``(result dict, seconds)`` or None without mrcal."""
    tool = shutil.which("mrcal-calibrate-cameras")
    if tool is None or subprocess.run([SYSTEM_PYTHON, "-c", "import mrcal"], capture_output=True).returncode:
        print("mrcal not found (Debian: apt-get install mrcal python3-mrcal): its rows are left out")
        return None
    env = {k: v for k, v in os.environ.items() if not k.startswith(("VIRTUAL_ENV", "PYTHON"))}
    with tempfile.TemporaryDirectory() as tmp:
        corners = os.path.join(tmp, "corners.vnl")
        with open(corners, "w") as f:
            f.write("# filename x y level\n")
            for k in range(186):
                m = raw[raw[:, 0] == k]
                m = m[np.lexsort((m[:, 2], m[:, 1]))]  # row-major, as mrcal reads a board
                for r in m:
                    level = int(round(-np.log2(abs(r[5])))) if r[5] != 0 else 0
                    f.write(f"img{k:03d}.jpg {r[3]:.6f} {r[4]:.6f} {level}\n")
        t0 = time.perf_counter()
        proc = subprocess.run([tool, "--corners-cache", corners, "--lensmodel", "LENSMODEL_OPENCV8", "--focal", "1900",
                               "--object-spacing", str(SPACING), "--object-width-n", str(N), "--imagersize",
                               *map(str, SIZE), "--outdir", tmp, "img*.jpg"], capture_output=True, text=True, env=env)
        seconds = time.perf_counter() - t0
        if proc.returncode:
            print(f"mrcal-calibrate-cameras failed: {proc.stderr[-800:]}")
            return None
        script = os.path.join(tmp, "residuals.py")
        Path(script).write_text(MRCAL_RESIDUALS)
        out = subprocess.run([SYSTEM_PYTHON, script, os.path.join(tmp, "camera-0.cameramodel")], capture_output=True,
                             text=True, env=env, check=True)
    return json.loads(out.stdout), seconds


def rms(res, mask) -> float:
    return float(np.sqrt(np.mean(res[mask] ** 2)))


def part1(skip_mrcal: bool) -> None:
    print("\n## Part 1: mrcal's wide-angle set (186 views, OPENCV8)")
    raw = load_figueroa()
    obs = figueroa_observations(raw)
    rows = []
    flat, res_f, in_f, first_f, second_f = jcalib_figueroa(obs, warp=False)
    warped, res_w, in_w, first_w, second_w = jcalib_figueroa(obs, warp=True)
    mr = None if skip_mrcal else mrcal_figueroa(raw)
    common = in_f & in_w
    if mr is not None:
        data, mr_seconds = mr
        in_m = np.asarray(data["inlier"], bool)
        common &= in_m
    total = in_f.size
    std = np.sqrt(np.diag(warped.warp_covariance["board"])) * 1e3
    c = warped.warps["board"] * 1e3
    rows.append(("jcalib, flat board", total - in_f.sum(), rms(res_f, in_f), rms(res_f, common), "–",
                 f"{first_f:.1f} / {second_f:.1f}"))
    rows.append(("jcalib, warp estimated", total - in_w.sum(), rms(res_w, in_w), rms(res_w, common),
                 f"{c[0]:+.4f} ± {std[0]:.4f}, {c[1]:+.4f} ± {std[1]:.4f}", f"{first_w:.1f} / {second_w:.1f}"))
    if mr is not None:
        rw, rf = np.asarray(data["warped"]), np.asarray(data["flat"])
        wm = np.asarray(data["warp"]) * 1e3
        rows.append(("mrcal, warp estimated", total - in_m.sum(), rms(rw, in_m), rms(rw, common),
                     f"{wm[0]:+.4f}, {wm[1]:+.4f}", f"{mr_seconds:.1f}"))
        rows.append(("mrcal's solution, warp ignored", total - in_m.sum(), rms(rf, in_m), rms(rf, common), "(0, 0)",
                     "–"))
    print(f"{common.sum()} corners kept by every solution (of {total})\n")
    print("| solution | rejected corners | RMS px/coord, own inliers | RMS px/coord, common corners | "
          "warp c0, c1 (mm) | time s (first / second) |")
    print("|---|---|---|---|---|---|")
    for name, rej, own, com, w, t in rows:
        print(f"| {name} | {rej} | {own:.3f} | {com:.3f} | {w} | {t} |")
    if mr is not None:
        print(f"\nwarp difference jcalib − mrcal: {c[0] - wm[0]:+.4f}, {c[1] - wm[1]:+.4f} mm; fx, fy, cx, cy: "
              f"jcalib {np.round(np.asarray(warped.cameras['cam'].params)[:4], 2).tolist()}, "
              f"mrcal {np.round(np.asarray(data['intrinsics'])[:4], 2).tolist()}")


def errors(cal, true) -> np.ndarray:
    """``(fx, cx, hand-eye rotation deg, hand-eye translation mm)`` errors against the truth."""
    e = log_se3(invert(true["T_flange_cam0"]) @ cal.transforms["T_flange_cam0"])
    d = np.asarray(cal.cameras["cam0"].params) - true["cam0"]
    return np.array([d[0], d[2], np.degrees(np.linalg.norm(e[:3])), 1e3 * np.linalg.norm(e[3:])])


def part2(trials: int) -> None:
    warp = np.array([0.0003, 0.0002])
    print(f"\n## Part 2: a board that sags {1e3 * warp.sum():.1f} mm (c0 = {1e3 * warp[0]} mm, c1 = {1e3 * warp[1]} mm), "
          f"synthetic hand-eye cell, {trials} seeds")
    print("| pixel noise | board model | fx err px | cx err px | hand-eye rot err deg | hand-eye trans err mm | "
          "warp err / σ (rms) |")
    print("|---|---|---|---|---|---|---|")
    for sigma, n in ((0.0, 1), (0.05, trials), (0.2, trials)):
        out = {False: [], True: []}
        z = []
        for seed in range(n):
            # "0 px": pixels and robot poses practically exact (exact zeros leave no noise to estimate)
            noise = dict(sigma_px=sigma, tip_sigma_px=0.2) if sigma else dict(
                sigma_px=1e-4, tip_sigma_px=1e-4, robot_m=1e-7, robot_deg=1e-6)
            cell, obs, true = synthetic_cell(seed, num_tool_stations=8, board_warp=warp, **noise)
            o = parse_observations(obs)
            for estimate in (False, True):
                c = copy.deepcopy(cell)
                c["targets"]["board"]["warp"] = estimate
                cal = jcalib.calibrate_cell(parse_cell(c), o)
                out[estimate].append(errors(cal, true))
                if estimate and sigma > 0:
                    z.append((cal.warps["board"] - warp) / np.sqrt(np.diag(cal.warp_covariance["board"])))
        r = {k: np.sqrt(np.mean(np.square(v), axis=0)) for k, v in out.items()}
        zr = f"{np.sqrt(np.mean(np.square(z))):.2f}" if z else "–"
        for estimate in (False, True):
            print(f"| {sigma} px | {'warp estimated' if estimate else 'flat'} | "
                  + " | ".join(f"{v:.4g}" for v in r[estimate]) + f" | {zr if estimate else '–'} |")
        ratio = r[True] / np.where(r[False] > 0, r[False], 1.0)
        print(f"| {sigma} px | ratio warp / flat | " + " | ".join(f"{v:.2f}" for v in ratio) + " | |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--skip-mrcal", action="store_true")
    parser.add_argument("--part", choices=("1", "2", "all"), default="all")
    args = parser.parse_args()
    if args.part in ("1", "all"):
        part1(args.skip_mrcal)
    if args.part in ("2", "all"):
        part2(args.trials)


if __name__ == "__main__":
    main()
