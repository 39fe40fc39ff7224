"""Boards found per image set, with the finders' defaults only and with retries, and wrong boards.

Image sets:
- rendered hard cases (``jcalib.sim``, ground truth known): blur, low contrast, glare, steep tilt,
  small board, dim and noisy, plus a clean control; a 9x6 chessboard (unambiguous orientation) and a
  7x5 ChArUco board, 640x480 with lens distortion. A *wrong* detection has a point farther than 0.15
  of the local spacing (and 1 px) from its true projection: a wrong id, corner or order, not noise.
  The median and 99th percentile of the point errors are printed beside.
- OpenCV's real ChArUco photograph (``--charuco-photo``, bundled in ``tests/data/charuco_opencv``) and
  versions of it made harder (half size, blur, glare, contrast); reference: the corners found in the
  original, checked against OpenCV's published marker corners (1 px); wrong as above.
- real chessboard images (``--real DIR``, e.g. the shared ``data/real`` folder: OpenCV's left/right
  images): no ground truth; a wrong board would show as a large reprojection error of
  ``cv2.calibrateCamera`` on the found corners (printed: RMS and worst point).

- speed and robustness (``--speed``): a table per target type and image size (640x480, 1280x960,
  1600x1200, 6016x4016: the sensor of the bundled mrcal set, whose images are not bundled, so its views are
  rendered) for the sets of ``benchmarks/detection_sets.py`` (board present, absent, partly out of view,
  blur, low contrast, glare, steep tilt): CPU time per image on one core (``cv2.setNumThreads(1)``,
  ``time.process_time``: median and 95th percentile), boards found, corners found, wrong boards
  (a point farther than 0.15 spacings and 1 px from its true projection, or found outside the image),
  sub-pixel RMS of the right points against the truth, px. Side by side: this code ("after"), the code
  that ``--before FILE`` recorded (run this script with ``--save FILE`` and ``PYTHONPATH`` at that code),
  and OpenCV's finder alone (``findChessboardCornersSB`` with ``CALIB_CB_EXHAUSTIVE | CALIB_CB_ACCURACY``,
  ``CharucoDetector``, ``findCirclesGrid``; labels matched to the truth up to the board's symmetries).
- ``jobs``: ``detect_many`` on image files with 1 and 2 processes, wall time, and whether the results agree.
- ``track``: :func:`jcalib.vision.track_target` through a rendered 1280x960 sequence, per target type.
- with ``--real``: OpenCV's left01 with an outer row or column of corners covered (no board may be returned).

Run: ``.venv/bin/python benchmarks/bench_detection.py [--real tests/data/real] [--views 10] [--before FILE]``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import cv2
import numpy as np

import jcalib  # noqa: F401  (float64)
from jcalib.errors import DetectionError
from jcalib.geometry import camera_from_opencv
from jcalib.geometry.targets import Charuco, Checkerboard
from jcalib.sim.render import RenderOptions, render_target_image
from jcalib.sim.scene import project_target, random_calibration_views
from jcalib.sim.textures import target_texture
from jcalib.vision import detect_target

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))  # detection_sets
from detection_sets import CONDITIONS  # noqa: E402
K = np.array([[800.0, 0.0, 322.0], [0.0, 798.0, 241.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.2, 0.08, 0.0, 0.0, 0.0])
SIZE = (640, 480)
#: A point is wrong when farther than this fraction of the local spacing (distance to its nearest board
#: neighbour in the image) from its true projection: a different corner, id or order, not noise.
WRONG_SPACING = 0.15
BOARDS = {"chessboard 9x6": Checkerboard(9, 6, 0.03), "charuco 7x5": Charuco(7, 5, 0.04, 0.03, "DICT_5X5_100")}
PHOTO_BOARD = Charuco(5, 7, 0.04, 0.02, "DICT_6X6_250")
#: OpenCV's published marker corners of choriginal.jpg (test CV_ArucoTutorial.can_find_choriginal), px.
PHOTO_MARKERS = np.array([
    [268, 77, 290, 80, 286, 97, 263, 94], [360, 90, 382, 93, 379, 111, 357, 108],
    [211, 106, 233, 109, 228, 127, 205, 123], [306, 120, 328, 124, 325, 142, 302, 138],
    [402, 135, 425, 139, 423, 157, 400, 154], [247, 152, 271, 155, 267, 174, 242, 171],
    [347, 167, 371, 171, 369, 191, 344, 187], [185, 185, 209, 189, 203, 210, 178, 206],
    [288, 201, 313, 206, 309, 227, 284, 223], [393, 218, 418, 222, 416, 245, 391, 241],
    [223, 240, 250, 244, 244, 268, 217, 263], [333, 258, 359, 262, 356, 286, 329, 282],
    [152, 281, 179, 285, 171, 312, 143, 307], [267, 300, 294, 305, 289, 331, 261, 327],
    [383, 319, 410, 324, 408, 351, 380, 347], [194, 347, 223, 352, 216, 382, 186, 377],
    [315, 368, 345, 373, 341, 403, 310, 398]], dtype=np.float64).reshape(17, 4, 2)  # fmt: skip


def hard_cases(rng: np.random.Generator) -> dict[str, tuple[RenderOptions, dict]]:
    """name -> (render options, view options of random_calibration_views)."""
    base = RenderOptions()
    glare = tuple((float(rng.uniform(0.3, 0.7)), float(rng.uniform(0.3, 0.7)), 0.12, 1.5) for _ in range(1))
    return {
        "clean (control)": (base, {}),
        "blur σ 3 px": (RenderOptions(blur_sigma_px=3.0), {}),
        "low contrast": (RenderOptions.preset("realistic", white_electrons=400.0, gain_dn_per_e=255 / 560,
                                              ink_reflectance=0.55, paper_reflectance=0.8), {}),  # fmt: skip
        "faded print (5 %)": (RenderOptions(ink_reflectance=0.75, paper_reflectance=0.8), {}),
        "glare": (RenderOptions(glare=glare), {}),
        "steep tilt 55-75°": (base, {"max_tilt_deg": 75.0, "min_tilt_deg": 55.0}),
        "small board": (base, {"fill": (0.16, 0.24)}),
        "dim and noisy": (RenderOptions.preset("realistic", white_electrons=45.0, gain_dn_per_e=255 / 63), {}),
    }


def steep_views(camera, points, n, rng, min_tilt_deg, max_tilt_deg):
    """Views whose board normal is ``min_tilt_deg``..``max_tilt_deg`` from the viewing ray."""
    out = []
    tries = 0
    while len(out) < n and tries < 50:
        tries += 1
        for T in random_calibration_views(camera, points, 4 * n, rng, max_tilt_deg=max_tilt_deg, fill=(0.4, 0.9),
                                          margin_px=5.0):  # fmt: skip
            centre = T[:3, :3] @ points.mean(axis=0) + T[:3, 3]
            cosang = abs(float(T[:3, 2] @ centre) / np.linalg.norm(centre))
            if math.degrees(math.acos(min(cosang, 1.0))) >= min_tilt_deg:
                out.append(T)
                if len(out) == n:
                    break
    return out


def detect_both(image, board):
    """(detection or None) with the defaults only, then with retries; and seconds of each."""
    out = []
    for retry in (False, True):
        t0 = time.perf_counter()
        try:
            det = detect_target(image, board, retry=retry)
        except DetectionError:
            det = None
        out.append((det, time.perf_counter() - t0))
    return out


def wrong_points(det, truth: np.ndarray) -> int:
    """Points farther from their true projection than ``WRONG_SPACING`` of the local spacing (and 1 px)."""
    err = np.linalg.norm(det.pixels - truth[det.point_index], axis=1)
    d = np.linalg.norm(truth[:, None, :] - truth[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    spacing = np.nanmin(np.where(np.isfinite(d), d, np.inf), axis=1)[det.point_index]
    return int(np.sum(~(err <= np.maximum(WRONG_SPACING * spacing, 1.0))))


def point_errors(results, k) -> np.ndarray:
    errs = [np.linalg.norm(r[k][0].pixels - r[2][r[k][0].point_index], axis=1)
            for r in results if r[k][0] is not None and r[2] is not None]  # fmt: skip
    return np.concatenate(errs) if errs else np.zeros(0)


def row(name, board_name, n, results):
    """results: list of ((det0, t0), (det1, t1), truth or None)."""
    cells = []
    for k in (0, 1):
        found = [r[k][0] for r in results if r[k][0] is not None]
        pts = sum(d.num_points for d in found)
        wrong = [wrong_points(r[k][0], r[2]) for r in results if r[k][0] is not None and r[2] is not None]
        cells.append((len(found), pts, sum(w > 0 for w in wrong), sum(wrong), np.mean([r[k][1] for r in results])))
    retried = sum(1 for r in results if r[1][0] is not None and r[1][0].attempt != "default")
    (f0, p0, wb0, wp0, t0), (f1, p1, wb1, wp1, t1) = cells
    e = point_errors(results, 1)
    acc = f" {np.median(e):5.2f} {np.percentile(e, 99):5.2f}" if e.size else ""
    print(f"{name:24s} {board_name:15s} {n:4d} {f0:5d} {f1:5d} {p0:6d} {p1:6d} {retried:5d} "
          f"{wb0:3d}/{wp0:<4d} {wb1:3d}/{wp1:<4d} {1e3 * t0:6.0f} {1e3 * t1:6.0f}{acc}")  # fmt: skip
    return cells


HEADER = (f"{'image set':24s} {'board':15s} {'imgs':>4s} {'found':>5s} {'+retry':>5s} {'points':>6s} {'+retry':>6s} "
          f"{'retried':>5s} {'wrong b/p':>8s} {'+retry':>8s} {'ms':>6s} {'+retry':>6s} {'med':>5s} {'p99':>5s}")  # fmt: skip


def rendered(views: int, seed: int) -> list:
    camera = camera_from_opencv(K, DIST, SIZE)
    rng = np.random.default_rng(seed)
    print(f"\nrendered hard cases: {SIZE[0]}x{SIZE[1]}, k1 = {DIST[0]}, {views} views per case and board; "
          f"'found' = defaults only, '+retry' = with retries; wrong b/p = boards/points farther than "
          f"{WRONG_SPACING} spacings from the truth; med/p99: error of the points found with retries, px")
    print(HEADER)
    print("-" * len(HEADER))
    totals = []
    for case, (options, view_opts) in hard_cases(rng).items():
        for board_name, board in BOARDS.items():
            spacing = board.square
            texture = target_texture(board, spacing / 24)
            if "min_tilt_deg" in view_opts:
                poses = steep_views(camera, board.points, views, rng, view_opts["min_tilt_deg"], view_opts["max_tilt_deg"])
            else:
                poses = random_calibration_views(camera, board.points, views, rng, **view_opts)
            results = []
            for i, T in enumerate(poses):
                truth, _ = project_target(camera, T, board.points)
                img = render_target_image(camera, T, texture, options, rng=int(rng.integers(1 << 31)))
                d0, d1 = detect_both(img, board)
                results.append((d0, d1, truth))
            totals.append(row(case, board_name, len(poses), results))
    return totals


def photo(path: Path) -> None:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        print(f"\n(no ChArUco photograph at {path})")
        return
    ref = detect_target(img, PHOTO_BOARD, retry=False)
    # reference corners, checked against OpenCV's published marker corners (homography of the markers)
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    b = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02, d)
    obj = np.asarray(b.getObjPoints())[:, :, :2].reshape(-1, 2)
    H, _ = cv2.findHomography(obj, PHOTO_MARKERS.reshape(-1, 2), 0)
    corners = np.asarray(b.getChessboardCorners())[:, :2]
    p = np.column_stack([corners, np.ones(len(corners))]) @ H.T
    pred = p[:, :2] / p[:, 2:]
    gap = np.linalg.norm(pred[ref.point_index] - ref.pixels, axis=1)
    print(f"\nOpenCV's ChArUco photograph ({path.name}, 5x7 DICT_6X6_250): reference {ref.num_points} corners, "
          f"{np.max(gap):.2f} px at most from OpenCV's published markers' homography")  # fmt: skip
    truth = np.full((PHOTO_BOARD.num_points, 2), np.nan)
    truth[ref.point_index] = ref.pixels
    h, w = img.shape
    yy, xx = np.mgrid[:h, :w]
    spot = np.exp(-((xx - 300.0) ** 2 + (yy - 200.0) ** 2) / (2 * 120.0**2))
    variants = {
        "photo as is": (img, 1.0),
        "photo at half size": (cv2.resize(img, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA), 0.5),
        "photo at 0.45 size": (cv2.resize(img, None, fx=0.45, fy=0.45, interpolation=cv2.INTER_AREA), 0.45),
        "photo blurred σ 1.5": (cv2.GaussianBlur(img, (0, 0), 1.5), 1.0),
        "photo blurred σ 2": (cv2.GaussianBlur(img, (0, 0), 2.0), 1.0),
        "photo with glare": (np.clip(img + 255.0 * spot, 0, 255).astype(np.uint8), 1.0),
        "photo contrast 5 %": (np.clip(128 + (img - 128.0) * 0.05, 0, 255).astype(np.uint8), 1.0),
    }
    print(HEADER)
    print("-" * len(HEADER))
    for name, (im, s) in variants.items():
        t = (truth + 0.5) * s - 0.5
        d0, d1 = detect_both(im, PHOTO_BOARD)
        row(name, "charuco 5x7", 1, [(d0, d1, t)])
        for k, (det, _) in enumerate((d0, d1)):
            if det is not None and k == 1 and det.attempt != "default":
                print(f"{'':24s} retry: attempt {det.attempt} (tried {', '.join(det.attempts)})")


def real_sets(root: Path) -> None:
    sets = {
        "OpenCV left (Bouguet)": (sorted((root / "opencv_left_right_chessboard" / "images").glob("left*.jpg")),
                                  Checkerboard(9, 6, 0.03)),
        "OpenCV right (Bouguet)": (sorted((root / "opencv_left_right_chessboard" / "images").glob("right*.jpg")),
                                   Checkerboard(9, 6, 0.03)),
    }  # fmt: skip
    print(f"\nreal image sets under {root} (no ground truth: calibrateCamera RMS / worst point on the found corners)")
    print(HEADER + "   RMS  worst")
    print("-" * (len(HEADER) + 13))
    for name, (files, board) in sets.items():
        if not files:
            print(f"{name}: no images")
            continue
        results = [(*detect_both(str(f), board), None) for f in files]
        row(name, f"chessboard {board.cols}x{board.rows}", len(files), results)
        found = [r[1][0] for r in results if r[1][0] is not None]
        if len(found) >= 3:
            obj = [board.points[d.point_index].astype(np.float32) for d in found]
            img = [d.pixels.astype(np.float32) for d in found]
            rms, Kc, dist, rv, tv = cv2.calibrateCamera(obj, img, found[0].image_size, None, None)
            worst = max(
                float(np.max(np.linalg.norm(cv2.projectPoints(o, r, t, Kc, dist)[0].reshape(-1, 2) - p, axis=1)))
                for o, p, r, t in zip(obj, img, rv, tv)
            )
            print(f"{'':24s} calibrateCamera on the corners found with retries: RMS {rms:.3f} px, worst point {worst:.2f} px")


# ------------------------------------------------------------------------------------------- speed


def _symmetric_best(target, pixels: np.ndarray, index: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``index`` relabelled by the board symmetry (proper rotations) that puts the points nearest the truth:
    OpenCV's own finders number a grid in their own order."""
    from jcalib.vision.orientation import point_symmetries

    best, best_err = index, np.inf
    for perm in point_symmetries(target.points[:, :2]):
        t = truth[perm[index]]
        e = np.nanmean(np.linalg.norm(pixels - t, axis=1)) if np.any(np.isfinite(t)) else np.inf
        if e < best_err:
            best, best_err = perm[index], e
    return best


