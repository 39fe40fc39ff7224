"""The options of a calibration: one type for every cell, with what each option applies to.

Every cell takes the same :class:`CalibrationOptions`. An option that a cell has nothing to apply to
(``--pose-model`` without a robot, ``--method`` without a hand-eye pair) is refused by
:func:`check_applicable` with a message naming the option and why, never dropped silently.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from jcalib.errors import BadInputError
from jcalib.init.handeye import HAND_EYE_METHODS

LOSSES = ("none", "huber", "cauchy")
NOISES = ("a_posteriori", "stated")


@dataclass(frozen=True)
class CalibrationOptions:
    """Options of :func:`jcalib.calibrate` (every cell kind).

    Noise (σ of each residual kind; with ``noise="a_posteriori"`` each kind's σ is re-estimated from
    its own residuals by variance components and these only weigh the kinds against stated priors
    such as the robot's pose noise):

    Attributes:
        sigma_px: target-corner detection noise (pixels).
        tip_sigma_px: tool-tip detection noise (pixels).
        axis_sigma_px: noise of a point on an imaged tool axis, across the axis (pixels).
        contact_sigma_m: how well a tool tip sits in a touched point, per axis (m).
        pose_sigma_deg, pose_sigma_m: noise of a 6-DOF pose measurement, per rotation axis (degrees)
            and per translation axis (m); ``pose_sigma_m`` is also a point sensor's noise per axis (m).
        noise: ``"a_posteriori"`` (σ from the residuals, default) or ``"stated"`` (trust the σ above).
        loss: robust loss on corners, tool tips, axis points and contacts: ``"none"``, ``"huber"`` or
            ``"cauchy"``.
        loss_scale: the loss scale in units of σ.
        outlier_threshold: corners, tips and axis points beyond this many σ of their own kind (a robust
            scale of that kind's residuals with ``a_posteriori`` noise) are rejected and the problem
            re-solved (re-deciding every measurement each round); ``None`` keeps everything.
        reseed_views: re-start views of free targets whose residual is far above the rest from their
            other planar-PnP pose (a far view can start flipped and stay in that wrong minimum).
        pose_model: per-station robot pose corrections under the robot's ``pose_noise`` prior:
            ``None`` = as the cell says, ``False`` = poses exact, ``True`` = needs ``pose_noise``.
        method: closed-form hand-eye start (a key of :data:`jcalib.init.handeye.HAND_EYE_METHODS`).
        max_iterations: Levenberg–Marquardt iterations per solve.
        reference_camera: the camera whose frame is the rig frame of a cell without robots.
        fix_unobservable: when every hand-eye rotation is about one axis, hold the hand-eye translation
            along it at ``unobservable_prior_m`` ± ``unobservable_prior_sigma_m`` instead of failing.
        prediction: a robot cell's held-out prediction error (``stats.prediction``,
            :mod:`jcalib.problems.prediction`): every station's corners predicted from its robot pose by the
            cell calibrated without it (warm re-solves; off saves their time).
    """

    sigma_px: float = 0.25
    tip_sigma_px: float = 0.25
    axis_sigma_px: float = 0.5
    contact_sigma_m: float = 5e-5
    pose_sigma_deg: float = 0.1
    pose_sigma_m: float = 1e-3
    noise: str = "a_posteriori"
    loss: str = "none"
    loss_scale: float = 3.0
    outlier_threshold: float | None = 5.0
    reseed_views: bool = True
    pose_model: bool | None = None
    method: str = "park_martin"
    max_iterations: int = 100
    reference_camera: str | None = None
    fix_unobservable: bool = False
    unobservable_prior_m: float = 0.0
    unobservable_prior_sigma_m: float = 1e-6
    prediction: bool = True

    def __post_init__(self):
        for name in ("sigma_px", "tip_sigma_px", "axis_sigma_px", "contact_sigma_m", "pose_sigma_deg",
                     "pose_sigma_m", "loss_scale", "unobservable_prior_sigma_m"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0 or value == float("inf"):
                raise BadInputError(f"{name}: got {value!r}, expected a positive finite number")
        if self.noise not in NOISES:
            raise BadInputError(f"noise: got {self.noise!r}, expected one of {', '.join(NOISES)}")
        if self.loss not in LOSSES:
            raise BadInputError(f"loss: got {self.loss!r}, expected one of {', '.join(LOSSES)}")
        if self.outlier_threshold is not None and not self.outlier_threshold > 0:
            raise BadInputError(f"outlier_threshold: got {self.outlier_threshold!r}, expected a positive number of σ "
                                "or None")
        if self.pose_model not in (None, True, False):
            raise BadInputError(f"pose_model: got {self.pose_model!r}, expected None, True or False")
        if self.method not in HAND_EYE_METHODS:
            raise BadInputError(f"method: got {self.method!r}, expected one of {', '.join(sorted(HAND_EYE_METHODS))}")
        if isinstance(self.max_iterations, bool) or not isinstance(self.max_iterations, int) or self.max_iterations < 1:
            raise BadInputError(f"max_iterations: got {self.max_iterations!r}, expected a positive integer")
        if not isinstance(self.prediction, bool):
            raise BadInputError(f"prediction: got {self.prediction!r}, expected true or false")
        if not abs(self.unobservable_prior_m) < float("inf"):
            raise BadInputError(f"unobservable_prior_m: got {self.unobservable_prior_m!r}, expected a finite value (m)")

    def replace(self, **changes) -> CalibrationOptions:
        """A copy with ``changes`` (validated)."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise BadInputError(f"options: unknown name(s) {unknown}; known: {', '.join(sorted(known))}")
        return CalibrationOptions(**{**{f.name: getattr(self, f.name) for f in fields(self)}, **changes})


def _hand_eye_pair(g) -> bool:
    """A camera and a target that a robot moves relative to each other (neither free)."""
    return any(g.holder(g.cell.cameras[c]) != g.holder(g.cell.targets[t])
               and "~free" not in (g.holder(g.cell.cameras[c]), g.holder(g.cell.targets[t]))
               for (c, t) in list(g.pairs) + list(g.poses))


_HAND_EYE = "a camera and a target that a robot moves relative to each other (a hand-eye pair)"

#: Option name -> (what in the cell it needs, a predicate on the problem graph). Options not listed
#: apply to every cell (noise, max_iterations).
APPLIES = {
    "sigma_px": ("target corners in the observations", lambda g: bool(g.pairs)),
    "tip_sigma_px": ("tool-tip detections", lambda g: bool(g.tips)),
    "axis_sigma_px": ("tool-axis points on tool-tip detections", lambda g: any(len(a) for t in g.tips.values()
                                                                              for a in t.axis)),
    "contact_sigma_m": ("tool contacts with cell points", lambda g: bool(g.contacts)),
    "pose_sigma_deg": ("6-DOF pose measurements", lambda g: bool(g.poses)),
    "pose_sigma_m": ("6-DOF pose or 3-D point measurements", lambda g: bool(g.poses) or bool(g.positions)),
    "reseed_views": ("free-moving targets (mount: free)", lambda g: bool(g.free_things())),
    "pose_model": ("a robot with pose_noise in the cell spec", lambda g: any(g.has_noise(r) for r in g.used_robots)),
    "method": (_HAND_EYE, _hand_eye_pair),
    "reference_camera": ("cells without robots (camera rigs)", lambda g: not g.has_robot),
    "prediction": ("a robot (the prediction is from its recorded poses)", lambda g: g.has_robot),
    "fix_unobservable": (_HAND_EYE, _hand_eye_pair),
    "unobservable_prior_m": (_HAND_EYE, _hand_eye_pair),
    "unobservable_prior_sigma_m": (_HAND_EYE, _hand_eye_pair),
    "loss": ("target corners, tool tips, axis points or contacts (pose measurements take no robust loss)",
             lambda g: bool(g.pairs or g.tips or g.contacts)),
    "loss_scale": ("target corners, tool tips, axis points or contacts (pose measurements take no robust loss)",
                   lambda g: bool(g.pairs or g.tips or g.contacts)),
    "outlier_threshold": ("target corners, tool tips or axis points (contacts and pose measurements are never "
                          "rejected)", lambda g: bool(g.pairs or g.tips)),
}

#: Option name -> (the option it acts through, that option's default): refused while that one is off.
NEEDS = {
    "loss_scale": ("loss", "none"),
    "unobservable_prior_m": ("fix_unobservable", False),
    "unobservable_prior_sigma_m": ("fix_unobservable", False),
}


def check_applicable(options: CalibrationOptions, graph, given: set[str]) -> None:
    """Refuse every option in ``given`` (set explicitly by the user) that the cell cannot use.

    Raises:
        BadInputError: naming the option and what the cell lacks for it.
    """
    for name in sorted(given):
        if name in NEEDS and getattr(options, NEEDS[name][0]) == NEEDS[name][1]:
            other = NEEDS[name][0].replace("_", "-")
            raise BadInputError(f"option --{name.replace('_', '-')} has no effect without --{other} (it scales or "
                                f"sets what --{other} does); give --{other} too, or drop it")
        if name in APPLIES:
            need, ok = APPLIES[name]
            if not ok(graph):
                raise BadInputError(
                    f"option --{name.replace('_', '-')} has no effect here: it applies to {need}, and this cell has "
                    "none; drop it (or fix the cell spec / observations if you expected one)")
    if options.pose_model is True and not any(graph.has_noise(r) for r in graph.used_robots):
        where = "robots.<name>.pose_noise" if graph.multi else "robot.pose_noise"
        raise BadInputError(f"options.pose_model: got True, but {graph.cell.source} has no {where}; state the "
                            "robot's pose accuracy (translation_m, rotation_deg) in the cell")
