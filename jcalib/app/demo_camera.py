"""``jcalib demo``: render a simulated camera calibration, detect, calibrate, compare with the truth.

Until the whole-cell demo exists this is the main job: it exercises the renderer, the detector, the
closed-form start, the engine and the covariance end to end, on images it renders itself.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import yaml
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from jcalib.io.atomic import write_text_atomic

#: The simulated camera: a 1280x960 industrial camera with a 6 mm lens (OpenCV 5-coefficient model).
DEMO_K = np.array([[1105.0, 0.0, 648.5], [0.0, 1103.0, 471.2], [0.0, 0.0, 1.0]])
DEMO_DIST = np.array([-0.27, 0.11, 0.0006, -0.0004, -0.02])
DEMO_SIZE = (1280, 960)


def run_demo(out_dir: Path, num_views: int = 20, seed: int = 0, console: Console | None = None) -> dict:
    """Run the demo; returns ``{parameter: (truth, estimate, σ)}`` for camera ``cam0``."""
    from rich.progress import Progress

    from jcalib.problems.api import calibrate
    from jcalib.pipeline.images import detect_images
    from jcalib.geometry import Checkerboard, camera_from_opencv
    from jcalib.io.export import write_opencv_yaml, write_ros_camera_info
    from jcalib.io.observations import save_observations
    from jcalib.sim.render import RenderOptions
    from jcalib.sim.scene import camera_calibration_scene, render_dataset
    from jcalib.sim.textures import target_texture

    console = console or Console()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    timings = {}

    camera = camera_from_opencv(DEMO_K, DEMO_DIST, DEMO_SIZE)
    board = Checkerboard(cols=11, rows=8, square=0.02)
    texture = target_texture(board, metres_per_pixel=0.0002)
    scene = camera_calibration_scene(camera, board, texture, num_views, seed=seed, camera_name="cam0")
    options = RenderOptions.preset("realistic")  # ~0.1 px corners: the σ table is a fair test

    t0 = time.perf_counter()
    with Progress(console=console, transient=True) as progress:
        progress.add_task(f"rendering {num_views} views at {DEMO_SIZE[0]}x{DEMO_SIZE[1]}", total=None)
        truth_path = render_dataset(scene, out_dir / "sim", options, seed=seed)
    timings["render"] = time.perf_counter() - t0

    cell = {
        "schema": "jcalib.cell/1",
        "cameras": {"cam0": {"model": "opencv5"}},
        "targets": {"board": {"type": "checkerboard", "cols": 11, "rows": 8, "square": 0.02}},
    }
    write_text_atomic(out_dir / "cell.yaml", yaml.safe_dump(cell, sort_keys=False))

    t0 = time.perf_counter()
    images = sorted((out_dir / "sim" / "images" / "cam0").glob("*.png"))
    obs, failures = detect_images(out_dir / "cell.yaml", "cam0", images)
    save_observations(out_dir / "observations.json", obs)
    timings["detect"] = time.perf_counter() - t0
    for path, err in failures.items():
        console.print(f"[yellow]skipped[/] {escape(f'{path}: {err.reason}')}", highlight=False)

    t0 = time.perf_counter()
    with Progress(console=console, transient=True) as progress:
        progress.add_task("calibrating (closed form, then joint least squares)", total=None)
        result = calibrate(out_dir / "cell.yaml", out_dir / "observations.json")
    timings["calibrate"] = time.perf_counter() - t0
    result.to_json(out_dir / "result.json")
    write_opencv_yaml(result.file, out_dir / "cam0_opencv.yaml")
    write_ros_camera_info(result.file, out_dir / "cam0_camera_info.yaml")

    truth = json.loads(Path(truth_path).read_text())["cameras"]["cam0"]
    K_true, dist_true = np.asarray(truth["K"]), np.asarray(truth["dist"])
    true_params = dict(zip(("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"),
                           [K_true[0, 0], K_true[1, 1], K_true[0, 2], K_true[1, 2], *dist_true]))
    cam = result.file.cameras["cam0"]
    rows = {}
    table = Table(title=f"jcalib demo: camera cam0 from {len(obs.stations)} rendered views")
    for col in ("parameter", "truth", "estimate", "σ", "error", "error / σ"):
        table.add_column(col, justify="left" if col == "parameter" else "right")
    for name, value in zip(cam.param_names, cam.params):
        t, s = true_params[name], cam.std[name]
        rows[name] = (t, float(value), float(s))
        unit = " px" if name in ("fx", "fy", "cx", "cy") else ""
        table.add_row(name, f"{t:.5g}{unit}", f"{value:.5g}{unit}", f"{s:.2g}", f"{value - t:+.2g}", f"{(value - t) / s:+.2f}")
    console.print(table)
    z = np.array([(e - t) / s for t, e, s in rows.values()])
    stats = result.file.stats
    console.print(
        f"reprojection RMS {stats['rms_px']:.3f} px per point ({stats['rms_px_per_coordinate']:.3f} px per coordinate), "
        f"a-posteriori σ {stats['sigma_px']:.3f} px, "
        f"{stats['iterations']} iterations; max |error/σ| = {np.max(np.abs(z)):.2f} "
        f"(errors consistent with the reported σ when most are below 2)",
        highlight=False,
    )
    console.print(
        "timings: " + ", ".join(f"{k} {v:.1f} s" for k, v in timings.items())
        + f"; images skipped: {len(failures)}",
        highlight=False,
    )
    console.print(escape(f"wrote {out_dir}/result.json, cam0_opencv.yaml, cam0_camera_info.yaml"), highlight=False)
    return rows
