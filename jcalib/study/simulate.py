"""One simulated trial of a study: ground truth, station poses and noisy measurements.

Every random number of trial ``i`` comes from its own generator, derived from ``(seed, i)`` only
(:func:`trial_rng`), so a trial is the same whichever batch or worker runs it. Draws happen in a
fixed order whatever the outcome (a dropped station still consumes its noise draws).

Frames and units as in DESIGN.md: ``T_a_b`` maps b to a, metres, radians inside, degrees in names.
The board is printed on its -z side; cameras look along the target's +z axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jcalib.study.scenario import Scenario

__all__ = ["CameraTrial", "HandEyeTrial", "TCPTrial", "simulate_trial", "trial_rng"]


def trial_rng(seed: int, trial: int) -> np.random.Generator:
    """The generator of trial ``trial`` of a study with ``seed``: ``SeedSequence(seed).spawn(...)[trial]``.

    Depends on ``(seed, trial)`` only, never on the batch or the worker that runs the trial.
    """
    return np.random.default_rng(np.random.SeedSequence(entropy=int(seed), spawn_key=(int(trial),)))


# ------------------------------------------------------------------------------------ small SE(3)


def _pose(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _inv(T: np.ndarray) -> np.ndarray:
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def _exp_so3(w: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of rotation vectors ``(..., 3)`` (rad), Rodrigues."""
    w = np.asarray(w, dtype=np.float64)
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    return np.eye(3) + a * K + b * (K @ K)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def perturb_poses(T: np.ndarray, rng: np.random.Generator, sigma_m: float, sigma_deg: float) -> np.ndarray:
    """Measured flange poses ``T · [Exp(ω) | v]``: ω ~ N(0, σ_rot²), v ~ N(0, σ_m²) per flange axis.

    Args:
        T: (N, 4, 4) true poses, m.  sigma_m: m.  sigma_deg: deg.
    Returns:
        (N, 4, 4) perturbed poses (the right perturbation of the robot pose model, to first order).
    """
    w = np.radians(sigma_deg) * rng.normal(size=(len(T), 3))
    v = sigma_m * rng.normal(size=(len(T), 3))
    D = np.zeros((len(T), 4, 4))
    D[:, :3, :3] = _exp_so3(w)
    D[:, :3, 3] = v
    D[:, 3, 3] = 1.0
    return T @ D


# ------------------------------------------------------------------------------------ model objects


def camera_model(scenario: Scenario):
    """The scenario's true camera model."""
    from jcalib.geometry.cameras import camera_model_from_name

    c = scenario.camera
    return camera_model_from_name(c["model"], tuple(c["image_size"]), np.asarray(c["params"], np.float64))


def board(scenario: Scenario):
    """The scenario's checkerboard (:class:`jcalib.geometry.Checkerboard`)."""
    from jcalib.geometry import Checkerboard

    t = scenario.target
    return Checkerboard(cols=int(t["cols"]), rows=int(t["rows"]), square=float(t["square"]))


# ------------------------------------------------------------------------------------ strategies


def _rot(axis: str, a: float) -> np.ndarray:
    return _exp_so3(np.radians(a) * {"X": np.array([1.0, 0, 0]), "Y": np.array([0, 1.0, 0]),
                                     "Z": np.array([0, 0, 1.0])}[axis])


def target_cam_views(scenario: Scenario, rng: np.random.Generator, camera, points: np.ndarray) -> np.ndarray:
    """(N, 4, 4) ``T_target_cam`` of the station strategy (hand-eye and camera cells), m."""
    from jcalib.geometry import views as rc
    from jcalib.sim.scene import random_calibration_views

    st = scenario.stations
    o = st.options
    centre = points.mean(axis=0)
    if st.strategy == "random":
        T_ct = random_calibration_views(camera, points, int(o["count"]), rng, fill=tuple(o["fill"]),
                                        max_tilt_deg=float(o["max_tilt_deg"]), max_roll_deg=float(o["max_roll_deg"]))
        return _inv(np.stack(T_ct))
    if st.strategy == "robocalib_handeye":
        D = float(o["distance_m"])
        T0 = rc.frontal_view(centre, D)
        views = [T0]
        for axis in ("Z", "Y", "X"):
            for a in o[f"angles_{axis.lower()}_deg"]:
                views.append(rc.recentre(rc.rotate_camera(T0, axis, np.radians(a)), centre, D))
        return np.stack(views)
    if st.strategy == "robocalib_viewsets":
        D, t = float(o["distance_m"]), float(o["tilt_deg"])
        views = [rc.frontal_view(centre, D)]
        views += [rc.tilted_view(centre, D, ax, np.radians(s * t)) for ax in ("X", "Y") for s in (1.0, -1.0)]
        views.append(rc.origin_view(D))
        views += [rc.height_view(centre, D, float(h), np.radians(float(r))) for h in o["heights"]
                  for r in o["rolls_deg"]]
        return np.stack(views)
    if st.strategy == "file":
        return np.asarray(st.T_target_cam, dtype=np.float64).copy()
    raise AssertionError(st.strategy)  # validated by load_scenario


