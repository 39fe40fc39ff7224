"""Synthetic robot cells with ground truth: cell spec and observations dicts for tests, benchmarks and
the demo's reference (a flange camera, a fixed camera, a fixed board and a tool; or two robots).

Pixels come from the true flange poses plus Gaussian noise; the files hold flange poses perturbed by
the robot noise (right perturbation, σ per axis), as the cell states.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jcalib.geometry import lie
from jcalib.geometry.cameras import camera_model_from_name
from jcalib.geometry.conversions import pose_to_matrix
from jcalib.geometry.se3 import invert, make_pose, rotation

#: Fewest corners of a view the problems accept (as jcalib.problems.graph.MIN_POINTS_PER_VIEW).
MIN_POINTS_PER_VIEW = 6

__all__ = ["SYNTH_FIXED_PARAMS", "SYNTH_FLANGE_PARAMS", "SYNTH_IMAGE_SIZE", "synthetic_cell", "synthetic_two_robot_cell"]

#: The synthetic demo cell's cameras: opencv5 ``(fx, fy, cx, cy, k1, k2, p1, p2, k3)`` at 1600x1200.
SYNTH_IMAGE_SIZE = (1600, 1200)
SYNTH_FLANGE_PARAMS = np.array([1400.0, 1398.0, 801.5, 598.0, -0.12, 0.08, 0.0005, -0.0003, -0.02])
SYNTH_FIXED_PARAMS = np.array([1800.0, 1801.0, 795.0, 603.0, -0.08, 0.05, 0.0, 0.0, 0.0])


def _look_at(eye, target, up=(0.0, 0.0, 1.0)):
    """``T_base_cam`` of a camera at ``eye`` whose optical axis (+z) points at ``target``."""
    z = np.asarray(target, np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, (1.0, 0.0, 0.0))
    x /= np.linalg.norm(x)
    return make_pose(np.stack([x, np.cross(z, x), z], axis=1), eye)


def _perturb(T, rng, sigma_m, sigma_deg):
    if sigma_m <= 0 and sigma_deg <= 0:
        return T.copy()
    d = np.concatenate([np.radians(sigma_deg) * rng.normal(size=3), sigma_m * rng.normal(size=3)])
    return T @ np.asarray(pose_to_matrix(np.asarray(lie.se3_exp(jnp.asarray(d)))))


def _synth_project(model, T_cam_x, P):
    """Pixels ``(n, 2)`` of points ``P (n, 3)`` in frame x seen by ``model`` at ``T_cam_x``, and whether each
    is in front of the camera and 5 px inside the synthetic image."""
    p = P @ T_cam_x[:3, :3].T + T_cam_x[:3, 3]
    u = np.asarray(model.project(jnp.asarray(p)))
    w, h = SYNTH_IMAGE_SIZE
    ok = (p[:, 2] > 0.05) & (u[:, 0] > 5) & (u[:, 0] < w - 6) & (u[:, 1] > 5) & (u[:, 1] < h - 6)
    return u, ok


def synthetic_cell(
    seed: int = 0,
    *,
    num_board_stations: int = 15,
    num_tool_stations: int = 30,
    sigma_px: float = 0.2,
    tip_sigma_px: float = 0.2,
    robot_m: float = 1e-4,
    robot_deg: float = 0.01,
    truth: dict | None = None,
    board_warp=None,
) -> tuple[dict, dict, dict]:
    """A synthetic demo cell: flange camera ``cam0``, fixed camera ``cam1`` (intrinsics known from a lab
    calibration and held fixed), a 9x6 checkerboard ``board`` fixed on the table, a tool ``needle`` whose
    tip ``cam1`` sees. Pixels come from the true flange poses plus Gaussian noise; the file holds flange
    poses perturbed by the robot noise (right perturbation, σ per axis), as the cell states.

    Args:
        seed: random seed (stations and noise).
        num_board_stations: stations where ``cam0`` (and ``cam1``) see the board.
        num_tool_stations: stations presenting the tool tip to ``cam1``.
        sigma_px, tip_sigma_px: corner / tip pixel noise σ.
        robot_m, robot_deg: robot pose noise σ per axis (m, degrees).
        truth: override true transforms (``T_flange_cam0``, ``T_base_cam1``, ``T_base_board``,
            ``T_flange_needle``, (4, 4) m) and intrinsics (``cam0``, ``cam1`` param vectors), e.g. to
            simulate a bumped camera or a moved TCP with the same geometry.
        board_warp: ``(c0, c1)`` m, a bent board (:func:`jcalib.geometry.targets.warp_bow`): the cameras
            see its corners there; the observations keep the flat design (the cell does not estimate
            the warp unless its target says ``warp: true``).

    Returns:
        ``(cell dict, observations dict, truth dict)``.
    """
    from jcalib.geometry.targets import Checkerboard, warped_points

    rng = np.random.default_rng(seed)
    geo = np.random.default_rng(12345)  # the cell's layout is the same for every seed
    board = Checkerboard(cols=9, rows=6, square=0.03)
    pts = np.asarray(board.points, np.float64)
    seen = pts if board_warp is None else warped_points(pts, board_warp)
    centre_t = pts.mean(axis=0)
    T_base_board = make_pose(rotation((1, 0, 0), np.pi), [0.7, -0.1, 0.0])  # printed face (-z) up
    centre = T_base_board[:3, :3] @ centre_t + T_base_board[:3, 3]
    T_flange_cam0 = make_pose(rotation((0.2, 0.1, 1.0), 0.3), [0.06, -0.03, 0.08])
    T_base_cam1 = _look_at(np.array([1.2, 0.5, 0.6]), centre + np.array([0.05, 0.1, 0.1]))
    T_flange_tool = make_pose(np.eye(3), [0.01, -0.02, 0.18])
    true = {"T_flange_cam0": T_flange_cam0, "T_base_cam1": T_base_cam1, "T_base_board": T_base_board,
            "T_flange_needle": T_flange_tool, "cam0": SYNTH_FLANGE_PARAMS.copy(), "cam1": SYNTH_FIXED_PARAMS.copy()}
    true.update({k: np.asarray(v, np.float64) for k, v in (truth or {}).items()})
    cams = {c: camera_model_from_name("opencv5", SYNTH_IMAGE_SIZE, true[c]) for c in ("cam0", "cam1")}

    def project(cam, T_cam_x, P):
        return _synth_project(cams[cam], T_cam_x, P)

    stations = []
    T_bf_true = []
    # board stations: cam0 looks at the board from 0.35-0.6 m, tilted up to ~35 deg
    k = 0
    while len(T_bf_true) < num_board_stations:
        k += 1
        dirn = np.array([geo.uniform(-0.5, 0.5), geo.uniform(-0.5, 0.5), 1.0])
        eye = centre + geo.uniform(0.35, 0.6) * dirn / np.linalg.norm(dirn)
        T_base_c = _look_at(eye, centre + geo.normal(scale=0.03, size=3), up=(1.0, 0.0, 0.0))
        T_base_c[:3, :3] = T_base_c[:3, :3] @ rotation((0, 0, 1), geo.uniform(-0.6, 0.6))
        T_bf = T_base_c @ invert(true["T_flange_cam0"])
        u, ok = project("cam0", invert(T_bf @ true["T_flange_cam0"]) @ true["T_base_board"], pts)
        if ok.sum() == len(pts):
            T_bf_true.append(T_bf)
    # tool stations: the tip in front of cam1, the tool tilted up to ~40 deg
    look = true["T_base_cam1"]
    while len(T_bf_true) < num_board_stations + num_tool_stations:
        p_cam = np.array([geo.uniform(-0.08, 0.08), geo.uniform(-0.06, 0.06), geo.uniform(0.5, 0.7)])
        p_base = look[:3, :3] @ p_cam + look[:3, 3]
        R = rotation((1, 0, 0), np.pi) @ rotation(geo.normal(size=3), geo.uniform(0.1, 0.7))
        T_bf_true.append(make_pose(R, p_base - R @ true["T_flange_needle"][:3, 3]))
    for i, T_bf in enumerate(T_bf_true):
        dets = []
        if i < num_board_stations:
            for cam, T_cam_board in (
                ("cam0", invert(T_bf @ true["T_flange_cam0"]) @ true["T_base_board"]),
                ("cam1", invert(true["T_base_cam1"]) @ true["T_base_board"]),
            ):
                u, ok = project(cam, T_cam_board, seen)
                idx = np.flatnonzero(ok)
                if idx.size >= MIN_POINTS_PER_VIEW:
                    px = u[idx] + sigma_px * rng.normal(size=(idx.size, 2))
                    dets.append({"camera": cam, "target": "board", "point_index": idx.tolist(), "pixels": px.tolist()})
        else:
            tip = T_bf[:3, :3] @ true["T_flange_needle"][:3, 3] + T_bf[:3, 3]
            u, ok = project("cam1", invert(true["T_base_cam1"]), tip[None])
            if ok[0]:
                dets.append({"camera": "cam1", "tool": "needle",
                             "pixel": (u[0] + tip_sigma_px * rng.normal(size=2)).tolist()})
        T_meas = _perturb(T_bf, rng, robot_m, robot_deg)
        stations.append({"id": f"s{i:03d}", "T_base_flange": T_meas.tolist(), "detections": dets})
    K1, d1 = cams["cam1"].to_opencv()
    cell = {
        "schema": "jcalib.cell/1",
        "cameras": {
            "cam0": {"model": "opencv5", "mount": "flange"},
            "cam1": {"model": "opencv5", "mount": "base",
                     "fix": ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"],
                     "intrinsics": {"K": np.asarray(K1).tolist(), "dist": np.asarray(d1).tolist()}},
        },
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03, "mount": "base"}},
        "tools": {"needle": {"observed_by": ["cam1"]}},
        "robot": {"pose_noise": {"translation_m": robot_m, "rotation_deg": robot_deg}},
    }
    obs = {"schema": "jcalib.observations/1",
           "cameras": {c: {"image_size": list(SYNTH_IMAGE_SIZE)} for c in ("cam0", "cam1")},
           "targets": {"board": {"points": pts.tolist()}}, "stations": stations}
    return cell, obs, true


def synthetic_two_robot_cell(
    seed: int = 0,
    *,
    num_board_stations: int = 12,
    num_r2_stations: int = 12,
    num_cross_stations: int = 6,
    num_tool_stations: int = 16,
    sigma_px: float = 0.2,
    tip_sigma_px: float = 0.2,
    robot_m: float = 1e-4,
    robot_deg: float = 0.01,
) -> tuple[dict, dict, dict]:
    """A synthetic two-robot cell (world frame = robot ``r1``'s base): ``r1`` carries the flange camera
    ``cam0``; ``r2`` (base ``T_world_r2`` unknown) carries a 7x5 checkerboard ``board2`` and a tool
    ``torch``; the world holds a 9x6 ``board`` (on the table) and a camera ``cam1`` (intrinsics given as
    the start, estimated) that sees ``board``, ``board2`` and the torch's tip. Stations: ``cam0`` looks at
    ``board`` (r1 only), ``r2`` presents ``board2`` to ``cam1`` (r2 only), ``cam0`` looks at ``board2``
    held by ``r2`` (both robots), ``r2`` presents the tip to ``cam1``. Pixels from the true poses plus
    Gaussian noise; the file holds each robot's flange poses perturbed by the robot noise (right
    perturbation, σ per axis, both robots alike).

    Returns:
        ``(cell dict, observations dict, truth dict)``; truth holds ``T_world_r1`` (identity),
        ``T_world_r2``, ``T_flange_cam0``, ``T_world_cam1``, ``T_world_board``, ``T_flange_board2``,
        ``T_flange_torch`` ((4, 4), m) and the ``cam0`` / ``cam1`` parameter vectors.
    """
    from jcalib.geometry.targets import Checkerboard

    rng = np.random.default_rng(seed)
    geo = np.random.default_rng(54321)  # the layout is the same for every seed
    boards = {"board": Checkerboard(cols=9, rows=6, square=0.03), "board2": Checkerboard(cols=7, rows=5, square=0.03)}
    pts = {n: np.asarray(b.points, np.float64) for n, b in boards.items()}
    T_world_board = make_pose(rotation((1, 0, 0), np.pi), [0.7, -0.1, 0.0])
    centre = T_world_board[:3, :3] @ pts["board"].mean(axis=0) + T_world_board[:3, 3]
    T_world_r2 = make_pose(rotation((0.05, -0.03, 1.0), 2.4), [1.7, 0.9, 0.05])
    T_flange_cam0 = make_pose(rotation((0.2, 0.1, 1.0), 0.3), [0.06, -0.03, 0.08])
    T_flange_board2 = make_pose(rotation((0.1, -0.2, 1.0), 0.5), [-0.09, -0.06, 0.04])
    T_flange_torch = make_pose(np.eye(3), [0.015, 0.01, 0.21])
    T_world_cam1 = _look_at(np.array([1.2, 0.5, 0.6]), centre + np.array([0.05, 0.1, 0.1]))
    true = {"T_world_r1": np.eye(4), "T_world_r2": T_world_r2, "T_flange_cam0": T_flange_cam0,
            "T_world_cam1": T_world_cam1, "T_world_board": T_world_board, "T_flange_board2": T_flange_board2,
            "T_flange_torch": T_flange_torch, "cam0": SYNTH_FLANGE_PARAMS.copy(), "cam1": SYNTH_FIXED_PARAMS.copy()}
    cams = {c: camera_model_from_name("opencv5", SYNTH_IMAGE_SIZE, true[c]) for c in ("cam0", "cam1")}

    def project(cam, T_cam_x, P):
        return _synth_project(cams[cam], T_cam_x, P)

    def look(eye, at):  # a camera pose at eye looking at `at`, rolled at random
        T = _look_at(eye, at + geo.normal(scale=0.03, size=3), up=(1.0, 0.0, 0.0))
        T[:3, :3] = T[:3, :3] @ rotation((0, 0, 1), geo.uniform(-0.6, 0.6))
        return T

    def facing(T_world_cam, dist):  # a board2 pose in front of a camera, tilted, printed face to it
        c = np.array([geo.uniform(-0.06, 0.06), geo.uniform(-0.05, 0.05), dist])
        T = T_world_cam.copy()
        T[:3, :3] = T_world_cam[:3, :3] @ rotation(geo.normal(size=3), geo.uniform(0.1, 0.6))
        T[:3, 3] = T_world_cam[:3, :3] @ c + T_world_cam[:3, 3] - T[:3, :3] @ pts["board2"].mean(axis=0)
        return T

    stations = []  # (F1 or None, F2 or None) true flange poses in each robot's base
    while len(stations) < num_board_stations:
        dirn = np.array([geo.uniform(-0.5, 0.5), geo.uniform(-0.5, 0.5), 1.0])
        T_wc = look(centre + geo.uniform(0.35, 0.6) * dirn / np.linalg.norm(dirn), centre)
        if project("cam0", invert(T_wc) @ T_world_board, pts["board"])[1].all():
            stations.append((T_wc @ invert(T_flange_cam0), None))
    while len(stations) < num_board_stations + num_r2_stations:
        T_wb = facing(T_world_cam1, geo.uniform(0.45, 0.7))
        if project("cam1", invert(T_world_cam1) @ T_wb, pts["board2"])[1].all():
            stations.append((None, invert(T_world_r2) @ T_wb @ invert(T_flange_board2)))
    hold = np.array([1.0, 0.45, 0.35])
    while len(stations) < num_board_stations + num_r2_stations + num_cross_stations:
        dirn = np.array([geo.uniform(-0.6, 0.2), geo.uniform(-0.6, 0.0), geo.uniform(0.2, 0.6)])
        T_wc = look(hold + geo.uniform(0.4, 0.55) * dirn / np.linalg.norm(dirn), hold)
        T_wb = facing(T_wc, np.linalg.norm(T_wc[:3, 3] - hold))
        if project("cam0", invert(T_wc) @ T_wb, pts["board2"])[1].all():
            stations.append((T_wc @ invert(T_flange_cam0), invert(T_world_r2) @ T_wb @ invert(T_flange_board2)))
    while len(stations) < num_board_stations + num_r2_stations + num_cross_stations + num_tool_stations:
        p_cam = np.array([geo.uniform(-0.08, 0.08), geo.uniform(-0.06, 0.06), geo.uniform(0.5, 0.7)])
        p_world = T_world_cam1[:3, :3] @ p_cam + T_world_cam1[:3, 3]
        R = rotation((1, 0, 0), np.pi) @ rotation(geo.normal(size=3), geo.uniform(0.1, 0.7))
        stations.append((None, invert(T_world_r2) @ make_pose(R, p_world - R @ T_flange_torch[:3, 3])))

    out = []
    for i, (F1, F2) in enumerate(stations):
        W1 = F1
        W2 = None if F2 is None else T_world_r2 @ F2
        dets = []
        views = []
        if W1 is not None and W2 is not None:
            views.append(("cam0", W1 @ T_flange_cam0, "board2", W2 @ T_flange_board2))
        elif W1 is not None:
            views += [("cam0", W1 @ T_flange_cam0, "board", T_world_board), ("cam1", T_world_cam1, "board", T_world_board)]
        elif i < num_board_stations + num_r2_stations:
            views.append(("cam1", T_world_cam1, "board2", W2 @ T_flange_board2))
        for cam, T_wc, tgt, T_wt in views:
            u, ok = project(cam, invert(T_wc) @ T_wt, pts[tgt])
            idx = np.flatnonzero(ok)
            if idx.size >= MIN_POINTS_PER_VIEW:
                px = u[idx] + sigma_px * rng.normal(size=(idx.size, 2))
                dets.append({"camera": cam, "target": tgt, "point_index": idx.tolist(), "pixels": px.tolist()})
        if F1 is None and i >= num_board_stations + num_r2_stations:
            tip = W2[:3, :3] @ T_flange_torch[:3, 3] + W2[:3, 3]
            u, ok = project("cam1", invert(T_world_cam1), tip[None])
            if ok[0]:
                dets.append({"camera": "cam1", "tool": "torch", "pixel": (u[0] + tip_sigma_px * rng.normal(size=2)).tolist()})
        flange = {r: _perturb(F, rng, robot_m, robot_deg).tolist() for r, F in (("r1", F1), ("r2", F2)) if F is not None}
        out.append({"id": f"s{i:03d}", "flange_poses": flange, "detections": dets})
    K1, d1 = cams["cam1"].to_opencv()
    noise = {"pose_noise": {"translation_m": robot_m, "rotation_deg": robot_deg}}
    cell = {
        "schema": "jcalib.cell/1",
        "robots": {"r1": dict(noise), "r2": dict(noise)},
        "cameras": {
            "cam0": {"model": "opencv5", "mount": "flange", "robot": "r1"},
            "cam1": {"model": "opencv5", "mount": "world",
                     "intrinsics": {"K": np.asarray(K1).tolist(), "dist": np.asarray(d1).tolist()}},
        },
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03, "mount": "world"},
                    "board2": {"type": "checkerboard", "cols": 7, "rows": 5, "square": 0.03, "mount": "flange",
                               "robot": "r2"}},
        "tools": {"torch": {"observed_by": ["cam1"], "robot": "r2"}},
    }
    obs = {"schema": "jcalib.observations/1",
           "cameras": {c: {"image_size": list(SYNTH_IMAGE_SIZE)} for c in ("cam0", "cam1")},
           "targets": {n: {"points": p.tolist()} for n, p in pts.items()}, "stations": out}
    return cell, obs, true
