"""The cell spec's ``assumptions:`` block: stated inputs and their stated uncertainty (GUM Type B).

Keys name a cell entry and its quantity; values give the uncertainty::

    assumptions:
      board.square: {sigma_rel: 0.001}              # a target's printed scale (also <target>.scale)
      cam1.intrinsics: {covariance_from: old.json}   # a camera's held intrinsics (or sigma: {fx: 1.5, ...})
      T_base_cam1.pose: {sigma_deg: 0.05, sigma_m: 0.0005}   # a held transform (or covariance: [[6x6]],
                                                     # covariance_from: old.json); also <camera|target>.pose
      robot.kinematics: {sigma_m: 0.0005, sigma_deg: 0.02}   # a robot's nominal kinematic parameters
                                                     # that the calibration holds (robot name, or "robot")
      noise.corner: {sigma_rel: 0.3}                 # a stated noise level (corner, tip, axis, contact, ...)

Parsing checks the form and that the named entry exists; :mod:`jcalib.problems.budget` checks that
the quantity is held by the calibration (an estimated quantity has no Type B uncertainty) and adds the
visible defaults (:data:`DEFAULT_SCALE_SIGMA_REL`). Nothing here changes a calibration's estimate or its
sampling σ.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError

#: Relative σ of a target's printed scale when the cell states none (a professional target; office
#: printers scale by 0.1-0.5 %: state yours).
DEFAULT_SCALE_SIGMA_REL = 5e-4

QUANTITIES = ("square", "scale", "intrinsics", "pose", "kinematics")
NOISE_KINDS = ("corner", "corner_mean", "tip", "axis", "contact", "pose_rotation", "pose_translation")
_KEYS = {"square": {"sigma_rel"}, "scale": {"sigma_rel"}, "intrinsics": {"sigma", "covariance_from"},
         "pose": {"sigma_deg", "sigma_m", "covariance", "covariance_from"}, "kinematics": {"sigma_m", "sigma_deg"},
         "noise": {"sigma_rel"}}


@dataclass(frozen=True)
class Assumption:
    """One stated input and its stated uncertainty.

    Attributes:
        key: as written (``board.square``); thing: ``board``; quantity: ``square`` | ``scale`` |
            ``intrinsics`` | ``pose`` | ``kinematics`` | ``noise`` (thing: the residual kind).
        sigma_rel: relative σ (scale, noise).
        sigma: name -> σ (intrinsics: by intrinsic name, px or unitless).
        sigma_m, sigma_deg: σ per translation axis (m) / rotation axis (deg) of a pose, or per kinematic
            length / angle parameter.
        covariance: ``(p, p)`` covariance (a pose: 6x6, rx..tz, rad and m; intrinsics: over ``names``).
        names: the names ``covariance`` is over (intrinsics from a result: its ``param_names``).
        source: where the covariance came from (a result file), or ``"stated"`` / ``"default"``.
    """

    key: str
    thing: str
    quantity: str
    sigma_rel: float | None = None
    sigma: dict[str, float] = field(default_factory=dict)
    sigma_m: float | None = None
    sigma_deg: float | None = None
    covariance: np.ndarray | None = None
    names: tuple[str, ...] = ()
    source: str = "stated"
    spec: dict = field(default_factory=dict, compare=False)


def _positive(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
        raise BadInputError(f"{where}: got {value!r}, expected a finite number >= 0")
    return float(value)


def _covariance_from(path_text: Any, thing: str, quantity: str, base_dir: Path | None, where: str):
    from jcalib.io.result import load_result

    if not isinstance(path_text, str) or not path_text:
        raise BadInputError(f"{where}.covariance_from: got {path_text!r}, expected the path of a jcalib result file")
    path = Path(path_text)
    if not path.is_absolute() and base_dir is not None:
        path = base_dir / path
    if not path.is_file():
        raise BadInputError(f"{where}.covariance_from: '{path}' does not exist (expected a jcalib result file whose "
                            f"covariance of {thing} is the stated one)")
    result = load_result(path)
    if quantity == "intrinsics":
        cam = result.cameras.get(thing)
        if cam is None or cam.covariance is None:
            raise BadInputError(f"{where}.covariance_from: '{path}' has no covariance of camera '{thing}'; give "
                                "sigma: {fx: ..., cx: ...} instead")
        return np.asarray(cam.covariance, np.float64), tuple(cam.param_names), str(path)
    names = [thing] + [n for n in result.transforms if n.endswith(f"_{thing}")]
    for n in names:
        tr = result.transforms.get(n)
        if tr is not None and tr.covariance is not None:
            return np.asarray(tr.covariance, np.float64), ("rx", "ry", "rz", "tx", "ty", "tz"), str(path)
    raise BadInputError(f"{where}.covariance_from: '{path}' has no covariance of transform '{thing}'; give "
                        "sigma_deg and sigma_m instead")


def parse_assumptions(data: Any, entities: set[str], source: str, base_dir: Path | None = None) -> tuple:
    """The ``assumptions:`` mapping -> tuple of :class:`Assumption`.

    Args:
        data: the block (None: no assumptions).
        entities: names the cell defines (cameras, targets, tools, robots, transform names).
        source: the cell's file, for messages; base_dir: where ``covariance_from`` paths are relative to.
    Raises:
        BadInputError: naming the key and what is expected.
    """
    if data is None:
        return ()
    if not isinstance(data, dict):
        raise BadInputError(f"{source}: assumptions: expected a mapping like {{board.square: {{sigma_rel: 0.001}}}}, "
                            f"got {data!r}")
    out = []
    for key, value in data.items():
        where = f"{source}: assumptions.{key}"
        if not isinstance(key, str) or key.count(".") != 1:
            raise BadInputError(f"{where}: expected a key <entry>.<quantity> (e.g. board.square, cam1.intrinsics, "
                                "T_base_cam1.pose, robot.kinematics, noise.corner)")
        thing, quantity = key.split(".")
        if thing == "noise":
            thing, quantity = quantity, "noise"
            if thing not in NOISE_KINDS:
                raise BadInputError(f"{where}: unknown residual kind '{thing}'; expected one of {', '.join(NOISE_KINDS)}")
        elif quantity not in QUANTITIES:
            raise BadInputError(f"{where}: unknown quantity '{quantity}'; expected one of {', '.join(QUANTITIES)} "
                                "(or noise.<kind>)")
        elif thing not in entities:
            raise BadInputError(f"{where}: '{thing}' names nothing in the cell; expected one of "
                                f"{', '.join(sorted(entities))}")
        if not isinstance(value, dict) or not value:
            raise BadInputError(f"{where}: expected a mapping of its uncertainty, e.g. {{sigma_rel: 0.001}}, got {value!r}")
        unknown = sorted(set(value) - _KEYS[quantity])
        if unknown:
            raise BadInputError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(_KEYS[quantity])}")
        kw: dict[str, Any] = {}
        if "sigma_rel" in value:
            kw["sigma_rel"] = _positive(value["sigma_rel"], f"{where}.sigma_rel")
        for k in ("sigma_m", "sigma_deg"):
            if k in value:
                kw[k] = _positive(value[k], f"{where}.{k}")
        if "sigma" in value:
            sig = value["sigma"]
            if not isinstance(sig, dict) or not sig:
                raise BadInputError(f"{where}.sigma: expected intrinsic name -> σ (px for fx, fy, cx, cy), got {sig!r}")
            kw["sigma"] = {str(n): _positive(s, f"{where}.sigma.{n}") for n, s in sig.items()}
        if "covariance" in value:
            try:
                C = np.asarray(value["covariance"], np.float64)
            except (TypeError, ValueError):
                C = np.zeros(0)
            if C.shape != (6, 6) or not np.all(np.isfinite(C)) or np.min(np.linalg.eigvalsh(0.5 * (C + C.T))) < -1e-12 * max(1.0, np.abs(C).max()):
                raise BadInputError(f"{where}.covariance: expected a symmetric positive semi-definite 6x6 matrix "
                                    "(rx, ry, rz, tx, ty, tz; rad², m²)")
            kw["covariance"], kw["names"] = 0.5 * (C + C.T), ("rx", "ry", "rz", "tx", "ty", "tz")
        if "covariance_from" in value:
            C, names, src = _covariance_from(value["covariance_from"], thing, quantity, base_dir, where)
            kw.update(covariance=C, names=names, source=src)
        given = {"sigma_rel", "sigma", "sigma_m", "sigma_deg", "covariance", "covariance_from"} & set(value)
        if quantity == "pose" and {"sigma_m", "sigma_deg"} & given and {"covariance", "covariance_from"} & given:
            raise BadInputError(f"{where}: give sigma_deg / sigma_m or a covariance, not both")
        if quantity == "intrinsics" and len(given) > 1:
            raise BadInputError(f"{where}: give sigma or covariance_from, not both")
        out.append(Assumption(key, thing, quantity, spec=dict(value), **kw))
    return tuple(out)


def assumptions_to_dict(items: tuple) -> dict:
    """The block as written (for :func:`jcalib.io.cell.cell_to_dict`)."""
    return {a.key: dict(a.spec) for a in items}
