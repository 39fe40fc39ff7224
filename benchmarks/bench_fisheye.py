"""The fisheye (KB4) model end to end on rendered wide-angle images, and its σ by Monte Carlo.

The scene is the one of ``tests/problems/test_fisheye_end_to_end.py`` (``tests/problems/fisheye_scene.py``):
a 1024x768 fisheye of 174° x 130° (over 180° on the diagonal), a ChArUco 9x7 board in views spread over
the whole image, near the rim too. Printed:

1. detection per view (``jcalib detect``'s pipeline on the rendered PNGs): corners found, corners of
   the board inside the image, largest angle from the optical axis, the detector's attempt, RMS error
   against the true projections;
2. the calibration (``jcalib.calibrate``, ``model: fisheye``): each intrinsic's estimate, σ, truth and
   z = (estimate - truth) / σ;
3. a Monte Carlo on the same views and corners (true projections + Gaussian noise, fixed seed):
   per parameter the RMS and mean of z, the reported σ over the empirical spread, and the χ² test of
   Σ d² (d² = eᵀ Σ⁻¹ e of the 8 intrinsics) against χ²(8 · trials), plus a KS test of the d².

Run: ``.venv/bin/python benchmarks/bench_fisheye.py [--views 12] [--seed 1] [--trials 200] [--sigma 0.1]``
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "problems"))
from fisheye_scene import (  # noqa: E402
    BOARD,
    CAMERA,
    CELL,
    PARAM_NAMES,
    RENDER,
    TEXTURE_M_PER_PX,
    TRUE_PARAMS,
    board_views,
    observations,
)

import jcalib  # noqa: E402
from jcalib.io.cell import parse_cell  # noqa: E402
from jcalib.io.observations import parse_observations  # noqa: E402
from jcalib.pipeline.images import detect_images  # noqa: E402
from jcalib.sim.render import render_target_image  # noqa: E402
from jcalib.sim.scene import project_target  # noqa: E402
from jcalib.sim.textures import target_texture  # noqa: E402


def true_pixels(views, index):
    """Per view the true pixels of the points ``index`` and their angles from the axis (degrees)."""
    p_cam = [BOARD.points[i] @ T[:3, :3].T + T[:3, 3] for T, i in zip(views, index)]
    stacked = np.concatenate(p_cam)
    pixels = np.asarray(CAMERA.project(stacked))
    angles = np.degrees(np.arctan2(np.linalg.norm(stacked[:, :2], axis=1), stacked[:, 2]))
    split = np.cumsum([len(p) for p in p_cam])[:-1]
    return np.split(pixels, split), np.split(angles, split)


def rendered_set(num_views: int, seed: int):
    texture = target_texture(BOARD, TEXTURE_M_PER_PX)
    views = board_views(CAMERA, BOARD, num_views, seed)
    with tempfile.TemporaryDirectory() as folder:
        paths = []
        t0 = time.perf_counter()
        for i, T in enumerate(views):
            paths.append(Path(folder) / f"v{i:02d}.png")
            cv2.imwrite(str(paths[-1]), render_target_image(CAMERA, T, texture, RENDER, rng=100 + i))
        t_render = time.perf_counter() - t0
        t0 = time.perf_counter()
        notes: dict[str, str] = {}
        obs, failures = detect_images(CELL, "cam0", paths, progress=False, notes=notes)
        t_detect = time.perf_counter() - t0
        notes = {Path(k).stem: v for k, v in notes.items()}
    return views, obs, failures, notes, t_render, t_detect


def detection_table(views, obs, failures, notes) -> None:
    by_id = {s.id: s.detections[0] for s in obs.stations}
    found = [i for i in range(len(views)) if f"v{i:02d}" in by_id]
    dets = [by_id[f"v{i:02d}"] for i in found]
    truth, angles = true_pixels([views[i] for i in found], [d.point_index for d in dets])
    rows = dict(zip(found, zip(dets, truth, angles)))
    failed = {Path(k).stem: v for k, v in failures.items()}
    print(f"\n## Detection per view (ChArUco {BOARD.squares_x}x{BOARD.squares_y}, {BOARD.num_points} corners)\n")
    print("| view | found | in image | max angle from axis (deg) | RMS error vs truth (px) | max (px) | detector attempt |")
    print("|------|-------|----------|---------------------------|-------------------------|----------|------------------|")
    for i, T in enumerate(views):
        name = f"v{i:02d}"
        in_image = int(project_target(CAMERA, T, BOARD.points)[1].sum())
        if i not in rows:
            print(f"| {name} | 0 | {in_image} | - | - | - | failed: {failed.get(name, '?')} |")
            continue
        d, t, a = rows[i]
        e = np.linalg.norm(d.pixels - t, axis=1)
        note = notes.get(name, "")  # retry_note: "found by attempt A (tried ...); N points inconsistent ..."
        attempt = note.split("found by attempt ")[1].split(" (")[0] if "found by attempt" in note else "default"
        dropped = note.split("; ")[-1].split(" points")[0] if "inconsistent" in note else "0"
        print(f"| {name} | {len(d.point_index)} | {in_image} | {a.max():.1f} | {np.sqrt(np.mean(e**2)):.3f} | "
              f"{e.max():.2f} | {attempt} (dropped {dropped}) |")


def calibration_table(result) -> None:
    cal = result.details
    p = np.asarray(cal.cameras["cam0"].params)
    s = np.sqrt(np.diag(cal.intrinsics_covariance["cam0"]))
    print(f"\n## Calibration (model fisheye): status {cal.status}, {len(cal.station_ids)} views, "
          f"corner RMS {cal.rms['corner']:.3f} px, a-posteriori sigma {cal.sigma_px:.3f} px, "
          f"{len(cal.outliers)} corners rejected\n")
    print("| param | estimate | sigma | truth | (estimate - truth) / sigma |")
    print("|-------|----------|-------|-------|----------------------------|")
    for name, e, sd, t in zip(PARAM_NAMES, p, s, TRUE_PARAMS):
        print(f"| {name} | {e:.6g} | {sd:.3g} | {t:.6g} | {(e - t) / sd:+.2f} |")


def monte_carlo(views, obs, trials: int, sigma_px: float) -> None:
    index = [s.detections[0].point_index for s in obs.stations]
    views = [views[int(s.id[1:])] for s in obs.stations]
    clean, _ = true_pixels(views, index)
    cell = parse_cell(CELL)
    rng = np.random.default_rng(2025)
    errors, covariances, times, status = [], [], [], []
    for _ in range(trials):
        noisy = parse_observations(observations(index, [c + sigma_px * rng.standard_normal(c.shape) for c in clean]))
        t0 = time.perf_counter()
        cal = jcalib.calibrate_cell(cell, noisy, jcalib.CalibrationOptions())
        times.append(time.perf_counter() - t0)
        status.append(cal.status)
        errors.append(np.asarray(cal.cameras["cam0"].params) - TRUE_PARAMS)
        covariances.append(np.asarray(cal.intrinsics_covariance["cam0"]))
    e, S = np.array(errors), np.array(covariances)
    sd = np.sqrt(np.diagonal(S, axis1=1, axis2=2))
    z = e / sd
    d2 = np.einsum("ti,ti->t", e, np.linalg.solve(S, e[..., None])[..., 0])
    dof = len(PARAM_NAMES)
    total = float(d2.sum())
    p_upper = float(stats.chi2(dof * trials).sf(total))
    p_two = 2.0 * min(p_upper, 1.0 - p_upper)
    ks = float(stats.kstest(d2, stats.chi2(dof).cdf).pvalue)
    lo, hi = stats.chi2(dof * trials).ppf([0.001, 0.999])
    print(f"\n## Monte Carlo: {trials} trials, the rendered set's views and corners ({sum(map(len, index))}), "
          f"Gaussian noise sigma {sigma_px} px per axis, default options (a-posteriori sigma)\n")
    print(f"{np.mean(np.array(status) == 'converged') * 100:.0f}% converged; median solve "
          f"{np.median(times[1:]) * 1e3:.0f} ms (first, with compilation: {times[0]:.1f} s)\n")
    print("| param | RMS z | mean z | reported sigma (RMS) | empirical sigma | reported / empirical |")
    print("|-------|-------|--------|----------------------|-----------------|----------------------|")
    for k, name in enumerate(PARAM_NAMES):
        rep, emp = np.sqrt(np.mean(sd[:, k] ** 2)), np.sqrt(np.mean(e[:, k] ** 2))
        print(f"| {name} | {np.sqrt(np.mean(z[:, k] ** 2)):.3f} | {z[:, k].mean():+.3f} | {rep:.4g} | {emp:.4g} | "
              f"{rep / emp:.3f} |")
    band = np.sqrt(stats.chi2(trials).ppf([0.001, 0.999]) / trials)
    print(f"\n(RMS z of an honest σ: 1, 99.8 % sampling band for {trials} trials [{band[0]:.3f}, {band[1]:.3f}])")
    print(f"\nSum of d2 over trials: {total:.1f}; chi2({dof * trials}) central 99.8 %: [{lo:.1f}, {hi:.1f}]; "
          f"two-sided p = {p_two:.3f}; mean d2 {d2.mean():.3f} (expected {dof}); KS p (d2 vs chi2({dof})) = {ks:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=12, help="rendered views (default 12, as the test)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the board views (default 1, as the test)")
    parser.add_argument("--trials", type=int, default=200, help="Monte Carlo trials (default 200)")
    parser.add_argument("--sigma", type=float, default=0.1, help="Monte Carlo pixel noise per axis, px")
    args = parser.parse_args()
    if args.trials < 2 or args.views < 3:
        parser.error("--trials must be >= 2 and --views >= 3")

    rays, _ = CAMERA.unproject_valid(np.array([[0.0, 0.0], [CAMERA.image_size[0] - 1.0, 0.0]]))
    print(f"# Fisheye (KB4) end to end: {CAMERA.image_size[0]}x{CAMERA.image_size[1]}, truth "
          + ", ".join(f"{n} {v:g}" for n, v in zip(PARAM_NAMES, TRUE_PARAMS))
          + f"; diagonal field of view {2 * np.degrees(np.arccos(np.asarray(rays)[0, 2])):.0f} deg")
    views, obs, failures, notes, t_render, t_detect = rendered_set(args.views, args.seed)
    print(f"\nrendered {args.views} views in {t_render:.1f} s, detected in {t_detect:.1f} s "
          f"({len(failures)} failed)")
    detection_table(views, obs, failures, notes)
    t0 = time.perf_counter()
    result = jcalib.calibrate(CELL, obs)
    print(f"\n(calibration {time.perf_counter() - t0:.1f} s, with compilation)")
    calibration_table(result)
    monte_carlo(views, obs, args.trials, args.sigma)


if __name__ == "__main__":
    main()
