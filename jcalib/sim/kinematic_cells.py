"""Synthetic cells whose robot differs from its nominal kinematics, with ground truth.

A real arm is repeatable to a few hundredths of a millimetre but its joint zeros, link lengths and
twists differ from the nominal model its controller uses, so the flange poses the controller reports
(nominal forward kinematics at the encoder values) are off by up to millimetres, systematically.
These cells simulate that: the robot moves with *true* parameters (nominal plus seeded errors of
realistic size), the observations hold what a controller reports (``joints_deg`` and the nominal
``T_base_flange``), and the pixels or sensor poses come from the true flange poses.

- :func:`synthetic_arm_cell`: a 6-axis arm with a camera on its flange looking at a board fixed in
  its base frame;
- :func:`synthetic_positioner_cell`: a 2-axis part positioner carrying a target, measured by a fixed
  6-DOF sensor (a laser tracker or 3D camera).

Errors are drawn only for the parameters in ``error_mask`` (default: the identifiable subset that the
builder keeps, passed in by the caller), so that the true kinematics, hand-eye and target poses are
the ones the calibration can recover (a change of a parameter that the hand-eye or the board pose can
absorb has no observable meaning).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.geometry import kinematic_models, lie
from jcalib.geometry.cameras import camera_model_from_name
from jcalib.geometry.conversions import pose_to_matrix
from jcalib.geometry.kinematics import inverse_kinematics
from jcalib.geometry.robots import robot_preset
from jcalib.geometry.se3 import invert, make_pose, rotation

__all__ = ["KINEMATIC_ERRORS", "kinematic_errors", "synthetic_arm_cell", "synthetic_positioner_cell"]

#: σ of the simulated kinematic errors per group: joint offsets (rad), link lengths (m), twists (rad).
KINEMATIC_ERRORS = {"joint_offsets": np.radians(0.05), "link_lengths": 0.5e-3, "twists": np.radians(0.05)}

_IMAGE_SIZE = (1600, 1200)
_CAMERA_PARAMS = np.array([1400.0, 1398.0, 801.5, 598.0, -0.12, 0.08, 0.0005, -0.0003, -0.02])


#: Flange poses ``(M, 4, 4)`` of a model at parameters ``(P,)`` and joints ``(M, n)`` (one compile per structure).
_fk = eqx.filter_jit(jax.vmap(kinematic_models.forward, in_axes=(None, None, 0)))


def _exp(d) -> np.ndarray:
    """``(..., 4, 4)`` of tangents ``(..., 6)`` (rx..tz)."""
    return np.asarray(pose_to_matrix(np.asarray(lie.se3_exp(jnp.asarray(d, jnp.float64)))))


def kinematic_errors(model, rng, error_mask=None, scale: float = 1.0) -> np.ndarray:
    """``(P,)`` true parameters: nominal plus Gaussian errors (σ from :data:`KINEMATIC_ERRORS`, times
    ``scale``) on the parameters in ``error_mask`` (``(P,)`` bool; default every joint offset, link
    length and twist)."""
    sigma = np.zeros(model.num_params)
    for g, s in KINEMATIC_ERRORS.items():
        sigma[np.asarray(kinematic_models.select(model, [g]), bool)] = s
    mask = np.ones(model.num_params, bool) if error_mask is None else np.asarray(error_mask, bool)
    return np.asarray(model.nominal, np.float64) + np.where(mask, scale * sigma * rng.normal(size=sigma.size), 0.0)


def _board(cols: int = 9, rows: int = 6, square: float = 0.03) -> np.ndarray:
    from jcalib.geometry.targets import Checkerboard

    return np.asarray(Checkerboard(cols=cols, rows=rows, square=square).points, np.float64)


def _look_at(eye, target, up) -> np.ndarray:
    z = np.asarray(target, np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    return make_pose(np.stack([x, np.cross(z, x), z], axis=1), eye)


def synthetic_arm_cell(seed: int = 0, num_stations: int = 30, num_heldout: int = 20, *,
                       preset: str = "kuka_kr10_r1100_sixx", sigma_px: float = 0.2,
                       repeatability_m: float = 2e-5, repeatability_deg: float = 0.002,
                       error_mask=None, error_scale: float = 1.0, scatter: bool = True,
                       calibrate: tuple[str, ...] = ("joint_offsets", "link_lengths", "twists")):
    """A 6-axis arm (``preset``) with hidden kinematic errors, a camera on its flange and a board.

    The camera looks at the board from 0.3–0.6 m, tilted up to ~45°, rolled about its axis, with the
    arm in the inverse-kinematics solution closest to a random joint vector (so the joints move through
    varied configurations). Stations whose board is not fully in view are redrawn.

    Args:
        seed: noise, kinematic errors and stations; num_stations, num_heldout: fitted and held-out
            stations (held-out ones are not in the observations; the truth has them).
        sigma_px: corner noise; repeatability_m, repeatability_deg: the true flange scatter about the
            true kinematics (σ per axis, none when ``scatter`` is False), also the cell's stated ``pose_noise``.
        error_mask, error_scale: which parameters get errors, and a factor on their σ.
        calibrate: the cell's ``calibrate_kinematics``.

    Returns:
        ``(cell dict, observations dict, truth dict)``; truth: ``params`` (P,) true kinematics,
        ``nominal`` (P,), ``names``, ``cam0`` intrinsics, ``T_flange_cam0``, ``T_base_board``, and
        ``heldout``: ``{"q" (H, n) rad, "T_base_flange" (H, 4, 4) true}`` (also ``fitted`` for the
        fitted stations).
    """
    rng = np.random.default_rng(seed)
    dh = robot_preset(preset)
    model = kinematic_models.from_dh_robot(dh)
    true_params = kinematic_errors(model, rng, error_mask, error_scale)
    pts = _board()
    T_base_board = make_pose(rotation((1, 0, 0), np.pi), [0.55, -0.12, 0.05])  # printed face up
    centre = T_base_board[:3, :3] @ pts.mean(axis=0) + T_base_board[:3, 3]
    T_flange_cam0 = make_pose(rotation((0.3, 0.2, 1.0), 0.4), [0.04, -0.03, 0.07])
    cam = camera_model_from_name("opencv5", _IMAGE_SIZE, _CAMERA_PARAMS)
    def fk_true(q):
        return _fk(model, jnp.asarray(true_params), q)

    def fk_nominal(q):
        return _fk(model, model.nominal, q)

    want = num_stations + num_heldout
    qs: list[np.ndarray] = []
    lo, hi = np.asarray(dh.lower), np.asarray(dh.upper)
    for _ in range(20):
        m = 4 * (want - len(qs))
        targets = []
        for _ in range(m):
            d = np.array([rng.uniform(-0.7, 0.7), rng.uniform(-0.7, 0.7), 1.0])
            eye = centre + rng.uniform(0.3, 0.6) * d / np.linalg.norm(d)
            T_base_cam = _look_at(eye, centre + rng.normal(scale=0.03, size=3), up=(1.0, 0.0, 0.0))
            T_base_cam[:3, :3] = T_base_cam[:3, :3] @ rotation((0, 0, 1), rng.uniform(-1.2, 1.2))
            targets.append(T_base_cam @ invert(T_flange_cam0))
        q0 = rng.uniform(np.maximum(lo, -np.pi), np.minimum(hi, np.pi), size=(m, lo.size))
        ik = inverse_kinematics(dh, np.stack(targets), jnp.asarray(q0), num_seeds=8,
                                key=jax.random.PRNGKey(int(rng.integers(1 << 30))), position_tolerance_m=1e-7,
                                rotation_tolerance_rad=1e-7)
        q_ok = np.asarray(ik.q)[np.asarray(ik.success)]
        if q_ok.size == 0:
            continue
        T_true = np.asarray(fk_true(jnp.asarray(q_ok)))
        for q, T_bf in zip(q_ok, T_true):
            T_cam_board = invert(T_bf @ T_flange_cam0) @ T_base_board
            p = pts @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
            u = np.asarray(cam.project(jnp.asarray(p)))
            w, h = _IMAGE_SIZE
            if np.all((p[:, 2] > 0.05) & (u[:, 0] > 5) & (u[:, 0] < w - 6) & (u[:, 1] > 5) & (u[:, 1] < h - 6)):
                qs.append(q)
            if len(qs) == want:
                break
        if len(qs) == want:
            break
    if len(qs) < want:
        raise RuntimeError(f"synthetic_arm_cell: found only {len(qs)} of {want} reachable stations that see the board")
    q_all = np.stack(qs)
    T_true = np.asarray(fk_true(jnp.asarray(q_all)))
    if scatter:
        d = np.concatenate([np.radians(repeatability_deg) * rng.normal(size=(want, 3)),
                            repeatability_m * rng.normal(size=(want, 3))], axis=1)
        T_true = T_true @ _exp(d)
    T_nominal = np.asarray(fk_nominal(jnp.asarray(q_all)))
    joints_deg = np.asarray(kinematic_models.joints_to_controller(model, q_all))
    stations = []
    for i in range(num_stations):
        T_cam_board = invert(T_true[i] @ T_flange_cam0) @ T_base_board
        p = pts @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
        u = np.asarray(cam.project(jnp.asarray(p))) + sigma_px * rng.normal(size=(len(pts), 2))
        stations.append({"id": f"s{i:03d}", "T_base_flange": T_nominal[i].tolist(), "joints_deg": joints_deg[i].tolist(),
                         "detections": [{"camera": "cam0", "target": "board", "point_index": list(range(len(pts))),
                                         "pixels": u.tolist()}]})
    cell = {
        "schema": "jcalib.cell/1",
        "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
        "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03, "mount": "base"}},
        "robot": {"kinematics": preset, "calibrate_kinematics": list(calibrate),
                  "pose_noise": {"translation_m": repeatability_m, "rotation_deg": repeatability_deg}},
    }
    obs = {"schema": "jcalib.observations/1", "cameras": {"cam0": {"image_size": list(_IMAGE_SIZE)}},
           "targets": {"board": {"points": pts.tolist()}}, "stations": stations}
    truth = {"params": true_params, "nominal": np.asarray(model.nominal, np.float64), "names": list(model.param_names),
             "cam0": _CAMERA_PARAMS.copy(), "T_flange_cam0": T_flange_cam0, "T_base_board": T_base_board,
             "fitted": {"q": q_all[:num_stations], "T_base_flange": T_true[:num_stations]},
             "heldout": {"q": q_all[num_stations:], "T_base_flange": T_true[num_stations:]}}
    return cell, obs, truth


def synthetic_positioner_cell(seed: int = 0, num_stations: int = 30, num_heldout: int = 20, *,
                              sigma_deg: float = 0.005, sigma_m: float = 2e-5, error_mask=None,
                              error_scale: float = 1.0, repeatability_m: float = 1e-5,
                              repeatability_deg: float = 0.001, scatter: bool = True, tilt_range_deg: float = 80.0,
                              calibrate: tuple[str, ...] = ("joint_offsets", "link_lengths", "twists"),
                              form: str = "camera"):
    """A 2-axis tilt-rotate positioner carrying a target, whose pose a fixed 6-DOF sensor measures.

    Args:
        seed: noise, kinematic errors and joint values (tilt within ±``tilt_range_deg``, rotation within ±180°).
        sigma_deg, sigma_m: the sensor's pose noise (right perturbation of ``T_sensor_target``, per axis);
            0 for noiseless data.
        repeatability_m, repeatability_deg: the positioner's scatter about its true kinematics (none
            when ``scatter`` is False) and the cell's ``pose_noise``.
        form: ``"sensor"``: the tracker is a pose sensor of the cell (``sensors:``, measurements
            ``{sensor, target, T_sensor_target}``, no lens, no image size); ``"camera"``: the same data in the
            camera form (a ``pinhole`` camera with an image size, ``{camera, target, T_cam_target}``).

    Returns:
        ``(cell dict, observations dict, truth dict)``; truth as :func:`synthetic_arm_cell` with
        ``T_base_tracker`` and ``T_flange_part`` instead of the camera and board.
    """
    rng = np.random.default_rng(seed)
    model = kinematic_models.PRESETS["positioner_2axis"]()
    true_params = kinematic_errors(model, rng, error_mask, error_scale)
    T_base_tracker = _look_at(np.array([1.8, 0.6, 1.6]), np.array([0.0, 0.0, 0.9]), up=(0.0, 0.0, 1.0))
    T_flange_part = make_pose(rotation((0.1, 0.3, 1.0), 0.5), [0.12, -0.08, 0.05])
    want = num_stations + num_heldout
    lo = np.maximum(np.asarray(model.lower), np.radians([-tilt_range_deg, -180.0]))
    hi = np.minimum(np.asarray(model.upper), np.radians([tilt_range_deg, 180.0]))
    q_all = rng.uniform(lo, hi, size=(want, 2))
    T_true = np.asarray(_fk(model, jnp.asarray(true_params), jnp.asarray(q_all)))
    if scatter:
        d = np.concatenate([np.radians(repeatability_deg) * rng.normal(size=(want, 3)),
                            repeatability_m * rng.normal(size=(want, 3))], axis=1)
        T_true = T_true @ _exp(d)
    T_nominal = np.asarray(_fk(model, model.nominal, jnp.asarray(q_all)))
    joints = np.asarray(kinematic_models.joints_to_controller(model, q_all))
    stations = []
    noise = _exp(np.concatenate([np.radians(sigma_deg) * rng.normal(size=(num_stations, 3)),
                                 sigma_m * rng.normal(size=(num_stations, 3))], axis=1))
    for i in range(num_stations):
        T = invert(T_base_tracker) @ T_true[i] @ T_flange_part @ noise[i]
        pose = ({"sensor": "tracker", "target": "part", "T_sensor_target": T.tolist()} if form == "sensor" else
                {"camera": "tracker", "target": "part", "T_cam_target": T.tolist()})
        stations.append({"id": f"s{i:03d}", "T_base_flange": T_nominal[i].tolist(), "joints_deg": joints[i].tolist(),
                         "poses": [pose]})
    cell = {
        "schema": "jcalib.cell/1",
        **({"sensors": {"tracker": {"kind": "pose", "mount": "base"}}} if form == "sensor" else
           {"cameras": {"tracker": {"model": "pinhole", "mount": "base"}}}),
        "targets": {"part": {"type": "points", "mount": "flange"}},
        "robot": {"kinematics": "positioner_2axis", "calibrate_kinematics": list(calibrate),
                  "pose_noise": {"translation_m": repeatability_m, "rotation_deg": repeatability_deg}},
    }
    obs = {"schema": "jcalib.observations/1", "targets": {"part": {"points": [[0.0, 0.0, 0.0]]}}, "stations": stations}
    if form != "sensor":
        obs["cameras"] = {"tracker": {"image_size": [640, 480]}}
    truth = {"params": true_params, "nominal": np.asarray(model.nominal, np.float64), "names": list(model.param_names),
             "T_base_tracker": T_base_tracker, "T_flange_part": T_flange_part,
             "fitted": {"q": q_all[:num_stations], "T_base_flange": T_true[:num_stations]},
             "heldout": {"q": q_all[num_stations:], "T_base_flange": T_true[num_stations:]}}
    return cell, obs, truth
