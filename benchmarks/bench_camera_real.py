"""jcalib camera calibration on real data: OpenCV's left/right samples (against cv2) and mrcal's
wide-angle Figueroa set as a stress test.

Part 1: corners as OpenCV's calibration sample finds them (findChessboardCorners with ADAPTIVE_THRESH |
FAST_CHECK | NORMALIZE_IMAGE, cornerSubPix 11x11, EPS + COUNT 30, 0.1: the settings that reproduce its
left_intrinsics.yml), CALIB_FIX_ASPECT_RATIO, opencv5; ``jcalib.calibrate_cell`` (no rejection, no
re-seeding) vs cv2.calibrateCamera on the same corners: parameters, RMS, wall time (warm, median of 5).
Part 2: mrcal_figueroa (186 views, 10x10 board, 6016x4016): corners with weight <= 0 dropped; the
observation format has no per-corner weight, so the others count equally. Reports what happens.

Run: ``.venv/bin/python benchmarks/bench_camera_real.py [--skip-mrcal]``
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from pathlib import Path

import cv2
import numpy as np

import jcalib
from jcalib.io.cell import parse_cell
from jcalib.io.observations import parse_observations

REAL = Path(__file__).resolve().parents[1] / "tests" / "data" / "real"
IMAGES = REAL / "opencv_left_right_chessboard" / "images"
VIEWS = [i for i in range(1, 15) if i != 10]  # 13 pairs, no pair 10
COLS, ROWS = 9, 6
SAMPLE_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_FAST_CHECK | cv2.CALIB_CB_NORMALIZE_IMAGE


def board_points(square: float) -> np.ndarray:
    """calibration.cpp's calcChessboardCorners, rounded to float32 as OpenCV takes them (same problem)."""
    points = np.array([[j * square, i * square, 0.0] for i in range(ROWS) for j in range(COLS)])
    return points.astype(np.float32).astype(np.float64)


def detect(side: str, win: int) -> dict[int, np.ndarray]:
    """Corners of every ``side`` image as OpenCV's calibration sample finds them, (54, 2) px each."""
    out = {}
    for i in VIEWS:
        view = cv2.imread(str(IMAGES / f"{side}{i:02d}.jpg"), cv2.IMREAD_COLOR)
        gray = cv2.cvtColor(view, cv2.COLOR_BGR2GRAY)
        found, corners = cv2.findChessboardCorners(view, (COLS, ROWS), flags=SAMPLE_FLAGS)
        if not found:
            raise SystemExit(f"{side}{i:02d}.jpg: chessboard not found")
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.1)
        out[i] = cv2.cornerSubPix(gray, corners, (win, win), (-1, -1), criteria)[:, 0].astype(np.float64)
    return out


def observations(corners: dict[str, dict[int, np.ndarray]], square: float):
    return parse_observations({
        "schema": "jcalib.observations/1",
        "cameras": {s: {"image_size": [640, 480]} for s in corners},
        "targets": {"board": {"points": board_points(square).tolist()}},
        "stations": [{"id": f"{i:02d}", "detections": [
            {"camera": s, "target": "board", "point_index": list(range(COLS * ROWS)), "pixels": corners[s][i].tolist()}
            for s in corners]} for i in VIEWS],
    })


def cell(cameras: dict[str, dict], square: float):
    return parse_cell({"schema": "jcalib.cell/1", "cameras": cameras,
                       "targets": {"board": {"type": "checkerboard", "cols": COLS, "rows": ROWS, "square": square}}})


def timed(fn, repeat=5):
    out = fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return out, float(np.median(times))