# ------------------------------------------------------------------------------------ trials


@dataclass
class HandEyeTrial:
    """A simulated eye-in-hand data set.

    Attributes:
        T_flange_cam: (4, 4) true hand-eye transform, m.  T_base_target: (4, 4) true board pose, m.
        T_base_flange: (N, 4, 4) measured (noisy) flange poses of the kept stations, m.
        point_index: per kept station, the indices of the board corners seen.
        pixels: per kept station, (k, 2) noisy corner pixels, px.
        points: (M, 3) board corners, target frame, m.
        num_planned: stations planned (before dropouts and views without enough corners).
    """

    T_flange_cam: np.ndarray
    T_base_target: np.ndarray
    T_base_flange: np.ndarray
    point_index: list[np.ndarray]
    pixels: list[np.ndarray]
    points: np.ndarray
    num_planned: int


@dataclass
class CameraTrial:
    """A simulated camera-calibration data set: per kept view the corner indices and noisy pixels."""

    point_index: list[np.ndarray]
    pixels: list[np.ndarray]
    points: np.ndarray
    num_planned: int


@dataclass
class TCPTrial:
    """A simulated camera-based TCP data set.

    Attributes:
        p_flange_tip: (3,) true tool tip in the flange frame, m.
        R_base_cam: (3, 3) camera orientation (known to the estimators).
        T_base_flange: (N, 4, 4) measured flange poses (robot noise on top of the servo residual), m.
        ray_base: (3,) direction of the viewing ray of the tip pixel in the base frame.
        servo_sigma_m: σ of the servo residual per image axis converted to metres at the tip depth.
    """

    p_flange_tip: np.ndarray
    R_base_cam: np.ndarray
    T_base_flange: np.ndarray
    ray_base: np.ndarray
    servo_sigma_m: float
    num_planned: int


#: Fewest corners a view must keep to be used (below this a planar pose is poorly determined).
MIN_CORNERS = 8


def _observe(scenario: Scenario, rng, camera, points, T_cam_target: np.ndarray):
    """Noisy corners of every view; views lost to dropout or with too few corners are marked."""
    from jcalib.sim.scene import project_target

    n = len(T_cam_target)
    noise = scenario.noise.pixel_sigma_px * rng.normal(size=(n, len(points), 2))
    dropped = rng.random(n) < scenario.noise.dropout_rate
    keep, idx_list, pix_list = [], [], []
    for i in range(n):
        pix, vis = project_target(camera, T_cam_target[i], points)
        idx = np.flatnonzero(vis)
        if dropped[i] or len(idx) < MIN_CORNERS:
            continue
        keep.append(i)
        idx_list.append(idx)
        pix_list.append(pix[idx] + noise[i, idx])
    return np.asarray(keep, dtype=np.int64), idx_list, pix_list


def simulate_handeye(scenario: Scenario, rng: np.random.Generator) -> HandEyeTrial:
    """An eye-in-hand trial: random ``T_flange_cam`` (any rotation, translation within ±0.1 m), the board
    0.6 m in front of the base facing up (random yaw), the strategy's views, noisy corners and poses."""
    camera, points = camera_model(scenario), board(scenario).points
    X = _pose(_random_rotation(rng), rng.uniform(-0.1, 0.1, 3))
    yaw = rng.uniform(-np.pi, np.pi)
    T_base_target = _pose(_exp_so3(np.array([0.0, 0.0, yaw])) @ _rot("X", 180.0), [0.6, 0.1, 0.0])
    T_tc = target_cam_views(scenario, rng, camera, points)
    T_bf_true = T_base_target @ T_tc @ _inv(X)
    n = scenario.noise
    T_bf_meas = perturb_poses(T_bf_true, rng, n.robot_translation_m, n.robot_rotation_deg)
    keep, idx, pix = _observe(scenario, rng, camera, points, _inv(T_tc))
    return HandEyeTrial(T_flange_cam=X, T_base_target=T_base_target, T_base_flange=T_bf_meas[keep],
                        point_index=idx, pixels=pix, points=points, num_planned=len(T_tc))