def opencv_alone(image: np.ndarray, target):
    """(point_index, pixels) from OpenCV's own finder for the target type, or None."""
    from jcalib.geometry.targets import Charuco, Checkerboard

    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if gray.dtype != np.uint8:
        gray = cv2.normalize(gray, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if isinstance(target, Checkerboard):
        ok, c = cv2.findChessboardCornersSB(gray, (target.cols, target.rows),
                                            flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        return (np.arange(target.num_points), c.reshape(-1, 2).astype(np.float64)) if ok else None
    if isinstance(target, Charuco):
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, target.dictionary))
        board = cv2.aruco.CharucoBoard((target.squares_x, target.squares_y), target.square, target.marker, d)
        board.setLegacyPattern(target.legacy)
        corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
        if ids is None or len(ids) < 6:
            return None
        return ids.reshape(-1).astype(np.int64), corners.reshape(-1, 2).astype(np.float64)
    flags = cv2.CALIB_CB_ASYMMETRIC_GRID if target.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    ok, c = cv2.findCirclesGrid(gray, (target.cols, target.rows), flags=flags)
    return (np.arange(target.num_points), c.reshape(-1, 2).astype(np.float64)) if ok else None


def _record(found, truth: np.ndarray, seconds: float, target=None) -> dict:
    """One image's outcome: found, corners, wrong, squared errors of the right points, CPU seconds."""
    rec = {"found": False, "corners": 0, "wrong": False, "sq": [], "s": seconds}
    if found is None:
        return rec
    index, pixels = found
    if target is not None:
        index = _symmetric_best(target, pixels, index, truth)
    t = truth[index]
    err = np.linalg.norm(pixels - t, axis=1)
    d = np.linalg.norm(truth[:, None, :] - truth[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    with np.errstate(invalid="ignore"):
        spacing = np.nanmin(np.where(np.isfinite(d), d, np.inf), axis=1)[index]
        ok = err <= np.maximum(WRONG_SPACING * spacing, 1.0)
    rec.update(found=True, corners=int(len(index)), wrong=bool(np.any(~ok)), sq=(err[ok] ** 2).tolist())
    return rec


def run_detector(kind: str, cases, target) -> list[dict]:
    """Per-image records of ``kind`` ("jcalib" or "opencv") on a set, CPU time on one core."""
    out = []
    for case in cases:
        t0 = time.process_time()
        if kind == "opencv":
            found = opencv_alone(case.image, target)
        else:
            try:
                det = detect_target(case.image, target)
                found = (det.point_index, det.pixels)
            except DetectionError:
                found = None
        out.append(_record(found, case.truth, time.process_time() - t0, target if kind == "opencv" else None))
    return out


def _cells(records: list[dict] | None) -> str:
    if not records:
        return f"{'':>6s} {'':>6s} {'':>5s} {'':>5s} {'':>5s} {'':>6s}"
    ms = 1e3 * np.array([r["s"] for r in records])
    sq = [e for r in records for e in r["sq"]]
    rms = f"{np.sqrt(np.mean(sq)):6.3f}" if sq else f"{'-':>6s}"
    return (f"{np.median(ms):6.1f} {np.percentile(ms, 95):6.1f} {sum(r['found'] for r in records):5d} "
            f"{sum(r['corners'] for r in records):5d} {sum(r['wrong'] for r in records):5d} {rms}")  # fmt: skip


SPEED_HEAD = f"{'ms med':>6s} {'p95':>6s} {'found':>5s} {'pts':>5s} {'wrong':>5s} {'rms px':>6s}"


def speed(folder: Path, sizes: list[str], count: int, count_large: int, before: dict | None, save: Path | None,
          with_opencv: bool, conditions=CONDITIONS) -> dict:
    """The speed tables (module docstring); returns this code's records {set key: [records]}."""
    from detection_sets import load_or_render, targets

    cv2.setNumThreads(1)
    mine: dict[str, list[dict]] = {}
    print("\nspeed and robustness: CPU ms per image on one core (cv2.setNumThreads(1)); found/pts/wrong: boards, "
          "corners, wrong boards; rms: sub-pixel RMS of the right corners against the truth, px")  # fmt: skip
    for ti, (tname, target) in enumerate(targets().items()):
        for size in sizes:
            if size == "1600x1200" and not tname.startswith("charuco"):
                continue
            n = count_large if size == "6016x4016" else count
            print(f"\n{tname}, {size}, {n} images per set")
            print(f"{'set':13s} | {'before':^38s} | {'after':^38s}" + (f" | {'OpenCV alone':^38s}" if with_opencv else ""))
            print(f"{'':13s} | {SPEED_HEAD} | {SPEED_HEAD}" + (f" | {SPEED_HEAD}" if with_opencv else ""))
            for ci, cond in enumerate(CONDITIONS):
                if cond not in conditions:
                    continue
                key = f"{tname}|{size}|{cond}"
                cases = load_or_render(folder, tname, target, size, cond, n, 1000 * ti + 10 * ci + 7)
                mine[key] = run_detector("jcalib", cases, target)
                line = f"{cond:13s} | {_cells((before or {}).get(key))} | {_cells(mine[key])}"
                if with_opencv:
                    line += f" | {_cells(run_detector('opencv', cases, target))}"
                print(line, flush=True)
                if save is not None:
                    save.write_text(json.dumps(mine))
    return mine


def jobs_check(folder: Path) -> None:
    """``detect_many`` on the 640x480 chessboard sets written as files: 1 and 2 processes, wall time."""
    from detection_sets import CONDITIONS, load_or_render, targets

    from jcalib.vision import detect_many

    tname, target = next(iter(targets().items()))
    paths = []
    for ci, cond in enumerate(CONDITIONS):
        d = Path(folder) / f"{tname}_640x480_{cond}_10_{10 * ci + 7}".replace(" ", "-")
        load_or_render(folder, tname, target, "640x480", cond, 10, 10 * ci + 7)
        paths += sorted(d.glob("*.png"))
    print(f"\n--jobs: detect_many on {len(paths)} image files ({tname}, 640x480, every set), wall time")
    walls, outs = {}, {}
    for jobs in (1, 2):
        t0 = time.perf_counter()
        outs[jobs] = detect_many(paths, target, progress=False, jobs=jobs)
        walls[jobs] = time.perf_counter() - t0
    same = all(type(a) is type(b) and (not hasattr(a, "pixels") or np.array_equal(a.pixels, b.pixels))
               for a, b in zip(outs[1], outs[2]))  # fmt: skip
    for jobs in (1, 2):
        extra = f"  speed-up {walls[1] / walls[2]:4.2f}x, results identical to --jobs 1: {same}" if jobs == 2 else ""
        print(f"  --jobs {jobs}: {walls[jobs]:6.2f} s  ({1e3 * walls[jobs] / len(paths):5.1f} ms per image){extra}")


def tracking(frames: int = 30) -> None:
    """``track_target`` through a rendered 1280x960 sequence (the board turns and slides), each target type:
    CPU time per frame on one core, frames tracked, and a whole-frame ``detect_target`` of the same frames."""
    from detection_sets import camera, targets

    from jcalib.vision import track_target

    cv2.setNumThreads(1)
    size = (1280, 960)
    cam = camera(size)
    print(f"\ntracking: {frames} frames of 1280x960, the board turning 1.2° and sliding 2 mm per frame; CPU ms per "
          "frame on one core")  # fmt: skip
    print(f"{'target':18s} {'track med':>9s} {'p95':>6s} {'tracked':>7s} {'lost':>4s} {'full med':>8s} {'p95':>6s}")
    for tname, target in targets().items():
        spacing = getattr(target, "square", None) or target.spacing
        texture = target_texture(target, spacing / 24)
        T0 = random_calibration_views(cam, target.points, 1, 3, fill=(0.4, 0.5))[0]
        prev, t_track, t_full, tracked, lost = None, [], [], 0, 0
        for k in range(frames):
            T = T0.copy()
            T[:3, :3] = T0[:3, :3] @ cv2.Rodrigues(np.array([0.0, 0.0, math.radians(1.2 * k)]))[0]
            T[:3, 3] = T0[:3, 3] + np.array([0.002 * k, 0.001 * k, 0.0])
            img = render_target_image(cam, T, texture, RenderOptions(), rng=k)
            t0 = time.process_time()
            try:
                prev = track_target(img, target, prev)
                tracked += prev.tracked
            except DetectionError:
                prev, lost = None, lost + 1
            t_track.append(time.process_time() - t0)
            t0 = time.process_time()
            try:
                detect_target(img, target)
            except DetectionError:
                pass
            t_full.append(time.process_time() - t0)
        a, b = 1e3 * np.array(t_track), 1e3 * np.array(t_full)
        print(f"{tname:18s} {np.median(a):9.1f} {np.percentile(a, 95):6.1f} {tracked:7d} {lost:4d} {np.median(b):8.1f} "
              f"{np.percentile(b, 95):6.1f}")  # fmt: skip


def covered_rows(root: Path) -> None:
    """OpenCV's left01 with an outer row or column of corners painted over: boards returned (must be 0)."""
    img = cv2.imread(str(root / "opencv_left_right_chessboard" / "images" / "left01.jpg"), cv2.IMREAD_GRAYSCALE)
    if img is None:
        return
    board = Checkerboard(9, 6, 0.03)
    det = detect_target(img, board)
    P = det.pixels[np.argsort(det.point_index)].reshape(6, 9, 2)
    print("\nOpenCV's left01 with one outer row or column of corners covered (a board returned would be wrong):")
    for which, (inner, outer) in {"last row": (P[4], P[5]), "first row": (P[1], P[0]), "last column": (P[:, 7], P[:, 8]),
                                  "first column": (P[:, 1], P[:, 0])}.items():  # fmt: skip
        mid, beyond = 0.5 * (inner + outer), outer + 0.5 * (outer - inner)
        a, b = mid[0] - 1.5 * (mid[1] - mid[0]), mid[-1] + 1.5 * (mid[-1] - mid[-2])
        c, d = beyond[0] - 1.5 * (beyond[1] - beyond[0]), beyond[-1] + 1.5 * (beyond[-1] - beyond[-2])
        covered = img.copy()
        cv2.fillConvexPoly(covered, np.array([a, b, d, c]).round().astype(np.int32), 255)
        try:
            found = detect_target(covered, board)
            print(f"  {which:13s} FOUND by attempt {found.attempt}: {found.num_points} points  <-- wrong board")
        except DetectionError as e:
            print(f"  {which:13s} rejected ({e.reason}): {str(e)[:150]}")


def reference_ms() -> float:
    """CPU time of a fixed workload (sigma-1 Gaussian blur of a 640x480 float image, one thread): how fast the
    machine runs while the tables are measured (about 0.3-0.5 ms on a quiet core of this machine)."""
    cv2.setNumThreads(1)
    f = np.random.default_rng(0).random((480, 640)).astype(np.float32)
    t0 = time.process_time()
    for _ in range(200):
        cv2.GaussianBlur(f, (0, 0), 1.0)
    return 1e3 * (time.process_time() - t0) / 200


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--real", type=Path, default=None, help="folder with opencv_left_right_chessboard/ (shared data/real)")
    ap.add_argument("--charuco-photo", type=Path, default=ROOT / "tests" / "data" / "charuco_opencv" / "choriginal.jpg")
    ap.add_argument("--views", type=int, default=10, help="rendered views per case and board (hard cases)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sections", default="speed,jobs,track,hard,photo,real",
                    help="comma-separated: speed, jobs, track, hard (rendered hard cases), photo, real")
    ap.add_argument("--sets", type=Path, default=Path(tempfile.gettempdir()) / "jcalib-bench-detection",
                    help="folder of the rendered image sets (made on first use)")
    ap.add_argument("--sizes", default="640x480,1280x960,1600x1200,6016x4016")
    ap.add_argument("--count", type=int, default=10, help="images per set")
    ap.add_argument("--count-large", type=int, default=3, help="images per set at 6016x4016")
    ap.add_argument("--before", type=Path, nargs="+", default=None,
                    help="records saved by --save with the code before (several files are merged)")
    ap.add_argument("--conditions", default=",".join(CONDITIONS), help="comma-separated sets to run")
    ap.add_argument("--save", type=Path, default=None, help="write this code's speed records (JSON)")
    ap.add_argument("--no-opencv", action="store_true", help="leave out OpenCV's finders alone")
    args = ap.parse_args(argv)
    sections = set(args.sections.split(","))
    t0 = time.perf_counter()
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())} ({os.cpu_count()} cores); "
          f"reference: {reference_ms():.2f} ms for a 640x480 float Gaussian blur on one core")  # fmt: skip
    if "speed" in sections:
        before = {k: v for f in args.before for k, v in json.loads(f.read_text()).items()} if args.before else None
        speed(args.sets, args.sizes.split(","), args.count, args.count_large, before, args.save, not args.no_opencv,
              args.conditions.split(","))
    if "jobs" in sections:
        jobs_check(args.sets)
    if "track" in sections:
        tracking()
    if "hard" in sections:
        totals = rendered(args.views, args.seed)
        (f0, f1, w0, w1) = (sum(c[0][0] for c in totals), sum(c[1][0] for c in totals),
                            sum(c[0][2] for c in totals), sum(c[1][2] for c in totals))  # fmt: skip
        print(f"rendered total: boards found {f0} -> {f1} with retries; wrong boards {w0} -> {w1}")
    if "photo" in sections:
        photo(args.charuco_photo)
    if "real" in sections and args.real is not None:
        covered_rows(args.real)
        real_sets(args.real)
    print(f"\nload average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; reference: {reference_ms():.2f} ms")
    print(f"{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
