"""Parameterised robot kinematics for kinematic calibration: standard DH, modified DH, local POE.

A :class:`Kinematics` model maps a parameter vector ``params (P,)`` (m, rad) and joint values
``q (..., n)`` (rad for revolute, m for prismatic joints) to flange poses ``T_base_flange (..., 4, 4)``
(:func:`forward`). The calibration problem holds ``params`` as one Euclidean variable; ``nominal`` is
the catalogue value and :func:`select` says which entries are unknown. Arms and external axes
(positioners, tracks, turntables) are the same thing here: a serial chain of revolute and prismatic
joints.

Every convention is evaluated as one chain (``s_i`` = ``joint_sign``, ``J_i`` the joint motion: ``Rz``
for a revolute, ``Tz`` for a prismatic joint, about/along the local z axis)::

    T_base_flange(q) = B . L_1(q_1) ... L_n(q_n) . F,      L_i(q_i) = P_i . J_i(s_i q_i) . S_i
    B = T_base_link0 . Exp(base),                         F = T_link_flange . Exp(flange)

``Exp`` is the SE(3) exponential of jcalib's right tangent ``(rx, ry, rz, tx, ty, tz)`` (rad, m), see
:mod:`jcalib.geometry.lie`; ``base.*`` and ``flange.*`` (nominal 0) are right perturbations of the
fixed ``T_base_link0`` (first link frame in the robot base frame) and ``T_link_flange`` (flange in the
last link frame), in every convention. Per-joint parameters, in this order in ``params``:

- ``dh`` (standard/distal DH, as :mod:`jcalib.geometry.kinematics`): ``theta, d, a, alpha``;
  ``L = Rz(theta) Tz(d) Tx(a) Rx(alpha)`` with ``theta = s q + theta`` (revolute) or
  ``d = s q + d`` (prismatic).
- ``mdh`` (Craig's modified/proximal DH with Hayati's ``beta``): ``alpha, a, theta, d, beta``;
  ``L = Rx(alpha) Tx(a) Ry(beta) Rz(theta) Tz(d)``, same joint rule. ``alpha, a, beta`` place the
  axis of joint i relative to frame i-1. This is Hayati's ``Rz(theta) Tx(a) Rx(alpha) Ry(beta)``
  regrouped in Craig's order (``Tx`` and ``Rx`` commute): ``beta`` (nominal 0) tilts the axis about
  the y axis at the foot of the common normal, so two nominally parallel axes that are slightly
  tilted towards each other get a small ``beta`` instead of the DH singularity (a common normal that
  jumps far along the axis, i.e. a huge ``d``). Leave ``beta`` fixed where consecutive axes are not
  (near-)parallel: there it duplicates ``theta``/``d`` of the neighbours.
- ``poe`` (local product of exponentials): ``rx, ry, rz, tx, ty, tz`` (nominal 0):
  ``L = M_i . Exp(delta_i) . J_i(s q)`` with ``M_i`` (field ``links``) the nominal fixed transform
  from the previous joint frame to joint i's frame (its z axis is the joint axis). Perturbing
  ``rz`` (revolute) or ``tz`` (prismatic) by e is exactly a joint offset of ``s e``.

Parameter names are ``<joint>.<suffix>`` then ``base.rx .. base.tz`` and ``flange.rx .. flange.tz``
(``P = n k + 12``, ``k`` = 4, 5, 6). Joint names are sanitised to identifiers: white space removed,
other non-word characters replaced by ``_``, a leading digit prefixed with ``J`` (ABB ``"axis 1"`` ->
``"axis1"``; KUKA ``"A1"`` stays); they must be unique and not ``base``/``flange``.

Groups (:func:`parameter_groups`): ``joint_offsets`` (revolute ``theta`` / prismatic ``d``; poe
``rz`` / ``tz``), ``link_lengths`` (``a``, ``d`` of revolute joints; poe ``tx, ty`` and ``tz`` of
revolute joints), ``twists`` (the remaining constant angles: ``alpha``, ``beta``, ``theta`` of
prismatic joints; poe ``rx, ry`` and ``rz`` of prismatic joints), ``base``, ``flange``, ``all``.
The layout is over-complete on purpose (e.g. ``base.*`` and the first joint's parameters move the
same chain): calibrate a subset; the solver names what the data cannot determine.

Controller units: joints are reported in degrees (revolute) and mm (prismatic);
:func:`joints_from_controller` / :func:`joints_to_controller` convert.
"""

