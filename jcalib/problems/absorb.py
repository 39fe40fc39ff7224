"""Nothing absorbs the robot's error silently: a camera's intrinsics from the joint solve against its board views alone.

In a robot cell a camera's intrinsics are determined by its board views *and* by the robot's poses: the
target's pose in every view runs through the reported flange pose. When the robot is not where it says,
the joint solve can bend the intrinsics (the principal point, the focal length) to absorb the robot's
error, and the only sign is a larger residual. Here each camera whose views run through a robot pose is
calibrated again from those views alone (the same camera model and fixed intrinsics, each view with its
own free target pose, no robot): an intrinsic that moved by more than :data:`ABSORB_SIGMA` standard
deviations of the board-only solve is named (with an exact robot the joint solve holds the same views and
more, so the difference's σ is below the board-only σ: the test is conservative) in a warning and in
``stats.robot_error_model.absorbed``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from jcalib.errors import JcalibError
from jcalib.io.cell import CellSpec
from jcalib.io.observations import Observations
from jcalib.problems.graph import FREE

__all__ = ["ABSORB_SIGMA", "absorbed_intrinsics"]

#: An intrinsic is named when it moved by more than this many σ of the board-only solve.
ABSORB_SIGMA = 3.0
#: Fewest views of a camera for the board-only solve.
MIN_VIEWS = 4
#: Names of the intrinsics by what they mean, for the message.
_GROUPS = (("principal point", ("cx", "cy")), ("focal length", ("fx", "fy")))


def _robot_targets(g, camera: str) -> set[str]:
    hc = g.holder(g.cell.cameras[camera])
    return {t for (c, t) in g.pairs if c == camera and hc != g.holder(g.cell.targets[t])
            and FREE not in (hc, g.holder(g.cell.targets[t]))}


def _board_only(cell: CellSpec, obs: Observations, camera: str, targets: set[str]):
    cam = replace(cell.cameras[camera], mount="free", pose=None, robot=None)
    tgts = {t: replace(cell.targets[t], mount="free", pose=None, robot=None) for t in sorted(targets)}
    alone = CellSpec(cameras={camera: cam}, targets=tgts, source=f"{cell.source} ({camera}'s board views alone)")
    stations = []
    for st in obs.stations:
        dets = tuple(d for d in st.detections if d.camera == camera and d.target in targets)
        if dets:
            stations.append(type(st)(id=st.id, detections=dets))
    return alone, Observations({camera: obs.cameras[camera]}, {t: obs.targets[t] for t in targets}, tuple(stations),
                               obs.source), len(stations)


def _message(camera: str, moved: dict[str, dict], model: str) -> str:
    parts, named = [], set()
    for label, names in _GROUPS:
        hit = [n for n in names if n in moved]
        if hit:
            px = float(np.sqrt(sum(moved[n]["moved"] ** 2 for n in hit)))
            parts.append(f"{label} moved {px:.3g} px")
            named.update(hit)
    rest = [n for n in moved if n not in named]
    if rest:
        parts.append(", ".join(f"{n} moved {moved[n]['moved']:.3g} ({moved[n]['moved'] / moved[n]['sigma']:.1f} σ)"
                               for n in rest))
    advice = ("consider kinematic calibration or the pose model" if model == "exact"
              else f"the {model} model did not take up all of the robot's error")
    return (f"{camera}: {'; '.join(parts)} from a solve of its board views alone (beyond {ABSORB_SIGMA:g} σ) to absorb "
            f"robot pose error: {advice}")


def absorbed_intrinsics(cal, obs: Observations, options, calibrate) -> list[str]:
    """Warnings for the cameras whose intrinsics absorbed robot error (module docstring); records the
    moved intrinsics in ``cal.robot_error_model["absorbed"]``. Runs with ``options.prediction`` (the
    accuracy-in-use checks) on robot cells only.

    Args:
        cal: the cell's :class:`~jcalib.problems.assemble.Calibration`; calibrate: ``(cell, obs, options)
            -> Calibration`` of a cell without robot.
    """
    g = cal.graph
    if not options.prediction or g is None or not g.has_robot or not cal.robot_error_model:
        return []
    chosen = cal.robot_error_model.get("chosen")
    model = chosen if isinstance(chosen, str) else "the chosen"
    warnings, absorbed = [], {}
    for camera, joint in cal.cameras.items():
        targets = _robot_targets(g, camera)
        cov_j = cal.intrinsics_covariance.get(camera)
        if not targets or cov_j is None:
            continue
        alone, alone_obs, views = _board_only(g.cell, g.obs, camera, targets)
        if views < MIN_VIEWS:
            continue
        try:
            ref = calibrate(alone, alone_obs, options.replace(prediction=False, pose_model=None, reference_camera=None))
        except JcalibError:
            continue
        cov_a = ref.intrinsics_covariance[camera]
        names = list(joint.param_names)
        diff = np.asarray(joint.params, np.float64) - np.asarray(ref.cameras[camera].params, np.float64)
        sigma = np.sqrt(np.maximum(np.diag(cov_a), 0.0))
        moved = {n: {"moved": float(d), "sigma": float(s)} for n, d, s in zip(names, diff, sigma)
                 if s > 0 and abs(d) > ABSORB_SIGMA * s}
        if moved:
            absorbed[camera] = moved
            warnings.append(_message(camera, moved, model))
    if absorbed:
        cal.robot_error_model["absorbed"] = absorbed
    return warnings
