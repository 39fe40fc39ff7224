"""Export calibrated UR kinematics as Universal Robots' delta DH (``jcalib export --format ur-calibration``).

The text has the form of a UR controller's ``calibration.conf`` (:mod:`jcalib.io.ur_calibration`): a ``[mounting]``
section with ``delta_theta``, ``delta_a``, ``delta_d``, ``delta_alpha`` (rad, m), the calibrated standard DH table
minus the nominal table of the robot's UR type (UR's published values: the ``ur5e`` preset), so that nominal +
delta is jcalib's calibrated arm. ``jcalib`` reads it back as a robot's nominal kinematics
(``kinematics: {preset: ur5e, ur_calibration: FILE}``), and it compares directly with the controller's own file.

It is what jcalib calibrated, written in UR's form, not a controller file: it carries no checksums or
``calibration_status``, and a UR arm's calibration is applied only by UR's own procedure.

Refused, with the reason: a result without calibrated kinematics, a model that is not six revolute joints in the
dh convention with UR's joint directions, one whose base or flange frame was calibrated away from the DH frames
(UR's file has no terms for them: calibrate ``joint_offsets``, ``link_lengths``, ``twists``), or one that is no
UR type jcalib knows.
"""

from __future__ import annotations

import math

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry import kinematic_models as km
from jcalib.geometry.robots import UR5E_DH
from jcalib.io.export._common import checked_export, comment_text, provenance_lines
from jcalib.io.export.kinematics import calibrated_model, pick_robot
from jcalib.io.result import ResultFile
from jcalib.io.ur_calibration import ur_calibration_text

__all__ = ["UR_TYPES", "ur_calibration_export"]

#: UR types by preset: their nominal DH tables (``a``, ``d``, ``alpha``; ``theta`` nominal 0).
UR_TYPES = {"ur5e": UR5E_DH}
#: How far a calibrated table may be from its type's for the type to be recognised (m, rad). Joints 2 to 4's ``d``
#: are not compared: nearly parallel axes let them move by metres in a valid calibration.
_TYPE_TOL_M, _TYPE_TOL_RAD = 0.02, 0.05
_FRAME_TOL = 1e-9


def _ur_type(theta_d_a_alpha: np.ndarray, robot: str) -> str:
    for name, nominal in UR_TYPES.items():
        a, d, alpha = (np.asarray(nominal[k]) for k in ("a", "d", "alpha"))
        da = np.abs(theta_d_a_alpha[:, 2] - a).max()
        dd = np.abs(theta_d_a_alpha[[0, 4, 5], 1] - d[[0, 4, 5]]).max()
        dalpha = np.abs(theta_d_a_alpha[:, 3] - alpha).max()
        if da < _TYPE_TOL_M and dd < _TYPE_TOL_M and dalpha < _TYPE_TOL_RAD:
            return name
    raise BadInputError(f"format 'ur-calibration': the calibrated kinematics of robot {robot!r} is not the DH table of a "
                        f"UR type jcalib knows ({', '.join(UR_TYPES)}): a = {np.round(theta_d_a_alpha[:, 2], 4).tolist()} m")


def ur_calibration_export(result: ResultFile, robot: str | None = None) -> str:
    """The ``calibration.conf``-form text of one robot's calibrated kinematics (module docstring).

    Args:
        result: the calibration result.
        robot: the robot; None = the result's only robot with calibrated kinematics.

    Raises:
        BadInputError: as the module docstring says.
    """
    robot = pick_robot(result, robot, "ur-calibration")
    k = result.kinematics[robot]
    model = calibrated_model(k, robot)
    where = f"format 'ur-calibration': robot {robot!r}"
    if model.convention != "dh" or model.num_joints != 6 or any(t != "revolute" for t in model.joint_types):
        raise BadInputError(f"{where}: UR's calibration is a standard DH table of six revolute joints; this result's "
                            f"kinematics is {model.convention} with {model.num_joints} joints. Calibrate with the dh "
                            "convention (kinematics: ur5e)")
    if np.any(np.asarray(model.joint_sign) != 1.0):
        raise BadInputError(f"{where}: a joint turns the other way than UR's (sign -1): not a UR arm's table")
    base, flange = km.effective_base_flange(model, model.nominal)
    for name, T in (("base", base), ("flange", flange)):
        off_m = float(np.linalg.norm(T[:3, 3]))
        off_rad = float(np.arccos(np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
        if off_m > _FRAME_TOL or off_rad > _FRAME_TOL:
            raise BadInputError(
                f"{where}: the calibrated {name} frame is {off_m * 1e3:.4f} mm, {math.degrees(off_rad):.5f} deg from the "
                f"DH {name} frame, and UR's calibration has no {name} terms: calibrate joint_offsets, link_lengths and "
                f"twists only (not {name}) to export it in UR's form")
    table = np.asarray(model.nominal[:24], dtype=np.float64).reshape(6, 4)  # theta, d, a, alpha per joint
    ur_type = _ur_type(table, robot)
    nominal = UR_TYPES[ur_type]
    delta = {"theta": table[:, 0].tolist(), "a": (table[:, 2] - np.asarray(nominal["a"])).tolist(),
             "d": (table[:, 1] - np.asarray(nominal["d"])).tolist(),
             "alpha": (table[:, 3] - np.asarray(nominal["alpha"])).tolist()}  # fmt: skip
    comments = [
        f"jcalib calibrated kinematics of robot {comment_text(robot, True)!s} as Universal Robots delta DH "
        f"({ur_type} nominal + these deltas)",
        *provenance_lines(result, ascii_only=True),
        f"{len(k.calibrated)} parameters calibrated: {comment_text(', '.join(k.calibrated), True)}"[:400],
        "units: theta and alpha in rad, a and d in m (standard DH, theta_i = q_i + delta_theta_i)",
        "This is what jcalib calibrated, in the form of a UR controller's calibration.conf, for comparison and records.",
        "It is not a controller file (no checksums, no calibration_status): a UR arm's calibration is applied only",
        "by UR's own procedure.",
    ]
    return checked_export(ur_calibration_text(delta, comments), "ur-calibration", ascii_only=True)