from __future__ import annotations

import difflib
import functools
import math
import re
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry import robots
from jcalib.geometry.kinematics import DHRobot, dh_transform
from jcalib.geometry.lie import se3_exp, se3_to_matrix

__all__ = [
    "CONVENTIONS", "JOINT_TYPES", "PRESETS", "SUFFIXES", "Kinematics", "check_params", "controller_offsets",
    "convert", "effective_base_flange", "forward", "from_dh_robot", "joint_frames", "joints_from_controller",
    "joints_to_controller", "linear_track", "make_model", "parameter_groups", "poe_from_frames",
    "positioner_2axis", "rotary_table", "select", "suggest",
]

CONVENTIONS = ("dh", "mdh", "poe")
SUFFIXES = {
    "dh": ("theta", "d", "a", "alpha"),
    "mdh": ("alpha", "a", "theta", "d", "beta"),
    "poe": ("rx", "ry", "rz", "tx", "ty", "tz"),
}
_TANGENT = ("rx", "ry", "rz", "tx", "ty", "tz")
_OFFSET = {"revolute": {"dh": "theta", "mdh": "theta", "poe": "rz"},
           "prismatic": {"dh": "d", "mdh": "d", "poe": "tz"}}
_LENGTHS = ("a", "d", "tx", "ty", "tz")
_GROUPS = ("joint_offsets", "link_lengths", "twists", "base", "flange", "all")
JOINT_TYPES = ("revolute", "prismatic")


class Kinematics(eqx.Module):
    """A serial chain of revolute/prismatic joints with a calibratable parameter vector.

    Attributes:
        nominal: ``(P,)`` nominal parameters (m, rad), layout in the module docstring.
        joint_sign: ``(n,)`` +1 or -1: the joint moves by ``sign * q`` about/along its z axis.
        lower, upper: ``(n,)`` joint limits on ``q`` (rad revolute, m prismatic).
        T_base_link0: ``(4, 4)`` nominal first link frame in the robot base frame (m).
        T_link_flange: ``(4, 4)`` nominal flange frame in the last link frame (m).
        links: ``(n, 4, 4)`` poe: nominal transform ``M_i`` from joint frame i-1 (``T_base_link0``
            for i = 1) to joint frame i (m); identity (unused) for dh and mdh.
        name: the robot, for messages (static).
        convention: ``"dh"``, ``"mdh"`` or ``"poe"`` (static).
        joint_types: ``"revolute"`` / ``"prismatic"`` per joint (static).
        joint_names: sanitised joint identifiers (static).
        param_names: ``P`` unique parameter names (static).
    """

    nominal: jax.Array
    joint_sign: jax.Array
    lower: jax.Array
    upper: jax.Array
    T_base_link0: jax.Array
    T_link_flange: jax.Array
    links: jax.Array
    name: str = eqx.field(static=True)
    convention: str = eqx.field(static=True)
    joint_types: tuple[str, ...] = eqx.field(static=True)
    joint_names: tuple[str, ...] = eqx.field(static=True)
    param_names: tuple[str, ...] = eqx.field(static=True)

    @property
    def num_joints(self) -> int:
        return len(self.joint_types)

    @property
    def num_params(self) -> int:
        return len(self.param_names)


# ----------------------------------------------------------------------------------------------
# Forward kinematics (pure jnp)
# ----------------------------------------------------------------------------------------------


def _matrices(entries, shape) -> jax.Array:
    """Stack 16 row-major entries of shape ``shape`` into matrices ``(*shape, 4, 4)``."""
    return jnp.stack(entries, axis=-1).reshape(tuple(shape) + (4, 4))


