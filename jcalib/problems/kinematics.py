"""Which kinematic parameters of a robot the builder estimates: a minimal identifiable set.

A robot's kinematic parameters (:mod:`jcalib.geometry.kinematic_models`) are never all separable from
what else the cell estimates. Whatever sits on the robot's base side (a fixed camera, a fixed board, a
pose sensor: an unknown pose in the base frame) absorbs any change of the base transform, whatever
sits on the flange (a hand-eye camera, a tool, a board on a positioner) absorbs any change of the
flange transform, and within the chain some parameters trade off exactly (the first joint's offset
against the base yaw, consecutive parallel axes' link offsets). Kinematic calibration therefore keeps a
*minimal identifiable set*:

1. **Structure.** At generic joint values (seeded random configurations within the joint limits) the
   Jacobian of the flange pose with respect to the parameters, together with the 12 columns of an
   unknown pose on either side of the robot, is scanned column by column in the parameter order; a
   parameter whose column lies in the span of the columns already kept is held at its nominal value
   and the result says with what it cannot be separated. Parameters requested by name (not by group)
   that are held this way are an error (exit 3): the user asked for something no data can give.
2. **Data.** At the stations' joint values, the kept set must still be determined: a joint that never
   moved, or two parameters that always moved together, leave a null direction. Those parameters are
   named (exit 3) with the joint motions to add.

Both scans whiten the rows by the robot's repeatability (so radians and metres weigh as the factor
weighs them) and normalise the columns (so parameter units do not matter). The structural scan is
:mod:`jcalib.geometry.kinematic_identifiability`, shared with the station planner.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import equinox as eqx
import jax
import numpy as np

from jcalib.errors import NotObservableError
from jcalib.geometry import kinematic_models
from jcalib.geometry.kinematic_identifiability import (GAUGE_COLUMNS, INDEPENDENCE_TOLERANCE, generic_joints,
                                                       repeatability_sqrt_info, structural_scan, unit_columns,
                                                       whitened)

__all__ = ["Selection", "forward_batch", "generic_joints", "repeatability_sqrt_info", "select_parameters"]


@dataclass
class Selection:
    """The kinematic parameters of one robot the builder estimates.

    Attributes:
        free: ``(P,)`` bool, estimated; ``requested``: ``(P,)`` bool, asked for by the cell.
        held: parameter name -> why it is held at its nominal value (requested but not separable).
    """

    free: np.ndarray
    requested: np.ndarray
    held: dict[str, str] = field(default_factory=dict)


#: The flange pose at each joint vector, compiled once per model structure and count.
forward_batch = eqx.filter_jit(jax.vmap(kinematic_models.forward, in_axes=(None, None, 0)))


def select_parameters(model, requested: tuple[str, ...], q: np.ndarray, S: np.ndarray, robot: str) -> Selection:
    """The minimal identifiable subset of the requested parameters (see the module docstring).

    Args:
        model: the robot's :class:`~jcalib.geometry.kinematic_models.Kinematics`; requested: the cell's
            ``calibrate_kinematics`` (names and groups); q: ``(N, n)`` the stations' joint values (rad, m);
            S: ``(6, 6)`` square-root information of one flange pose (rad, m); robot: its label in messages.

    Raises:
        NotObservableError: a parameter requested by name is not separable in any motion, or the
            stations' motion leaves kept parameters undetermined (named, with the joints to move).
    """
    want = np.asarray(kinematic_models.select(model, list(requested)), bool)
    groups = set(kinematic_models.parameter_groups(model))
    explicit = {n for n in requested if n not in groups}
    generic = generic_joints(model)
    gauge_all, cols_all = whitened(model, np.concatenate([generic, q]), S)  # one compiled call for both scans
    rows = 6 * generic.shape[0]
    free, held = structural_scan(model, want, S, gauge_all[:rows], cols_all[:rows])
    bad = [n for n in held if n in explicit]
    if bad:
        raise NotObservableError(
            f"{robot}: the kinematic parameter(s) {', '.join(bad)} cannot be determined by any motion: "
            + "; ".join(f"{n} is {held[n]}" for n in bad)
            + ". Remove them from calibrate_kinematics (name groups such as joint_offsets to let jcalib keep an "
              "identifiable subset)", [f"{robot} kinematics {n}" for n in bad])
    _check_motion(model, q, gauge_all[rows:], cols_all[rows:], free, robot)
    return Selection(free=free, requested=want, held=held)


def _check_motion(model, q: np.ndarray, gauge: np.ndarray, cols: np.ndarray, free: np.ndarray, robot: str) -> None:
    """Raise when the stations' joint values (``q``; whitened columns ``gauge``, ``cols`` at them) leave
    free parameters undetermined."""
    if not free.any():
        return
    A = unit_columns(np.concatenate([gauge, cols[:, free]], axis=1))
    _, sv, Vt = np.linalg.svd(A, full_matrices=False)
    small = sv < INDEPENDENCE_TOLERANCE * max(sv[0], 1e-300) * np.sqrt(A.shape[1])
    if not small.any():
        return
    names = [n for n, f in zip(model.param_names, free) if f]
    involved: list[str] = []
    for v in Vt[small]:
        w = np.abs(v[GAUGE_COLUMNS:])
        for j in np.flatnonzero(w > 0.2 * max(w.max(), 1e-300)):
            if names[j] not in involved:
                involved.append(names[j])
    still = [model.joint_names[j] for j in range(q.shape[1]) if np.ptp(q[:, j]) < 1e-9]
    hint = (f"joint(s) {', '.join(still)} never moved; " if still else "") + \
        "move every joint through a good part of its range, in varied combinations (jcalib plan --kind kinematics)"
    raise NotObservableError(
        f"{robot}: the stations' motion cannot determine the kinematic parameter(s) "
        f"{', '.join(involved) or ', '.join(names)} (they move together or not at all in these {q.shape[0]} "
        f"stations): {hint}, or remove them from calibrate_kinematics", [f"{robot} kinematics {n}" for n in involved])