def simulate_camera(scenario: Scenario, rng: np.random.Generator) -> CameraTrial:
    """A camera-calibration trial: the strategy's views of the board, noisy corners."""
    camera, points = camera_model(scenario), board(scenario).points
    T_tc = target_cam_views(scenario, rng, camera, points)
    _, idx, pix = _observe(scenario, rng, camera, points, _inv(T_tc))
    return CameraTrial(point_index=idx, pixels=pix, points=points, num_planned=len(T_tc))


def simulate_tcp(scenario: Scenario, rng: np.random.Generator) -> TCPTrial:
    """A camera-based TCP trial (the thesis' setting).

    A fixed camera (random orientation ``R_base_cam``) sees the tool tip on its optical axis at
    ``tip_depth_m``; the tip is ``p_flange_tip`` (±50 mm across, 100–250 mm along the flange z).
    ``tcp_three_pose``: pose 1 = pose 0 rotated by ``alpha_deg`` about the camera z axis, pose 2 by
    ``beta_deg`` about the camera x axis, each followed by a servo translation in the camera x-y plane
    back onto the pixel. ``random``: ``count`` poses rotated by 50–100 % of ``rotation_deg`` about
    random axes, the tip moved back onto the ray. The servo stops within the pixel noise: a residual
    of N(0, (σ_px · depth / f)²) per image axis. The recorded poses also carry the robot noise.
    """
    n = scenario.noise
    o = scenario.stations.options
    depth = float(o["tip_depth_m"])
    f = float(np.mean(scenario.camera["params"][:2]))
    servo_sigma_m = n.pixel_sigma_px * depth / f
    Rc = _random_rotation(rng)
    x = np.array([*rng.uniform(-0.05, 0.05, 2), rng.uniform(0.10, 0.25)])
    R0 = _random_rotation(rng)
    cam_centre = np.array([1.0, 0.0, 0.8])
    p0 = cam_centre + depth * Rc[:, 2]
    t0 = p0 - R0 @ x
    if scenario.stations.strategy == "tcp_three_pose":
        rel = [Rc @ _rot("Z", o["alpha_deg"]) @ Rc.T, Rc @ _rot("X", o["beta_deg"]) @ Rc.T]
        servo_xy_only = True
    else:
        k = int(o["count"]) - 1
        axes = rng.normal(size=(k, 3))
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        ang = np.radians(o["rotation_deg"]) * rng.uniform(0.5, 1.0, k)
        rel = list(_exp_so3(axes * ang[:, None]))
        servo_xy_only = False
    servo = servo_sigma_m * rng.normal(size=(len(rel), 2))
    Rs, ts = [R0], [t0]
    for j, Rrel in enumerate(rel):
        R = Rrel @ R0
        tip = R @ x + t0  # rotated about the flange origin, before the servo
        d_cam = Rc.T @ (tip - p0)
        if servo_xy_only:  # servo in the camera x-y plane only: depth may change (thesis)
            shift = -Rc[:, :2] @ d_cam[:2]
        else:  # back onto the ray at the initial depth
            shift = -(tip - p0)
        ts.append(t0 + shift + Rc[:, :2] @ servo[j])
        Rs.append(R)
    T_true = np.stack([_pose(R, t) for R, t in zip(Rs, ts)])
    T_meas = perturb_poses(T_true, rng, n.robot_translation_m, n.robot_rotation_deg)
    return TCPTrial(p_flange_tip=x, R_base_cam=Rc, T_base_flange=T_meas, ray_base=Rc[:, 2],
                    servo_sigma_m=float(servo_sigma_m), num_planned=len(T_true))


def simulate_trial(scenario: Scenario, seed: int, trial: int):
    """The data of trial ``trial`` (:class:`HandEyeTrial`, :class:`TCPTrial` or :class:`CameraTrial`)."""
    rng = trial_rng(seed, trial)
    return {"handeye": simulate_handeye, "tcp": simulate_tcp, "camera": simulate_camera}[scenario.cell](scenario, rng)
