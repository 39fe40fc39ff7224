"""Valid input documents of every kind jcalib reads, small and self-contained (no sibling folders),
for the fuzz suite to mutate. Numbers are plausible (metres, pixels inside the images), not solvable."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np

CELL_YAML = """schema: jcalib.cell/1
robot:
  model: kuka_kr10_r1100_sixx
  pose_noise: {translation_m: 0.0001, rotation_deg: 0.01}
cameras:
  cam_hand: {model: opencv4, mount: flange}
  cam_fixed:
    model: opencv5
    mount: base
    intrinsics: {K: [[720.0, 0.0, 322.0], [0.0, 718.0, 241.0], [0.0, 0.0, 1.0]], dist: [-0.12, 0.05, 0.0, 0.0, 0.0]}
    fix: [fx, fy, cx, cy, k1, k2, p1, p2, k3]
targets:
  board: {type: checkerboard, cols: 4, rows: 3, square: 0.025, mount: base}
tools:
  torch: {observed_by: [cam_fixed]}
points:
  divot: {position: [0.5, 0.1, 0.0]}
"""

CELL = {
    "schema": "jcalib.cell/1",
    "robot": {"model": "kuka_kr10_r1100_sixx", "pose_noise": {"translation_m": 0.0001, "rotation_deg": 0.01}},
    "cameras": {
        "cam_hand": {"model": "opencv4", "mount": "flange"},
        "cam_fixed": {"model": "opencv5", "mount": "base",
                      "intrinsics": {"K": [[720.0, 0.0, 322.0], [0.0, 718.0, 241.0], [0.0, 0.0, 1.0]],
                                     "dist": [-0.12, 0.05, 0.0, 0.0, 0.0]},
                      "fix": ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]},
    },
    "targets": {"board": {"type": "checkerboard", "cols": 4, "rows": 3, "square": 0.025, "mount": "base"}},
    "tools": {"torch": {"observed_by": ["cam_fixed"]}},
    "points": {"divot": {"position": [0.5, 0.1, 0.0]}},
}

BOARD = np.array([[0.025 * c, 0.025 * r, 0.0] for r in range(3) for c in range(4)])
SIZE = (640, 480)


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _pose(R: np.ndarray, t) -> list:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T.tolist()


def observations(num_stations: int = 4) -> dict:
    """Hand-camera board detections (pinhole projection from above) and one tool-tip detection."""
    stations = []
    K = np.array([[500.0, 0, 320.0], [0, 500.0, 240.0], [0, 0, 1]])
    for i in range(num_stations):
        # the camera looks down at the board from 0.4 m, shifted a little per station
        p_cam = BOARD + [-0.04 + 0.005 * i, -0.025, 0.4]
        uv = (K @ p_cam.T).T
        pixels = (uv[:, :2] / uv[:, 2:]).tolist()
        stations.append({
            "id": f"s{i:03d}",
            "T_base_flange": _pose(_rot_x(np.pi), [0.6 + 0.01 * i, 0.0, 0.45]),
            "detections": [{"camera": "cam_hand", "target": "board", "point_index": list(range(len(BOARD))),
                            "pixels": pixels}],
        })
    stations.append({"id": "t000", "T_base_flange": _pose(np.eye(3), [0.5, 0.2, 0.6]),
                     "detections": [{"camera": "cam_fixed", "tool": "torch", "pixel": [300.5, 200.25]}],
                     "contacts": [{"tool": "torch", "point": "divot"}]})
    return {"schema": "jcalib.observations/1",
            "cameras": {"cam_hand": {"image_size": list(SIZE)}, "cam_fixed": {"image_size": list(SIZE)}},
            "targets": {"board": {"points": BOARD.tolist()}},
            "stations": stations}


def result() -> dict:
    """A result with two cameras, a TCP, a fixed target (work object) and a point, with provenance."""
    cov6 = (np.diag([1e-6, 1e-6, 1e-6, 1e-8, 1e-8, 1e-8])).tolist()
    return {
        "schema": "jcalib.result/1",
        "cameras": {
            "cam_hand": {"model": "opencv4", "image_size": list(SIZE),
                         "K": [[500.0, 0.0, 320.0], [0.0, 501.0, 240.0], [0.0, 0.0, 1.0]],
                         "dist": [-0.1, 0.02, 0.0, 0.0], "std": {"fx": 0.5, "fy": 0.5}},
            "cam_fixed": {"model": "opencv5", "image_size": list(SIZE),
                          "K": [[720.0, 0.0, 322.0], [0.0, 718.0, 241.0], [0.0, 0.0, 1.0]],
                          "dist": [-0.12, 0.05, 0.0, 0.0, 0.0]},
        },
        "transforms": {
            "T_flange_cam_hand": {"matrix": _pose(np.eye(3), [0.0, 0.05, 0.1]), "covariance": cov6},
            "T_base_cam_fixed": {"matrix": _pose(_rot_x(0.3), [0.4, 0.3, 0.8]), "covariance": cov6},
            "T_flange_torch": {"matrix": _pose(np.eye(3), [0.0, 0.0, 0.2]), "covariance": cov6},
            "T_base_board": {"matrix": _pose(np.eye(3), [0.6, 0.0, 0.0]), "covariance": cov6},
        },
        "points": {"divot": {"position": [0.5, 0.1, 0.0], "frame": "base",
                             "covariance": (np.eye(3) * 1e-8).tolist()}},
        "stats": {"rms_px": 0.21, "num_residuals": 400, "sigma_px": 0.2},
        "provenance": {"input_hash": "sha256:" + "0" * 64, "jcalib_version": "0.1.0",
                       "options": {"loss": "none"}, "created": "2026-11-21T10:00:00Z"},
    }


def plan(num_stations: int = 3) -> dict:
    return {"schema": "jcalib.plan/1",
            "stations": [{"id": f"s{i:03d}", "T_base_flange": _pose(_rot_x(np.pi), [0.6, 0.01 * i, 0.45]),
                          "move": "joint"} for i in range(num_stations)]}


def pixels() -> dict:
    return {"schema": "jcalib.pixels/1", "sigma_px": 0.3,
            "cameras": {"cam_fixed": {"image_size": list(SIZE)}},
            "stations": [{"id": "s0", "T_base_flange": _pose(np.eye(3), [0.5, 0.0, 0.6]),
                          "pixels": {"cam_fixed": {"p1": [300.0, 200.0], "p2": [350.0, 210.0]},
                                     "cam_hand": {"p1": [310.0, 250.0], "p2": [330.0, 260.0]}}}]}


def points() -> dict:
    cov = (np.eye(3) * 1e-8).tolist()
    return {"schema": "jcalib.pipeline.points/1", "frame": "base",
            "points": {"p1": {"position": [0.5, 0.0, 0.0], "frame": "base", "covariance": cov},
                       "p2": {"position": [0.6, 0.0, 0.0], "frame": "base", "covariance": cov},
                       "p3": {"position": [0.5, 0.1, 0.0], "frame": "base", "covariance": cov}}}


def session_meta() -> dict:
    return {"schema": "jcalib.session/1", "jcalib_version": "0.1.0", "created": "2026-11-21T10:00:00.000Z",
            "cell": copy.deepcopy(CELL), "devices": {}, "plan": plan()}


def station_record(i: int = 0) -> dict:
    return {"id": f"s{i:03d}", "T_base_flange": _pose(_rot_x(np.pi), [0.6, 0.01 * i, 0.45]),
            "joints_deg": [0.0, -80.0, 70.0, 0.0, 100.0, -90.0], "time": "2026-11-21T10:00:01.000Z",
            "images": {"cam_hand": f"images/cam_hand/s{i:03d}.png"}, "status": "ok"}


SCENARIO_YAML = """schema: jcalib.study/1
cell: camera
camera: {model: opencv4, image_size: [640, 480], params: [500, 500, 320, 240, -0.1, 0.01, 0, 0]}
target: {cols: 4, rows: 3, square: 0.03}
stations: {strategy: random, count: 4}
estimators: [opencv]
"""


def write_all(folder: Path) -> dict[str, Path]:
    """Write one file of every kind into ``folder``; returns kind -> path."""
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    paths = {
        "cell": folder / "cell.yaml",
        "observations": folder / "observations.json",
        "result": folder / "result.json",
        "plan": folder / "plan.json",
        "pixels": folder / "pixels.json",
        "points": folder / "points.json",
        "scenario": folder / "scenario.yaml",
        "session": folder / "session",
    }
    paths["cell"].write_text(CELL_YAML)
    paths["observations"].write_text(json.dumps(observations()))
    paths["result"].write_text(json.dumps(result()))
    paths["plan"].write_text(json.dumps(plan()))
    paths["pixels"].write_text(json.dumps(pixels()))
    paths["points"].write_text(json.dumps(points()))
    paths["scenario"].write_text(SCENARIO_YAML)
    s = paths["session"]
    (s / "images" / "cam_hand").mkdir(parents=True)
    (s / "session.json").write_text(json.dumps(session_meta()))
    lines = []
    for i in range(2):
        cv2.imwrite(str(s / "images" / "cam_hand" / f"s{i:03d}.png"), np.full((48, 64), 128, np.uint8))
        lines.append(json.dumps(station_record(i)))
    (s / "stations.jsonl").write_text("\n".join(lines) + "\n")
    return paths