def opencv_samples() -> None:
    print("## OpenCV left/right samples, CALIB_FIX_ASPECT_RATIO, opencv5 (sample's corners)")
    print("| images | solver | fx = fy | cx | cy | k1 | k2 | k3 | RMS px | time ms |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for side in ("left", "right"):
        corners = detect(side, 11)
        obs = observations({side: corners}, 0.025)
        c = cell({side: {"model": "opencv5", "fix": ["aspect"]}}, 0.025)
        opts = jcalib.CalibrationOptions(outlier_threshold=None, reseed_views=False)
        t0 = time.perf_counter()
        jcalib.calibrate_cell(c, obs, opts)
        first = time.perf_counter() - t0
        cal, t_ours = timed(lambda: jcalib.calibrate_cell(c, obs, opts))
        K, d = cal.cameras[side].to_opencv()
        obj = [board_points(0.025).astype(np.float32)] * len(corners)
        img = [v.astype(np.float32) for v in corners.values()]
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-15)
        (rms, Kc, dc, *_), t_cv = timed(lambda: cv2.calibrateCamera(
            obj, img, (640, 480), np.eye(3), np.zeros(5), flags=cv2.CALIB_FIX_ASPECT_RATIO, criteria=crit))
        dc = dc.ravel()
        print(f"| {side} | jcalib | {K[0, 0]:.4f} | {K[0, 2]:.4f} | {K[1, 2]:.4f} | {d[0]:.6f} | {d[1]:.6f} "
              f"| {d[4]:.6f} | {cal.rms_px:.5f} | {t_ours * 1e3:.0f} (first {first:.1f} s) |")
        print(f"| {side} | cv2 | {Kc[0, 0]:.4f} | {Kc[0, 2]:.4f} | {Kc[1, 2]:.4f} | {dc[0]:.6f} | {dc[1]:.6f} "
              f"| {dc[4]:.6f} | {rms:.5f} | {t_cv * 1e3:.0f} |")
        print(f"|  | rel. diff K / abs diff dist | {np.abs(K - Kc).max() / Kc[0, 0]:.1e} | | | "
              f"{np.abs(d - dc).max():.1e} | | | {abs(cal.rms_px - rms):.1e} | |")
    print("| left | OpenCV published | 535.9157 | 342.2832 | 235.5708 | -0.266373 | -0.038589 | 0.238392 | 0.39259 | |")


def mrcal_figueroa() -> None:
    print("\n## mrcal Figueroa wide-angle set (stress test)")
    raw = np.loadtxt(REAL / "mrcal_figueroa" / "board_observations.csv", delimiter=",", comments="#")
    view, row, col, u, v, w = raw.T
    keep = w > 0
    print(f"{int(view.max()) + 1} views, {raw.shape[0]} corners, {int((~keep).sum())} marked outliers dropped; "
          f"weights 0.5/0.25/0.125 on {int(((w > 0) & (w < 1)).sum())} corners ignored (no per-corner sigma "
          "in jcalib.observations/1)")
    points = np.array([[j * 0.077, i * 0.077, 0.0] for i in range(10) for j in range(10)])
    stations = []
    for k in np.unique(view[keep]).astype(int):
        m = keep & (view == k)
        idx = (row[m] * 10 + col[m]).astype(int)
        stations.append({"id": f"{k:03d}", "detections": [{"camera": "cam", "target": "board",
                         "point_index": idx.tolist(), "pixels": np.c_[u[m], v[m]].tolist()}]})
    obs = parse_observations({"schema": "jcalib.observations/1", "cameras": {"cam": {"image_size": [6016, 4016]}},
                              "targets": {"board": {"points": points.tolist()}}, "stations": stations})
    print("| model | outcome | iterations | RMS px | sigma px | rejected corners | re-seeded views | fx | fy | cx | cy | "
          "time s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for model in ("opencv8", "fisheye", "opencv5"):
        c = parse_cell({"schema": "jcalib.cell/1", "cameras": {"cam": {"model": model}},
                        "targets": {"board": {"type": "checkerboard", "cols": 10, "rows": 10, "square": 0.077}}})
        t0 = time.perf_counter()
        try:
            cal = jcalib.calibrate_cell(c, obs)
        except Exception as exc:  # report, do not stop: this is a stress test
            print(f"| {model} | {type(exc).__name__}: {str(exc)[:200]} | | | | | | | | | | "
                  f"{time.perf_counter() - t0:.1f} |")
            traceback.print_exc(limit=2, file=sys.stderr)
            continue
        p = dict(zip(cal.cameras["cam"].param_names, np.asarray(cal.cameras["cam"].params)))
        print(f"| {model} | {cal.status} | {cal.iterations} | {cal.rms_px:.3f} | {cal.sigma_px:.3f} | "
              f"{len(cal.outliers)} | {len(cal.reseeded_views)} | {p['fx']:.1f} | {p['fy']:.1f} | {p['cx']:.1f} | "
              f"{p['cy']:.1f} | {time.perf_counter() - t0:.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-mrcal", action="store_true")
    args = parser.parse_args()
    opencv_samples()
    if not args.skip_mrcal:
        mrcal_figueroa()


if __name__ == "__main__":
    main()
