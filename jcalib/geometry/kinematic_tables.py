"""The cell-spec table form of a kinematic model, both ways: :func:`from_spec` reads a cell spec's
``kinematics:`` entry (a preset name, ``{preset, convention, base}``, or a DH / MDH / POE table) into a
:class:`~jcalib.geometry.kinematic_models.Kinematics`; :func:`to_spec` writes calibrated parameters back as
such a table (``from_spec`` of it has the same FK) and :func:`table` as an export table with units.

Units in tables: lengths ``*_m`` (limits of prismatic axes ``limits_mm``), angles ``*_deg``. Every
malformed entry raises :class:`~jcalib.errors.BadInputError` naming the source, the robot, the joint and
the field, and what to write instead.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.kinematic_models import (CONVENTIONS, JOINT_TYPES, PRESETS, SUFFIXES, Kinematics, check_params,
                                              convert, effective_base_flange, forward, joint_frames, make_model,
                                              poe_from_frames, suggest)

__all__ = ["DELTA_DH_KEYS", "apply_delta_dh", "from_spec", "table", "to_spec"]


# ----------------------------------------------------------------------------------------------
# Export
# ----------------------------------------------------------------------------------------------


def _limits_entry(joint_type: str, lo: float, hi: float) -> dict:
    if joint_type == "revolute":
        return {"limits_deg": [math.degrees(lo), math.degrees(hi)]}
    return {"limits_mm": [lo * 1e3, hi * 1e3]}


def _joint_rows(model: Kinematics, params) -> list[dict]:
    p = np.asarray(check_params(model, params))
    suffixes = SUFFIXES[model.convention]
    k = len(suffixes)
    frames = np.asarray(joint_frames(model, p))
    rows = []
    for i, (joint, joint_type) in enumerate(zip(model.joint_names, model.joint_types)):
        v = dict(zip(suffixes, (float(x) for x in p[i * k : (i + 1) * k])))
        row: dict[str, Any] = {"name": joint, "type": joint_type}
        if model.convention == "poe":
            row.update({f"{c}_deg": math.degrees(v[c]) for c in ("rx", "ry", "rz")})
            row.update({f"{c}_m": v[c] for c in ("tx", "ty", "tz")})
            row["axis"] = frames[i, :3, 2].tolist()
            row["point_m"] = frames[i, :3, 3].tolist()
        else:
            row.update(a_m=v["a"], alpha_deg=math.degrees(v["alpha"]), d_m=v["d"],
                       theta_deg=math.degrees(v["theta"]))
            if model.convention == "mdh":
                row["beta_deg"] = math.degrees(v["beta"])
        row["sign"] = int(np.asarray(model.joint_sign)[i])
        row.update(_limits_entry(joint_type, float(model.lower[i]), float(model.upper[i])))
        rows.append(row)
    return rows


def table(model: Kinematics, params) -> list[dict]:
    """Export table: one dict per joint, then ``{"name": "base", "matrix"}``, ``{"name": "flange", ...}``.

    Joint dicts: ``name``, ``type``, dh/mdh ``a_m, alpha_deg, d_m, theta_deg`` (mdh ``beta_deg``);
    poe ``rx_deg, ry_deg, rz_deg, tx_m, ty_m, tz_m`` plus the joint's ``axis`` and ``point_m`` in the
    base frame at zero joints; ``sign``; ``limits_deg`` (revolute) or ``limits_mm`` (prismatic).
    The matrices are ``T_base_link0 . Exp(base)`` and ``T_link_flange . Exp(flange)`` (4x4, m).
    """
    base, flange = effective_base_flange(model, params)
    return _joint_rows(model, params) + [
        {"name": "base", "matrix": base.tolist()}, {"name": "flange", "matrix": flange.tolist()}
    ]


def to_spec(model: Kinematics, params) -> dict:
    """A cell-spec ``kinematics:`` table for ``params``: :func:`from_spec` of it has the same FK."""
    rows = _joint_rows(model, params)
    if model.convention == "poe":
        keep = ("name", "type", "axis", "point_m", "sign", "limits_deg", "limits_mm")
        home = forward(model, params, jnp.zeros(model.num_joints, dtype=jnp.float64))
        return {"convention": "poe", "joints": [{k: r[k] for k in keep if k in r} for r in rows],
                "home": np.asarray(home).tolist()}
    base, flange = effective_base_flange(model, params)
    return {"convention": model.convention, "joints": rows, "base": base.tolist(),
            "flange": flange.tolist()}


# ----------------------------------------------------------------------------------------------
# Cell spec parsing
# ----------------------------------------------------------------------------------------------


#: Lengths (m) beyond this are refused even where the caller states no reach limit (no overflow downstream).
HARD_LENGTH_LIMIT_M = 1e6
#: The largest angle (deg) of a table (alpha, theta, beta, a UR delta; revolute limits): ten turns. A
#: controller's offsets can pass a whole turn (a UR's delta_theta of 6.47 rad), nothing sane passes ten.
MAX_TABLE_ANGLE_DEG = 3600.0
#: The largest prismatic joint limit (m): a track or a gantry lies within a cell (the reach limit bounds
#: the links, not the travel of an external axis).
MAX_TRAVEL_M = 100.0


def _check_reach(model: Kinematics, where: str, limit_m: float | None, lengths: list[tuple[str, float]]) -> None:
    """Refuse a chain whose flange lies beyond the reach limit (at zero joints, at the revolute joints' limits):
    in a kinematic table that is a unit error (mm as m). Single lengths are not bounded: a calibrated UR's
    link offsets reach hundreds of metres that cancel along parallel axes; its flange does not.

    ``lengths``: ``(label, value m)`` of the table's lengths, the largest of which the message names.
    """
    if limit_m is None:
        return
    lo, hi = np.asarray(model.lower, np.float64), np.asarray(model.upper, np.float64)
    revolute = np.array([t == "revolute" for t in model.joint_types])
    # revolute axes within their limits (one turn at most), prismatic ones (tracks) at their zero
    lo, hi = np.where(revolute, np.maximum(lo, -np.pi), 0.0), np.where(revolute, np.minimum(hi, np.pi), 0.0)
    q = np.stack([np.zeros_like(lo), lo, hi, 0.5 * (lo + hi)])
    with np.errstate(over="ignore", invalid="ignore"):
        T = np.asarray(forward(model, model.nominal, jnp.asarray(q)), np.float64)
        dist = np.linalg.norm(T[:, :3, 3], axis=1)
    worst = float(np.max(np.where(np.isfinite(dist), dist, np.inf)))
    if worst <= limit_m:
        return
    label, value = max(lengths, key=lambda lv: abs(lv[1]), default=("", 0.0))
    largest = f"; its largest length is {label} = {value:.4g} m" if label else ""
    raise BadInputError(f"{where}: the flange lies up to {worst:.4g} m from the base (at zero joints and at the joint "
                        f"limits), beyond the reach limit of {limit_m:g} m{largest}: kinematic tables are in metres; "
                        "are these millimetres? (divide by 1000; a genuinely larger machine, e.g. on a long track: "
                        "raise JCALIB_MAX_REACH_M)")


def _check_length(value_m: float, key: str, where: str, limit_m: float | None) -> None:
    """Refuse a length (m) beyond the reach limit: in kinematic tables that is a unit error (mm as m)."""
    limit = HARD_LENGTH_LIMIT_M if limit_m is None else limit_m
    if not abs(value_m) <= limit:
        raise BadInputError(f"{where}: {key}: {value_m:.4g} m is beyond the reach limit of {limit:g} m: kinematic "
                            "tables are in metres; are these millimetres? (divide by 1000; a genuinely larger "
                            "machine, e.g. a long track: raise JCALIB_MAX_REACH_M)")


def _check_angle(value_deg: float, key: str, where: str) -> None:
    if not abs(value_deg) <= MAX_TABLE_ANGLE_DEG:
        raise BadInputError(f"{where}: {key}: {value_deg:.4g} deg is beyond ±{MAX_TABLE_ANGLE_DEG:g} deg (ten turns); "
                            "write the angle in degrees")


_KEY_HINTS = {"beta_deg": " (beta_deg belongs to the mdh convention: write convention: mdh, or drop it)"}


def _check_keys(d: dict, allowed, where: str, what: str) -> None:
    for key in d:
        if key not in allowed:
            hint = _KEY_HINTS.get(key) or suggest(key, allowed)
            raise BadInputError(
                f"{where}: unknown key {key!r} in {what}{hint} Write only {', '.join(sorted(allowed))}."
            )


def _number(d: dict, key: str, where: str, hint: str, default: float | None = None) -> float:
    if key not in d:
        if default is not None:
            return default
        raise BadInputError(f"{where}: missing field {key!r}; write {key}: <number> ({hint})")
    v = d[key]
    try:
        finite = not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating)) and math.isfinite(v)
    except OverflowError:  # an integer beyond float
        finite = False
    if not finite:
        raise BadInputError(f"{where}: {key}: expected a finite number ({hint}), got {v!r}")
    return float(v)


def _array(d: dict, key: str, shape: tuple, where: str, hint: str) -> np.ndarray:
    if key not in d:
        raise BadInputError(f"{where}: missing field {key!r}; write {key}: {hint}")
    try:
        arr = np.asarray(d[key], dtype=np.float64)
    except (TypeError, ValueError):
        raise BadInputError(f"{where}: {key}: expected numbers, got {d[key]!r}; write {key}: {hint}") from None
    if arr.shape != shape:
        raise BadInputError(f"{where}: {key}: expected shape {shape}, got {arr.shape} ({d[key]!r}); write {key}: {hint}")
    if not np.all(np.isfinite(arr)):
        raise BadInputError(f"{where}: {key}: expected finite values, got {arr.tolist()}; write {key}: {hint}")
    return arr


def _transform(d: dict, key: str, where: str, default_identity: bool = True,
               limit_m: float | None = None) -> np.ndarray:
    hint = "[[4x4]], a rigid transform [[R, t], [0, 0, 0, 1]] in metres with orthonormal R, det +1"
    if key not in d and default_identity:
        return np.eye(4)
    T = _array(d, key, (4, 4), where, hint)
    R = T[:3, :3]
    if (np.max(np.abs(R.T @ R - np.eye(3))) > 1e-6 or np.linalg.det(R) < 0.0
            or np.max(np.abs(T[3] - [0.0, 0.0, 0.0, 1.0])) > 0.0):
        raise BadInputError(f"{where}: {key}: not a rigid transform: {np.round(T, 6).tolist()}; write {key}: {hint}")
    _check_length(float(np.linalg.norm(T[:3, 3])), f"{key} (its translation)", where, limit_m)
    u, _, vt = np.linalg.svd(R)  # the nearest rotation: printed matrices are rounded to ~1e-6
    T[:3, :3] = u @ vt
    return T


def _preset(name: Any, where: str) -> Kinematics:
    if not isinstance(name, str) or name not in PRESETS:
        raise BadInputError(
            f"{where}: unknown kinematics preset {name!r}{suggest(name, PRESETS, 0.0)} "
            f"Write one of {', '.join(PRESETS)}, or a dh/mdh/poe table."
        )
    return PRESETS[name]()


#: ``delta_dh`` keys: UR's ``calibration.conf`` names without ``delta_`` (rad, m).
DELTA_DH_KEYS = ("theta", "a", "d", "alpha")


def apply_delta_dh(model: Kinematics, delta: Any, where: str) -> Kinematics:
    """``model`` (a dh chain) with ``delta`` ``{theta, a, d, alpha: [n numbers]}`` (rad, m) added to its joint rows.

    This is how a Universal Robots controller applies its factory calibration (``calibration.conf``'s
    ``delta_theta``, ``delta_a``, ``delta_d``, ``delta_alpha``) to the nominal DH table of its type: the
    effective table is nominal + delta, ``theta_i = q_i + theta_i``.

    Raises:
        BadInputError: not a dh chain, a missing or extra key, a list of the wrong length, a non-finite number.
    """
    if model.convention != "dh":
        raise BadInputError(f"{where}: delta_dh: the preset is a {model.convention} chain; deltas apply to dh tables")
    if not isinstance(delta, dict):
        raise BadInputError(f"{where}: delta_dh: expected a mapping {{theta: [...], a: [...], d: [...], alpha: [...]}} "
                            f"(rad, m), got {delta!r}")
    _check_keys(delta, DELTA_DH_KEYS, f"{where}: delta_dh", "delta_dh")
    n = model.num_joints
    rows = np.zeros((n, 4))
    for col, key in ((0, "theta"), (1, "d"), (2, "a"), (3, "alpha")):
        if key in delta:
            rows[:, col] = _array(delta, key, (n,), f"{where}: delta_dh", f"[{n} numbers] ({'rad' if key in ('theta', 'alpha') else 'm'})")
            for x in rows[:, col]:
                if key in ("theta", "alpha"):
                    _check_angle(math.degrees(x), f"delta_dh.{key} ({x:.4g} rad)", where)
                else:  # a UR's delta_d reach hundreds of metres that cancel along parallel axes: no reach limit
                    _check_length(x, f"delta_dh.{key}", where, None)
    nominal = np.asarray(model.nominal, dtype=np.float64).copy()
    nominal[: 4 * n] += rows.reshape(-1)
    return dataclasses.replace(model, nominal=jnp.asarray(nominal))


def _convention(spec: dict, where: str) -> str:
    if "convention" not in spec:
        raise BadInputError(f"{where}: missing field 'convention'; write convention: dh, mdh or poe")
    conv = spec["convention"]
    if conv not in CONVENTIONS:
        raise BadInputError(
            f"{where}: convention: unknown {conv!r}{suggest(conv, CONVENTIONS)} Write dh, mdh or poe."
        )
    return conv


def _joint_common(js: Any, i: int, where: str, allowed: set) -> tuple:
    """(name, type, sign, lower, upper, where) of one joint entry; limits in rad / m."""
    jwhere = f"{where}, joint {i + 1}"
    if not isinstance(js, dict):
        raise BadInputError(f"{jwhere}: expected a mapping with name, type, ... got {js!r}")
    if "name" not in js or not isinstance(js["name"], str) or not js["name"].strip():
        raise BadInputError(f"{jwhere}: missing field 'name'; write name: A{i + 1} (the controller's axis name)")
    jwhere = f"{where}, joint {i + 1} ({js['name']!r})"
    _check_keys(js, allowed, jwhere, "the joint entry")
    joint_type = js.get("type", "revolute")
    if joint_type not in JOINT_TYPES:
        raise BadInputError(f"{jwhere}: type: unknown {joint_type!r}{suggest(joint_type, JOINT_TYPES)} "
                            f"Write revolute or prismatic.")
    sign = _number(js, "sign", jwhere, "+1 or -1", 1.0)
    if abs(sign) != 1.0:
        raise BadInputError(f"{jwhere}: sign: expected +1 or -1, got {js['sign']!r}; write sign: 1 or sign: -1")
    key, other, unit, scale = (("limits_deg", "limits_mm", "deg", math.pi / 180.0) if joint_type == "revolute"
                               else ("limits_mm", "limits_deg", "mm", 1e-3))
    if other in js:
        raise BadInputError(f"{jwhere}: {other}: a {joint_type} joint's limits are in {unit}; "
                            f"write {key}: [lower, upper] instead")
    lo, hi = _array(js, key, (2,), jwhere, f"[lower, upper] ({unit})")
    if lo >= hi:
        raise BadInputError(f"{jwhere}: {key}: lower {lo:g} >= upper {hi:g}; write {key}: [lower, upper] "
                            f"with lower < upper ({unit})")
    for x in (lo, hi):
        if joint_type == "revolute":
            _check_angle(x, key, jwhere)
        elif not abs(x) * 1e-3 <= MAX_TRAVEL_M:
            raise BadInputError(f"{jwhere}: {key}: {x:.4g} mm is beyond ±{MAX_TRAVEL_M * 1e3:g} mm; prismatic "
                                "limits are in millimetres (are these micrometres?)")
    return js["name"], joint_type, sign, lo * scale, hi * scale, jwhere


def _joints_list(spec: dict, where: str) -> list:
    joints = spec.get("joints")
    if not isinstance(joints, list) or not joints:
        raise BadInputError(f"{where}: joints: expected a non-empty list of joint entries, got {joints!r}; "
                            f"write joints: [{{name: A1, type: revolute, ...}}, ...]")
    return joints


def _dh_table(spec: dict, robot: str, convention: str, where: str, limit_m: float | None) -> Kinematics:
    _check_keys(spec, {"convention", "joints", "base", "flange"}, where, f"the {convention} table")
    allowed = {"name", "type", "a_m", "alpha_deg", "d_m", "theta_deg", "sign", "limits_deg", "limits_mm"}
    allowed |= {"beta_deg"} if convention == "mdh" else set()
    names, types, signs, lower, upper, rows, lengths = [], [], [], [], [], [], []
    for i, js in enumerate(_joints_list(spec, where)):
        name, joint_type, sign, lo, hi, jwhere = _joint_common(js, i, where, allowed)
        a = _number(js, "a_m", jwhere, "link length, m")
        d = _number(js, "d_m", jwhere, "link offset, m")
        for key, v in (("a_m", a), ("d_m", d)):
            _check_length(v, key, jwhere, None)
            lengths.append((f"joint {i + 1} ({name!r}) {key}", v))
        angles = {k: _number(js, k, jwhere, hint, default) for k, hint, default in (
            ("alpha_deg", "link twist, deg", None), ("theta_deg", "joint angle offset, deg", 0.0),
            ("beta_deg", "Hayati tilt, deg", 0.0))}
        for key, v in angles.items():
            _check_angle(v, key, jwhere)
        alpha, theta, beta = (math.radians(angles[k]) for k in ("alpha_deg", "theta_deg", "beta_deg"))
        rows.append([theta, d, a, alpha] if convention == "dh" else [alpha, a, theta, d, beta])
        names.append(name), types.append(joint_type), signs.append(sign), lower.append(lo), upper.append(hi)
    model = make_model(name=robot, convention=convention, joint_types=tuple(types), joint_names=names,
                       per_joint=rows, sign=signs, lower=lower, upper=upper,
                       base=_transform(spec, "base", where, limit_m=limit_m),
                       flange=_transform(spec, "flange", where, limit_m=limit_m), where=where)
    _check_reach(model, where, limit_m, lengths)
    return model


def _min_rotation(R_prev: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The rotation with z axis ``z`` closest to ``R_prev`` (the smallest turn of its z onto ``z``)."""
    u = R_prev[:, 2]
    c, w = float(u @ z), np.cross(u, z)
    if c < -1.0 + 1e-12:  # opposite: half turn about the previous x axis
        x = R_prev[:, 0]
        return (2.0 * np.outer(x, x) - np.eye(3)) @ R_prev
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    return (np.eye(3) + W + W @ W / (1.0 + c)) @ R_prev


def _poe_table(spec: dict, robot: str, where: str, limit_m: float | None) -> Kinematics:
    _check_keys(spec, {"convention", "joints", "home"}, where, "the poe table")
    allowed = {"name", "type", "axis", "point_m", "sign", "limits_deg", "limits_mm"}
    names, types, signs, lower, upper, frames, lengths = [], [], [], [], [], [], []
    R = np.eye(3)
    for i, js in enumerate(_joints_list(spec, where)):
        name, joint_type, sign, lo, hi, jwhere = _joint_common(js, i, where, allowed)
        axis = _array(js, "axis", (3,), jwhere, "[x, y, z], a unit vector in the base frame at zero joints")
        norm = float(np.linalg.norm(axis))
        if abs(norm - 1.0) > 1e-6:
            fix = np.round(axis / norm, 9).tolist() if norm > 0 else "[0, 0, 1]"
            raise BadInputError(f"{jwhere}: axis: expected a unit vector, got {axis.tolist()} (norm {norm:.6g}); "
                                f"write axis: {fix}")
        point = _array(js, "point_m", (3,), jwhere, "[x, y, z], a point on the axis, base frame at zero joints, m")
        _check_length(float(np.linalg.norm(point)), "point_m (its distance from the base)", jwhere, None)
        lengths.append((f"joint {i + 1} ({name!r}) point_m (its distance from the base)", float(np.linalg.norm(point))))
        R = _min_rotation(R, axis / norm)
        F = np.eye(4)
        F[:3, :3], F[:3, 3] = R, point
        frames.append(F)
        names.append(name), types.append(joint_type), signs.append(sign), lower.append(lo), upper.append(hi)
    if "home" not in spec:
        raise BadInputError(f"{where}: missing field 'home'; write home: [[4x4]], the flange pose in the base "
                            f"frame at zero joints (m)")
    like = {"name": robot, "joint_types": tuple(types), "joint_names": names, "sign": signs, "lower": lower,
            "upper": upper, "where": where}
    model = poe_from_frames(like, np.eye(4), np.stack(frames), _transform(spec, "home", where, False, limit_m))
    _check_reach(model, where, limit_m, lengths)
    return model


def from_spec(spec, robot: str, source: str = "cell", max_length_m: float | None = None) -> Kinematics:
    """Build the kinematics of a cell-spec ``kinematics:`` entry.

    Accepts a preset name; ``{"preset": NAME}`` with optional ``"delta_dh": {theta, a, d, alpha}`` (lists of
    one number per joint, rad and m, added to the preset's dh table: a UR controller's factory calibration,
    :func:`apply_delta_dh`), ``"base": [[4x4]]`` (m, pre-multiplied: the preset's base frame in the robot base
    frame) and ``"convention"`` (converted, same FK); a
    dh/mdh table ``{"convention", "joints": [{"name", "type", "a_m", "alpha_deg", "d_m",
    "theta_deg" (default 0), "beta_deg" (mdh, default 0), "sign" (default 1), "limits_deg" |
    "limits_mm"}], "base", "flange"}`` (4x4, m, default identity); or a poe table ``{"convention":
    "poe", "joints": [{"name", "type", "axis" (unit, base frame at zero), "point_m", "sign",
    "limits_deg" | "limits_mm"}], "home": [[4x4]]}`` (flange pose at zero joints). ``type`` defaults
    to revolute; a joint moves by ``sign * q`` about/along its axis. A :class:`Kinematics` passes
    through. Tables are named ``robot``, presets ``"<robot> (<model>)"``.

    ``max_length_m`` (m), the reach limit of cell specs (:func:`jcalib.io.schema.common.max_reach_m`), bounds
    the flange's distance from the base (at zero joints and at the revolute joints' limits) and the base,
    flange and home translations; None: no reach check. Single lengths are bounded by
    :data:`HARD_LENGTH_LIMIT_M`, prismatic limits by :data:`MAX_TRAVEL_M`, angles by ten turns.

    Raises:
        BadInputError: naming ``source``, the robot, the joint and the field, and what to write.
    """
    where = f"{source}: kinematics of robot {robot!r}"
    if isinstance(spec, Kinematics):
        return spec
    spec = {"preset": spec} if isinstance(spec, str) else spec
    if not isinstance(spec, dict):
        raise BadInputError(f"{where}: expected a preset name or a mapping (preset: ..., or a dh/mdh/poe "
                            f"table), got {spec!r}")
    if "preset" in spec:
        _check_keys(spec, {"preset", "base", "convention", "delta_dh"}, where, "the preset entry")
        model = _preset(spec["preset"], where)
        model = dataclasses.replace(model, name=f"{robot} ({model.name})")
        if "delta_dh" in spec:
            model = apply_delta_dh(model, spec["delta_dh"], where)
        if "base" in spec:
            base = jnp.asarray(_transform(spec, "base", where, limit_m=max_length_m), dtype=jnp.float64)
            model = dataclasses.replace(model, T_base_link0=base @ model.T_base_link0)
        return convert(model, _convention(spec, where)) if "convention" in spec else model
    if "joints" not in spec:
        raise BadInputError(f"{where}: expected 'preset' or 'joints' in {sorted(spec)}; write preset: "
                            f"<name> ({', '.join(PRESETS)}) or a dh/mdh/poe table with joints: [...]")
    convention = _convention(spec, where)
    if convention == "poe":
        return _poe_table(spec, robot, where, max_length_m)
    return _dh_table(spec, robot, convention, where, max_length_m)
