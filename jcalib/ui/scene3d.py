"""The cell page's 3-D view as plain data: frames, camera frustums, targets and stations in the robot base.

Poses come from the latest result where it has them (calibrated) and from the nominal layout otherwise
(:func:`jcalib.planning.cell_layout`); each item says which. The browser draws the lines (``ui/static``);
everything is in metres in the robot base frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["cell_scene"]

#: Depth of a drawn camera frustum, m.
FRUSTUM_DEPTH_M = 0.15


def _frustum(K: np.ndarray, size: tuple[int, int], T_base_cam: np.ndarray, depth: float) -> list[list[float]]:
    w, h = size
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]], dtype=np.float64)
    rays = np.column_stack([(corners[:, 0] - K[0, 2]) / K[0, 0], (corners[:, 1] - K[1, 2]) / K[1, 1], np.ones(4)])
    pts = np.vstack([np.zeros(3), rays * depth])
    return (pts @ T_base_cam[:3, :3].T + T_base_cam[:3, 3]).round(5).tolist()


def _matrix(T: Any) -> list[list[float]]:
    return np.asarray(T, dtype=np.float64).round(6).tolist()


def cell_scene(layout: Any, result: Any = None, planned: list[np.ndarray] | None = None,
               captured: list[np.ndarray] | None = None) -> dict:
    """The 3-D scene of a cell.

    Args:
        layout: :class:`jcalib.planning.CellLayout` (the nominal cell).
        result: a :class:`jcalib.io.result.ResultFile` (calibrated poses replace nominal ones), or None.
        planned, captured: flange poses ``T_base_flange`` (4, 4) of the planned and captured stations, m.

    Returns:
        ``{"frames": [{name, T, size, source}], "frustums": [{name, points (5 x 3), source}],
        "targets": [{name, polygon (k x 3), source}], "stations": {"planned": [T...], "captured": [T...]},
        "home": T}`` (m, robot base frame).
    """
    transforms = dict(result.transforms) if result is not None else {}
    cameras_calibrated = dict(result.cameras) if result is not None else {}

    def pose(name: str, nominal: np.ndarray) -> tuple[np.ndarray, str]:
        entry = transforms.get(name)
        if entry is not None:
            return np.asarray(entry.matrix, dtype=np.float64), "calibrated"
        return np.asarray(nominal, dtype=np.float64), "nominal"

    T_home = np.asarray(layout.T_base_flange_home, dtype=np.float64)
    frames = [{"name": "base", "T": _matrix(np.eye(4)), "size": 0.2, "source": "definition"},
              {"name": "flange (home)", "T": _matrix(T_home), "size": 0.08, "source": "nominal"}]  # fmt: skip
    frustums = []
    for name, cam in layout.cameras.items():
        T, source = pose(f"T_{cam.mount}_{name}", cam.pose)
        T_base_cam = T_home @ T if cam.mount == "flange" else T
        K = np.asarray(cam.K, dtype=np.float64)
        if name in cameras_calibrated:
            K = np.asarray(cameras_calibrated[name].K, dtype=np.float64)
        frames.append({"name": name, "T": _matrix(T_base_cam), "size": 0.05, "source": source})
        frustums.append({"name": name, "mount": cam.mount, "source": source,
                         "points": _frustum(K, tuple(cam.image_size), T_base_cam, FRUSTUM_DEPTH_M)})  # fmt: skip
    targets = []
    for name, tgt in layout.targets.items():
        T, source = pose(f"T_{tgt.mount}_{name}", tgt.pose)
        T_base_target = T_home @ T if tgt.mount == "flange" else T
        pts = np.asarray(tgt.geometry.points, dtype=np.float64)
        lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
        rect = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
        poly = rect @ T_base_target[:3, :3].T + T_base_target[:3, 3]
        frames.append({"name": name, "T": _matrix(T_base_target), "size": 0.04, "source": source})
        targets.append({"name": name, "mount": tgt.mount, "source": source, "polygon": poly.round(5).tolist()})
    for name, T_nominal in layout.tools.items():
        T, source = pose(f"T_flange_{name}", T_nominal)
        frames.append({"name": f"{name} (TCP at home)", "T": _matrix(T_home @ T), "size": 0.03, "source": source})
    return {
        "frames": frames,
        "frustums": frustums,
        "targets": targets,
        "stations": {"planned": [_matrix(T) for T in planned or []],
                     "captured": [_matrix(T) for T in captured or []]},  # fmt: skip
        "home": _matrix(T_home),
    }