def _rot(axis: int, angle) -> jax.Array:
    """Rotations ``(..., 4, 4)`` about x (0), y (1) or z (2) by ``angle (...)`` (rad)."""
    angle = jnp.asarray(angle, dtype=jnp.float64)
    c, s = jnp.cos(angle), jnp.sin(angle)
    o, z = jnp.ones_like(c), jnp.zeros_like(c)
    rows = (
        [o, z, z, z, z, c, -s, z, z, s, c, z],
        [c, z, s, z, z, o, z, z, -s, z, c, z],
        [c, -s, z, z, s, c, z, z, z, z, o, z],
    )[axis]
    return _matrices(rows + [z, z, z, o], angle.shape)


def _trans(axis: int, dist) -> jax.Array:
    """Translations ``(..., 4, 4)`` along x (0), y (1) or z (2) by ``dist (...)`` (m)."""
    dist = jnp.asarray(dist, dtype=jnp.float64)
    o, z = jnp.ones_like(dist), jnp.zeros_like(dist)
    t = [dist if i == axis else z for i in range(3)]
    return _matrices([o, z, z, t[0], z, o, z, t[1], z, z, o, t[2], z, z, z, o], dist.shape)


def _screw_z(angle, dist) -> jax.Array:
    """``Rz(angle) Tz(dist)`` ``(..., 4, 4)``: the joint motions, ``angle``/``dist (...)`` (rad, m)."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    o, z = jnp.ones_like(c), jnp.zeros_like(c)
    return _matrices([c, -s, z, z, s, c, z, z, z, z, o, dist, z, z, z, o], angle.shape)


@jax.jit  # one kernel per shape, so that evaluating models eagerly stays fast; inlined under jit
def _exp(delta) -> jax.Array:
    """``Exp(delta)`` ``(..., 4, 4)`` for right tangents ``delta (..., 6)`` (rad, m)."""
    return se3_to_matrix(se3_exp(delta))


def _fixed_parts(model: Kinematics, params: jax.Array):
    """The joint-independent parts: ``B (4, 4)``, ``P (n, 4, 4)`` or None, ``S (n, 4, 4)`` or None,
    ``F (4, 4)`` (module docstring; None = identity). All exponentials are evaluated in one batch."""
    n, k = model.num_joints, len(SUFFIXES[model.convention])
    blocks = params[: n * k].reshape(n, k)
    tangents = params[n * k :].reshape(2, 6)
    if model.convention == "poe":
        tangents = jnp.concatenate([blocks, tangents], axis=0)
    E = _exp(tangents)
    B, F = model.T_base_link0 @ E[-2], model.T_link_flange @ E[-1]
    if model.convention == "dh":  # theta, d, a, alpha
        return B, None, dh_transform(blocks[:, 2], blocks[:, 3], blocks[:, 1], blocks[:, 0]), F
    if model.convention == "mdh":  # alpha, a, theta, d, beta
        P = _rot(0, blocks[:, 0]) @ _trans(0, blocks[:, 1]) @ _rot(1, blocks[:, 4])
        return B, P, _screw_z(blocks[:, 2], blocks[:, 3]), F
    return B, model.links @ E[:n], None, F


def _chain(model: Kinematics, parts, q: jax.Array):
    """``(T_base_flange (4, 4), joint frames (n, 4, 4))`` for one joint vector ``q (n,)``."""
    B, P, S, F = parts
    revolute = np.array([t == "revolute" for t in model.joint_types], dtype=np.float64)
    motion = model.joint_sign * q
    J = _screw_z(revolute * motion, (1.0 - revolute) * motion)
    T, frames = B, []
    for i in range(model.num_joints):
        T = T if P is None else T @ P[i]
        frames.append(T)
        T = T @ J[i] if S is None else T @ J[i] @ S[i]
    return T @ F, jnp.stack(frames)


def check_params(model: Kinematics, params) -> jax.Array:
    params = jnp.asarray(params, dtype=jnp.float64)
    if params.shape != (model.num_params,):
        raise BadInputError(
            f"params: expected shape ({model.num_params},) for the {model.convention} kinematics of "
            f"{model.name}, got shape {params.shape}"
        )
    return params


def _check_q(model: Kinematics, q) -> jax.Array:
    q = jnp.asarray(q, dtype=jnp.float64)
    if q.ndim < 1 or q.shape[-1] != model.num_joints:
        raise BadInputError(
            f"q: expected joint values of shape (..., {model.num_joints}) (rad, m) for {model.name}, "
            f"got shape {q.shape}"
        )
    return q


def forward(model: Kinematics, params, q) -> jax.Array:
    """Flange poses ``T_base_flange (..., 4, 4)`` (m) for ``params (P,)`` and joints ``q (..., n)``.

    ``q`` is in rad (revolute) and m (prismatic). Pure ``jax.numpy``: jit, vmap and jacfwd work in
    ``params`` and ``q``. Joint limits are not checked.
    """
    params, q = check_params(model, params), _check_q(model, q)
    parts = _fixed_parts(model, params)
    return jnp.vectorize(lambda qi: _chain(model, parts, qi)[0], signature="(n)->(i,j)")(q)


def joint_frames(model: Kinematics, params, q=None) -> jax.Array:
    """Joint frames ``(..., n, 4, 4)`` in the base frame (m) at ``q (..., n)`` (default zeros).

    Frame i's z axis is joint i's axis (direction of positive motion for ``joint_sign = +1``); its
    origin is a point on that axis. Joint i moves everything after its frame.
    """
    params = check_params(model, params)
    q = jnp.zeros(model.num_joints, dtype=jnp.float64) if q is None else _check_q(model, q)
    parts = _fixed_parts(model, params)
    return jnp.vectorize(lambda qi: _chain(model, parts, qi)[1], signature="(n)->(m,i,j)")(q)


# ----------------------------------------------------------------------------------------------
# Parameter names, groups, selection, controller units
# ----------------------------------------------------------------------------------------------


def _group_of(convention: str, joint_type: str, suffix: str) -> str:
    if suffix == _OFFSET[joint_type][convention]:
        return "joint_offsets"
    return "link_lengths" if suffix in _LENGTHS else "twists"


def parameter_groups(model: Kinematics) -> dict[str, list[str]]:
    """Group name -> parameter names: ``joint_offsets``, ``link_lengths``, ``twists``, ``base``,
    ``flange``, ``all`` (definitions in the module docstring)."""
    groups: dict[str, list[str]] = {g: [] for g in _GROUPS}
    for joint, joint_type in zip(model.joint_names, model.joint_types):
        for suffix in SUFFIXES[model.convention]:
            groups[_group_of(model.convention, joint_type, suffix)].append(f"{joint}.{suffix}")
    groups["base"] = [f"base.{c}" for c in _TANGENT]
    groups["flange"] = [f"flange.{c}" for c in _TANGENT]
    groups["all"] = list(model.param_names)
    return groups


def select(model: Kinematics, names, source: str = "cell") -> np.ndarray:
    """Boolean mask ``(P,)`` of the parameters named in ``names``: groups or ``"<joint>.<param>"``.

    Raises:
        BadInputError: an entry that is neither, naming ``source``, the robot, the closest valid name
            and the valid groups.
    """
    if isinstance(names, str):
        names = [names]
    groups = parameter_groups(model)
    index = {name: i for i, name in enumerate(model.param_names)}
    mask = np.zeros(model.num_params, dtype=bool)
    for entry in names:
        if isinstance(entry, str) and entry in groups:
            mask[[index[p] for p in groups[entry]]] = True
        elif isinstance(entry, str) and entry in index:
            mask[index[entry]] = True
        else:
            raise BadInputError(
                f"{source}: calibrate_kinematics: {entry!r} is neither a parameter group nor a "
                f"parameter of the {model.convention} kinematics of {model.name}"
                f"{suggest(entry, list(groups) + list(model.param_names), 0.0)} "
                f"Valid groups: {', '.join(groups)}; parameters are '<joint>.<name>' "
                f"with joints {', '.join(model.joint_names)} and names "
                f"{', '.join(SUFFIXES[model.convention])} (and base.rx .. flange.tz)."
            )
    return mask


def _controller_scale(model: Kinematics) -> np.ndarray:
    """``(n,)`` internal units per controller unit: rad/deg (revolute), m/mm (prismatic)."""
    return np.array([math.pi / 180.0 if t == "revolute" else 1e-3 for t in model.joint_types])


def _joint_array(model: Kinematics, values, name: str, units: str) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise BadInputError(f"{name}: expected numbers ({units}) for {model.name}, got {values!r}") from None
    n = model.num_joints
    if arr.ndim < 1 or arr.shape[-1] != n:
        got = f"{arr.shape[-1]} values" if arr.ndim >= 1 else "a scalar"
        raise BadInputError(
            f"{name}: expected {n} joint values for {model.name} ({', '.join(model.joint_names)}; "
            f"{units}), got {got} (shape {arr.shape})"
        )
    if not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise BadInputError(
            f"{name}{list(bad)}: joint {model.joint_names[bad[-1]]} of {model.name} is {arr[bad]}; "
            f"expected a finite value ({units})"
        )
    return arr


def joints_from_controller(model: Kinematics, joints, name: str = "joints_deg") -> np.ndarray:
    """Controller joint values ``(..., n)`` (deg revolute, mm prismatic) -> ``q`` (rad, m).

    Raises:
        BadInputError: wrong length or non-finite values, naming ``name`` and the robot.
    """
    arr = _joint_array(model, joints, name, "deg for revolute, mm for prismatic joints")
    return arr * _controller_scale(model)


def joints_to_controller(model: Kinematics, q, name: str = "q") -> np.ndarray:
    """Internal joint values ``q (..., n)`` (rad, m) -> controller units (deg, mm)."""
    return _joint_array(model, q, name, "rad for revolute, m for prismatic joints") / _controller_scale(model)


def _offset_index(model: Kinematics, i: int) -> int:
    suffixes = SUFFIXES[model.convention]
    return i * len(suffixes) + suffixes.index(_OFFSET[model.joint_types[i]][model.convention])


def controller_offsets(model: Kinematics, params) -> dict[str, float]:
    """Per joint, the zero offset to add in the controller (deg revolute, mm prismatic).

    ``offset_i = s_i * (params - nominal)[offset parameter of joint i]`` (``theta``/``d``, poe
    ``rz``/``tz``). Meaning: the calibrated arm at controller reading ``q`` is the nominal arm at
    ``q + offset`` (to first order for poe when the other five parameters of that joint moved too),
    i.e. adding ``offset`` to the controller's joint values makes the nominal model fit. Example: a
    ``theta`` larger by 0.01 rad on a joint with sign -1 gives -0.573 deg.
    """
    p, nominal = np.asarray(check_params(model, params)), np.asarray(model.nominal)
    sign, scale = np.asarray(model.joint_sign), _controller_scale(model)
    out = {}
    for i, joint in enumerate(model.joint_names):
        k = _offset_index(model, i)
        out[joint] = float(sign[i] * (p[k] - nominal[k]) / scale[i]) + 0.0  # no -0.0
    return out


# ----------------------------------------------------------------------------------------------
# Construction
# ----------------------------------------------------------------------------------------------


def _identifier(name: Any) -> str:
    s = re.sub(r"\W", "_", re.sub(r"\s+", "", str(name)))
    return "J" + s if not s or s[0].isdigit() else s


def make_model(*, name, convention, joint_types, joint_names, per_joint, sign, lower, upper,
          base=None, flange=None, links=None, where=None) -> Kinematics:
    """Build and check a model; ``per_joint (n, k)`` holds the nominal per-joint parameters."""
    where = where or f"kinematics of {name}"
    n = len(joint_types)
    names = tuple(_identifier(j) for j in joint_names)
    dup = sorted({j for j in names if names.count(j) > 1 or j in ("base", "flange")})
    if dup:
        raise BadInputError(
            f"{where}: joint names {list(joint_names)} give the identifiers {list(names)}: {dup} "
            f"repeat or clash with base/flange; give every joint a distinct name such as 'A1'"
        )
    per_joint = np.asarray(per_joint, dtype=np.float64).reshape(n, len(SUFFIXES[convention]))
    arrays = {
        "per-joint parameters": per_joint, "sign": np.asarray(sign, dtype=np.float64),
        "lower": np.asarray(lower, dtype=np.float64), "upper": np.asarray(upper, dtype=np.float64),
        "base": np.eye(4) if base is None else np.asarray(base, dtype=np.float64),
        "flange": np.eye(4) if flange is None else np.asarray(flange, dtype=np.float64),
        "links": np.tile(np.eye(4), (n, 1, 1)) if links is None else np.asarray(links, dtype=np.float64),
    }
    for label, arr in arrays.items():
        if not np.all(np.isfinite(arr)):
            raise BadInputError(f"{where}: {label}: expected finite values, got {arr.tolist()}")
    if not np.all(np.abs(arrays["sign"]) == 1.0):
        raise BadInputError(f"{where}: sign: expected +1 or -1 per joint, got {arrays['sign'].tolist()}")
    for i in np.flatnonzero(arrays["lower"] >= arrays["upper"]):
        raise BadInputError(
            f"{where}, joint {i + 1} ({names[i]}): lower limit {arrays['lower'][i]:.6g} >= upper "
            f"limit {arrays['upper'][i]:.6g}; write the limits as [lower, upper] with lower < upper"
        )
    param_names = tuple(f"{j}.{s}" for j in names for s in SUFFIXES[convention])
    param_names += tuple(f"{f}.{c}" for f in ("base", "flange") for c in _TANGENT)
    f64 = functools.partial(jnp.asarray, dtype=jnp.float64)
    return Kinematics(
        nominal=f64(np.concatenate([per_joint.reshape(-1), np.zeros(12)])),
        joint_sign=f64(arrays["sign"]), lower=f64(arrays["lower"]), upper=f64(arrays["upper"]),
        T_base_link0=f64(arrays["base"]), T_link_flange=f64(arrays["flange"]), links=f64(arrays["links"]),
        name=str(name), convention=convention, joint_types=tuple(joint_types), joint_names=names,
        param_names=param_names,
    )


def effective_base_flange(model: Kinematics, params) -> tuple[np.ndarray, np.ndarray]:
    B, _, _, F = _fixed_parts(model, check_params(model, params))
    return np.asarray(B), np.asarray(F)


def _inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def poe_from_frames(model_like: dict, base, frames, home) -> Kinematics:
    """Local POE model with joint frames ``frames (n, 4, 4)`` and flange ``home`` at zero (base frame)."""
    base, frames, home = (np.asarray(x, dtype=np.float64) for x in (base, frames, home))
    previous = [base] + list(frames[:-1])
    links = np.stack([_inv(a) @ b for a, b in zip(previous, frames)])
    return make_model(convention="poe", per_joint=np.zeros((len(frames), 6)), base=base,
                 flange=_inv(frames[-1]) @ home, links=links, **model_like)


def convert(model: Kinematics, convention: str) -> Kinematics:
    """The same nominal FK in another convention: dh -> mdh, any -> poe (exact, to rounding).

    The new model's nominal ``base.*``/``flange.*`` are zero (a non-zero nominal perturbation is
    folded into ``T_base_link0``/``T_link_flange``).

    Raises:
        BadInputError: an unknown convention or an unsupported direction (mdh/poe -> dh, poe -> mdh).
    """
    if convention not in CONVENTIONS:
        raise BadInputError(f"convention: expected one of {CONVENTIONS}, got {convention!r}")
    if convention == model.convention:
        return model
    like = {"name": model.name, "joint_types": model.joint_types, "joint_names": model.joint_names,
            "sign": np.asarray(model.joint_sign), "lower": np.asarray(model.lower), "upper": np.asarray(model.upper)}
    base, flange = effective_base_flange(model, model.nominal)
    if convention == "poe":
        zeros = jnp.zeros(model.num_joints, dtype=jnp.float64)
        return poe_from_frames(like, base, joint_frames(model, model.nominal),
                                forward(model, model.nominal, zeros))
    if model.convention != "dh":
        raise BadInputError(
            f"kinematics of {model.name}: converting {model.convention} to {convention} is not "
            f"supported; write the table in {convention}, or convert to poe"
        )
    dh = np.asarray(model.nominal[: 4 * model.num_joints]).reshape(-1, 4)  # theta, d, a, alpha
    alpha_prev = np.concatenate([[0.0], dh[:-1, 3]])
    a_prev = np.concatenate([[0.0], dh[:-1, 2]])
    mdh = np.stack([alpha_prev, a_prev, dh[:, 0], dh[:, 1], np.zeros(len(dh))], axis=1)
    tail = np.asarray(_trans(0, dh[-1, 2]) @ _rot(0, dh[-1, 3]))
    return make_model(convention="mdh", per_joint=mdh, base=base, flange=tail @ flange, **like)


def from_dh_robot(robot: DHRobot, convention: str = "dh") -> Kinematics:
    """A model with exactly the FK of ``kinematics.forward_kinematics(robot, q)`` in ``convention``."""
    dh = np.stack([np.asarray(x) for x in (robot.theta_offset, robot.d, robot.a, robot.alpha)], axis=1)
    model = make_model(name=robot.name, convention="dh", joint_types=("revolute",) * robot.num_joints,
                  joint_names=robot.joint_names, per_joint=dh, sign=robot.joint_sign,
                  lower=robot.lower, upper=robot.upper, base=robot.T_base_link0,
                  flange=robot.T_link_flange)
    return convert(model, convention)


# ----------------------------------------------------------------------------------------------
# Presets
# ----------------------------------------------------------------------------------------------

# DH frame 0 with z along the base x axis and x up (y = -base y).
_Z_ALONG_X = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
_TWO_PI = 2.0 * math.pi


def positioner_2axis() -> Kinematics:
    """Tilt-rotate part positioner (dh), flange = table face centre, z = table normal.

    Axis 1 (``tilt``) is horizontal along the base x axis, 0.65 m above the base; axis 2 (``rotate``)
    is the table normal through the table centre, which lies above the tilt axis. At zero the table is
    horizontal, its face 0.80 m above the base at (0, 0, 0.8) m, flange axes parallel to the base's.
    Positive tilt turns about +x, positive rotate about the table normal. Limits: tilt +-135 deg,
    rotate +-360 deg.
    """
    base = _Z_ALONG_X.copy()
    base[2, 3] = 0.65
    # theta, d, a, alpha: frame 1 z = table normal (x1 = base y), frame 2 on the face with x = base x
    dh = [[-math.pi / 2, 0.0, 0.0, -math.pi / 2], [-math.pi / 2, 0.15, 0.0, 0.0]]
    return make_model(name="2-axis tilt-rotate positioner", convention="dh",
                 joint_types=("revolute", "revolute"), joint_names=("tilt", "rotate"), per_joint=dh,
                 sign=[1.0, 1.0], lower=[-math.radians(135.0), -_TWO_PI],
                 upper=[math.radians(135.0), _TWO_PI], base=base)


def linear_track() -> Kinematics:
    """Linear track (dh): one prismatic axis ``travel`` along the base x axis, 0 .. 6000 mm.

    The flange (carriage plate) is at ``(q, 0, 0)`` m with the base's orientation.
    """
    return make_model(name="linear track", convention="dh", joint_types=("prismatic",),
                 joint_names=("travel",), per_joint=[[0.0, 0.0, 0.0, 0.0]], sign=[1.0], lower=[0.0],
                 upper=[6.0], base=_Z_ALONG_X, flange=_Z_ALONG_X.T)


def rotary_table() -> Kinematics:
    """Rotary table (dh): one revolute axis ``rotate`` about the base z axis, +-360 deg; flange = table
    centre at the base origin, ``Rz(q)``."""
    return make_model(name="rotary table", convention="dh", joint_types=("revolute",),
                 joint_names=("rotate",), per_joint=[[0.0, 0.0, 0.0, 0.0]], sign=[1.0],
                 lower=[-_TWO_PI], upper=[_TWO_PI])


def _arm_preset(key: str) -> Kinematics:
    return from_dh_robot(robots.PRESETS[key]())


PRESETS: dict[str, Callable[[], Kinematics]] = {
    **{key: functools.partial(_arm_preset, key) for key in robots.PRESETS},
    "positioner_2axis": positioner_2axis,
    "linear_track": linear_track,
    "rotary_table": rotary_table,
}
"""Preset name -> constructor of the nominal model (dh): the arms of :mod:`jcalib.geometry.robots`
and three external axes."""


def suggest(word: Any, options, cutoff: float = 0.5) -> str:
    """A did-you-mean hint for the closest of ``options`` to ``word`` (empty when none is close)."""
    close = difflib.get_close_matches(str(word), list(options), 1, cutoff)
    return f"; did you mean {close[0]!r}?" if close else ""
