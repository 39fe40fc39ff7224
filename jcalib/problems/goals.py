"""Accuracy goals against a result: the σ each goal's quantity achieved, and each goal's row (achieved,
predicted, met) for the goals tables of the CLI and the report.

A goal (:mod:`jcalib.io.goals`, ``NAME:QUANTITY<=VALUE``) is checked against the covariances the solve
wrote into the result file, with the same worst-direction σ the planner predicts:

- a transform (``T_flange_cam0``): the rotation (rx, ry, rz) or translation (tx, ty, tz) 3 x 3 block of
  its 6 x 6 tangent covariance;
- a cell point: its 3 x 3 covariance;
- a camera's ``projection_px``: the intrinsics covariance propagated to the projection of fixed rays
  through the :func:`jcalib.io.goals.projection_grid` pixels (unprojected by the estimated model), the
  largest over the grid (:func:`jcalib.problems.taskspace.projection_jacobian`).

Includes the sampling noise of the observations as the solve reported it (a-posteriori or stated),
not model error. The predicted σ (a ``jcalib plan --kind optimal`` plan's ``planner.predicted``,
:func:`jcalib.io.plan.plan_goals`) assumed the stated noise and the nominal geometry.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.goals import Goal, parse_goals, projection_grid, sigma_from_covariance
from jcalib.io.result import ResultFile, load_result
from jcalib.problems.taskspace import camera_model, projection_jacobian, unproject

__all__ = ["GoalRow", "achieved_sigmas", "goal_rows"]

_ROTATION = ("rx", "ry", "rz")
_TRANSLATION = ("tx", "ty", "tz")


@dataclass(frozen=True)
class GoalRow:
    """One row of the goals table.

    Attributes:
        goal: the goal.  achieved: σ from the result (the goal's unit).
        predicted: σ the plan predicted (None without a plan or when it did not predict this goal).
        met: ``achieved <= goal.limit``.
    """

    goal: Goal
    achieved: float
    predicted: float | None
    met: bool


def _goals(goals: Iterable[Goal | str]) -> tuple[Goal, ...]:
    goals = list(goals)
    if all(isinstance(g, Goal) for g in goals):
        return tuple(goals)
    return parse_goals([g.text if isinstance(g, Goal) else g for g in goals])


def _result(result: Any) -> ResultFile:
    if isinstance(result, ResultFile):
        return result
    if hasattr(result, "file") and isinstance(result.file, ResultFile):  # a jcalib.Result
        return result.file
    return load_result(result)


def _transform_sigma(goal: Goal, file: ResultFile) -> float:
    if goal.name not in file.transforms:
        raise BadInputError(f"goal {goal.text!r}: the result has no transform {goal.name!r} (it has "
                            f"{', '.join(file.transforms) or 'none'}); name one of them")
    tr = file.transforms[goal.name]
    if tr.covariance is None:
        raise BadInputError(f"goal {goal.text!r}: the result's {goal.name} has no covariance (given or held "
                            "fixed, or written without one); its σ cannot be checked")
    calibrated = tr.extra.get("calibrated")
    part = _ROTATION if goal.measures == "rotation" else _TRANSLATION
    if isinstance(calibrated, list) and not set(part) & set(calibrated):
        raise BadInputError(f"goal {goal.text!r}: the {goal.measures} of {goal.name} was not calibrated (the result "
                            f"estimates only {', '.join(calibrated) or 'nothing'} of it); drop the goal")
    return float(sigma_from_covariance(goal, np.asarray(tr.covariance, np.float64)))


def _point_sigma(goal: Goal, file: ResultFile) -> float:
    if goal.name not in file.points:
        things = list(file.points) + list(file.transforms)
        raise BadInputError(f"goal {goal.text!r}: the result has no point {goal.name!r} (points and transforms: "
                            f"{', '.join(things) or 'none'})")
    pt = file.points[goal.name]
    if pt.covariance is None:
        raise BadInputError(f"goal {goal.text!r}: the result's point {goal.name} has no covariance; its σ cannot "
                            "be checked")
    return float(sigma_from_covariance(goal, np.asarray(pt.covariance, np.float64)))


def _projection_sigma(goal: Goal, file: ResultFile) -> float:
    if goal.name not in file.cameras:
        raise BadInputError(f"goal {goal.text!r}: the result has no camera {goal.name!r} (it has "
                            f"{', '.join(file.cameras) or 'none'})")
    cam = file.cameras[goal.name]
    if cam.covariance is None:
        raise BadInputError(f"goal {goal.text!r}: camera {goal.name} has no intrinsics covariance in the result "
                            "(intrinsics given, or written without one); its projection σ cannot be checked")
    model = camera_model(cam)
    rays, ok = unproject(model, projection_grid(cam.image_size))
    ok = ok & (rays[:, 2] > 1e-6)
    if not ok.any():
        raise BadInputError(f"goal {goal.text!r}: no pixel of camera {goal.name}'s image has a valid ray")
    J = projection_jacobian(model, rays[ok])
    return float(sigma_from_covariance(goal, np.asarray(cam.covariance, np.float64), J))


def achieved_sigmas(goals: Iterable[Goal | str], result: Any) -> dict[str, float]:
    """Each goal's σ (its unit: mm, deg, px) from a result's covariances.

    Args:
        goals: :class:`~jcalib.io.goals.Goal` s or their texts.
        result: a :class:`~jcalib.io.result.ResultFile`, a :class:`jcalib.Result` or a ``result.json`` path.

    Returns:
        goal text -> σ (worst direction; module docstring).

    Raises:
        BadInputError: a goal naming a transform, point or camera the result does not have, or one
            without a covariance (or whose quantity was not calibrated).
    """
    file = _result(result)
    out: dict[str, float] = {}
    for g in _goals(goals):
        if g.measures == "projection":
            out[g.text] = _projection_sigma(g, file)
        elif g.is_transform:
            out[g.text] = _transform_sigma(g, file)
        else:
            out[g.text] = _point_sigma(g, file)
    return out


def goal_rows(goals: Iterable[Goal | str], result: Any, predicted: Mapping[str, float] | None = None
              ) -> list[GoalRow]:
    """One :class:`GoalRow` per goal: achieved σ (:func:`achieved_sigmas`), predicted σ, met."""
    goals = _goals(goals)
    achieved = achieved_sigmas(goals, result)
    predicted = predicted or {}
    return [GoalRow(g, achieved[g.text], predicted.get(g.text), achieved[g.text] <= g.limit) for g in goals]
