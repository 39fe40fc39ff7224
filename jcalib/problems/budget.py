"""Error budgets: what each stated input (an assumption, GUM Type B) adds to every unknown's σ.

The cell's ``assumptions:`` (:mod:`jcalib.io.assumptions`) plus visible defaults (every used target's
printed scale, :data:`jcalib.io.assumptions.DEFAULT_SCALE_SIGMA_REL`) become a vector ``θ`` of stated
inputs with a stated covariance ``Σ_θ`` (block-diagonal: the assumptions are independent). Their
sensitivities ``S = dx*/dθ`` come from one block solve with the final solve's system
(:func:`jcalib.solve.sensitivity.sensitivities`); each assumption ``a`` contributes ``S_a Σ_a S_aᵀ`` to an
unknown's covariance, and ``covariance_combined = covariance + Σ_a S_a Σ_a S_aᵀ``. The sampling
covariance is never changed: both are written, named.

What a contribution includes: the first-order effect of the stated input on the estimate. What it does
not: nonlinearity beyond first order, inputs that are not stated (model error).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import rotation_z_to
from jcalib.io.assumptions import DEFAULT_SCALE_SIGMA_REL, Assumption
from jcalib.problems.budget_checks import assumption_checks
from jcalib.problems.build import CORNER_KINDS, Built, se3_matrix
from jcalib.problems.graph import Graph
from jcalib.problems.start import Start
from jcalib.solve.sensitivity import Perturbation, sensitivities

_ANGLE = ("theta", "alpha", "beta", "rx", "ry", "rz")
_PIXEL = {"fx", "fy", "cx", "cy", "skew"}
_TANGENT = ("rx", "ry", "rz", "tx", "ty", "tz")


@dataclass
class Item:
    """One assumption as the solve sees it: columns ``start:start+size`` of ``θ`` with covariance ``cov``.

    ``kind``: ``scale`` | ``held`` | ``noise``; ``what``: a phrase for messages; ``advice``: what reduces it;
    ``coords``: the names of its columns and ``units`` theirs; ``sigma_text``: the stated σ as written.
    """

    key: str
    kind: str
    what: str
    advice: str
    start: int
    size: int
    cov: np.ndarray
    coords: list[str]
    units: list[str]
    source: str
    sigma_text: str


def _fail(cell, a: Assumption, why: str) -> BadInputError:
    return BadInputError(f"{cell.source}: assumptions.{a.key}: {why}")


def _held_intrinsics(cell, a: Assumption, start: Start, built: Built):
    cam = a.thing
    if cam not in cell.cameras or f"intrinsics:{cam}" not in {v.name for v in built.problem.variables}:
        raise _fail(cell, a, f"'{cam}' is not a camera with intrinsics in this calibration")
    v = built.problem.variable(f"intrinsics:{cam}")
    names = list(v.coord_names)
    held = np.asarray(v.fixed[0], bool).copy()
    if start.aspects[cam][0]:
        held[1] = False  # fy follows fx (aspect): not an input of its own
    held_names = [n for n, h in zip(names, held) if h]
    if not held_names:
        raise _fail(cell, a, f"camera '{cam}''s intrinsics are all estimated, none is held; an assumption states the "
                             "uncertainty of a held input (list the held ones in the camera's fix:) or remove it")
    if a.covariance is not None:
        if not set(held_names) <= set(a.names):
            raise _fail(cell, a, f"the result's covariance is over {list(a.names)}, which lacks held "
                                 f"{sorted(set(held_names) - set(a.names))}")
        idx = [list(a.names).index(n) for n in held_names]
        cov = np.asarray(a.covariance)[np.ix_(idx, idx)]
    else:
        bad = sorted(set(a.sigma) - set(held_names))
        if bad:
            raise _fail(cell, a, f"{bad} are not held intrinsics of '{cam}' (held: {held_names}); an estimated "
                                 "intrinsic has no stated uncertainty")
        cov = np.diag([a.sigma.get(n, 0.0) ** 2 for n in held_names])
    coords = [int(np.flatnonzero(np.array(names) == n)[0]) for n in held_names]
    units = ["px" if n in _PIXEL else "" for n in held_names]
    return coords, held_names, cov, units


def _pose_name(g: Graph, cell, a: Assumption) -> str:
    if a.thing.startswith("T_"):
        return a.thing
    for spec in list(cell.cameras.values()) + list(cell.targets.values()):
        if spec.name == a.thing:
            m = g.mount_name(spec)
            if m is not None:
                return m
    raise _fail(cell, a, f"'{a.thing}' has no pose of its own in this cell")


def resolve(g: Graph, built: Built, start: Start) -> tuple[Perturbation, list[Item], list[str]]:
    """The cell's assumptions (and the defaults) as a :class:`Perturbation` of the built problem.

    Returns ``(perturbation, items, notes)``; notes say what is held without a stated uncertainty.
    Raises:
        BadInputError: an assumption about something the calibration estimates, or names nothing it uses.
    """
    cell = g.cell
    stated = {(a.thing, "scale" if a.quantity == "square" else a.quantity): a for a in cell.assumptions}
    items: list[Item] = []
    scale, held, prior, log_sigma = [], [], [], []
    notes: list[str] = []
    p = 0

    def add(key, kind, what, advice, size, cov, coords, units, source, text):
        nonlocal p
        items.append(Item(key, kind, what, advice, p, size, np.atleast_2d(np.asarray(cov, np.float64)), coords, units,
                          source, text))
        p += size
        return p - size

    for t in sorted({t for (_, t) in g.pairs}):
        a = stated.pop((t, "scale"), None)
        sigma = DEFAULT_SCALE_SIGMA_REL if a is None else a.sigma_rel
        if not sigma:
            continue
        i = add(a.key if a else f"{t}.square", "scale", f"target '{t}''s printed scale", f"measure the target '{t}'",
                1, [[sigma**2]], ["scale"], [""], "default" if a is None else "stated", f"{sigma:.3%} of its size")
        scale += [(gr.name, i) for gr in built.groups if gr.kind in CORNER_KINDS and gr.key[1] == t]
    for (thing, quantity), a in list(stated.items()):
        if quantity == "scale":
            raise _fail(cell, a, f"no camera sees target '{thing}' in these observations")
        if quantity == "intrinsics":
            coords, names, cov, units = _held_intrinsics(cell, a, start, built)
            i = add(a.key, "held", f"camera '{thing}''s held intrinsics", f"calibrate camera '{thing}''s intrinsics "
                    "(or free them)", len(coords), cov, names, units, a.source, _sigma_text(cov, names, units))
            held.append((f"intrinsics:{thing}", 0, tuple(coords), i))
        elif quantity == "pose":
            name = _pose_name(g, cell, a)
            if name not in built.calibrated or built.calibrated[name]:
                raise _fail(cell, a, f"{name} is estimated by this calibration, not held; an assumption states the "
                                     "uncertainty of a held transform (list it in fixed:) or remove it")
            if a.covariance is not None:
                cov = a.covariance
            else:
                r, t = np.radians(a.sigma_deg or 0.0), a.sigma_m or 0.0
                cov = np.diag([r**2] * 3 + [t**2] * 3)
            i = add(a.key, "held", f"the held transform {name}", f"calibrate {name} (or free it)", 6, cov,
                    list(_TANGENT), ["rad"] * 3 + ["m"] * 3, a.source, _sigma_text(cov, list(_TANGENT), ["rad"] * 3 + ["m"] * 3))
            held.append((name, 0, tuple(range(6)), i))
        elif quantity == "kinematics":
            robot = next((r for r in built.kinematics if r == thing or (thing == "robot" and len(built.kinematics) == 1)),
                         None)
            if robot is None:
                raise _fail(cell, a, f"'{thing}' has no kinematics in this calibration (calibrate_kinematics); a robot's "
                                     "nominal kinematics enter only where they are calibrated")
            v = built.problem.variable(f"kinematics:{robot}")
            hold = np.flatnonzero(np.asarray(v.fixed[0], bool))
            if hold.size == 0:
                notes.append(f"assumptions.{a.key}: every kinematic parameter of {g.label(robot)} is estimated; its "
                             "nominal values enter only as the prior (already in the sampling σ)")
                continue
            names = [v.coord_names[j] for j in hold]
            angle = [n.rsplit(".", 1)[-1] in _ANGLE for n in names]
            sig = np.array([np.radians(a.sigma_deg or 0.0) if ang else (a.sigma_m or 0.0) for ang in angle])
            units = ["rad" if ang else "m" for ang in angle]
            i = add(a.key, "held", f"{g.label(robot)}'s nominal kinematics (held parameters)",
                    "measure the robot's geometry or add stations that determine it", hold.size, np.diag(sig**2), names,
                    units, a.source, _sigma_text(np.diag(sig**2), names, units))
            held.append((f"kinematics:{robot}", 0, tuple(int(j) for j in hold), i))
        elif quantity == "noise":
            groups = tuple(gr.name for gr in built.groups if gr.kind == thing)
            if not groups:
                raise _fail(cell, a, f"no measurement of kind '{thing}' in this calibration")
            i = add(a.key, "noise", f"the stated {thing} noise", f"state the {thing} noise from a measurement", 1,
                    [[a.sigma_rel**2]], ["log_sigma"], [""], a.source, f"{a.sigma_rel:.0%} of its value")
            log_sigma.append((groups, i))
    for cam in start.aspects:
        v = f"intrinsics:{cam}"
        if v in {x.name for x in built.problem.variables} and (cam, "intrinsics") not in stated \
                and cell.cameras[cam].K is not None and np.asarray(built.problem.variable(v).fixed).any():
            notes.append(f"camera '{cam}''s held intrinsics are taken as exact (no stated uncertainty): state "
                         f"assumptions: {{{cam}.intrinsics: {{covariance_from: <its result>}}}} to see their cost")
    for name, cal in built.calibrated.items():
        if not cal and name in built.transforms and not any(a.quantity == "pose" and _pose_name(g, cell, a) == name
                                                             for a in cell.assumptions):
            notes.append(f"the held transform {name} is taken as exact (no stated uncertainty): state assumptions: "
                         f"{{{name}.pose: {{sigma_deg: ..., sigma_m: ...}}}} to see its cost")
    pert = Perturbation(size=p, scale_points=tuple(scale), held=tuple(held), prior_mean=tuple(prior),
                        log_sigma=tuple(log_sigma))
    return pert, items, notes


#: Information given to an input that is to stay where it is stated (a noise level, a zero-σ coordinate) when
#: the checks let the stated inputs move within their σ.
HELD_INFORMATION = 1e12


def _prior_information(items: list[Item], size: int) -> np.ndarray:
    """``(p, p)`` information of the stated inputs: the inverse of each assumption's stated covariance
    (:data:`HELD_INFORMATION` for noise levels and zero-variance directions)."""
    P = np.zeros((size, size))
    for it in items:
        sl = slice(it.start, it.start + it.size)
        if it.kind == "noise":
            P[sl, sl] = HELD_INFORMATION * np.eye(it.size)
            continue
        w, U = np.linalg.eigh(0.5 * (it.cov + it.cov.T))
        keep = w > max(float(np.max(w)), 0.0) * 1e-12
        inv = np.where(keep, 1.0 / np.where(keep, w, 1.0), HELD_INFORMATION)
        P[sl, sl] = (U * inv) @ U.T
    return P


def _sigma_text(cov, names, units) -> str:
    sd = np.sqrt(np.maximum(np.diag(np.atleast_2d(cov)), 0.0))
    parts = []
    for n, s, u in zip(names, sd, units):
        if u == "rad":
            parts.append(f"{n} {np.degrees(s):.3g}°")
        elif u == "m":
            parts.append(f"{n} {s * 1e3:.3g} mm")
        else:
            parts.append(f"{n} {s:.3g}{' ' + u if u else ''}")
    return ", ".join(parts[:8]) + (" …" if len(parts) > 8 else "")


def _unknowns(cal, built: Built, start: Start) -> list[tuple[str, str, str, list[str], list[str], np.ndarray, object]]:
    """``(label, kind, variable, coords, units, sampling covariance, row map)`` of every reported unknown."""
    out = []
    for cam, cov in cal.intrinsics_covariance.items():
        names = list(cal.cameras[cam].param_names)
        flag, ratio = start.aspects[cam]

        def rows(S, flag=flag, ratio=ratio):
            S = S.copy()
            if flag:
                S[1] = S[0] / ratio
            return S
        out.append((cam, "camera", f"intrinsics:{cam}", names, ["px" if n in _PIXEL else "" for n in names], cov, rows))
    vals = cal.solution.values
    for n in built.transforms:
        tool = n[9:] if n.startswith("T_flange_") else None
        rows = None
        if tool is not None and cal.tool_orientation.get(tool) == "calibrated":
            T = se3_matrix(vals[n][0])
            B = np.kron(np.eye(2), rotation_z_to(T[:3, 2]).T @ T[:3, :3])

            def rows(S, B=B):
                S = B @ S
                S[2] = 0.0
                return S
        out.append((n, "transform", n, list(_TANGENT), ["rad"] * 3 + ["m"] * 3, cal.transform_covariance[n], rows))
    for n, cov in cal.point_covariance.items():
        out.append((n, "point", f"point:{n}", ["x", "y", "z"], ["m"] * 3, cov, None))
    for t, cov in cal.warp_covariance.items():
        out.append((t, "target", f"warp:{t}", ["c0", "c1"], ["m"] * 2, cov, None))
    for r, k in cal.kinematics.items():
        free = np.asarray(k["free"], bool)
        names = [n for n, f in zip(k["model"].param_names, free) if f]
        cov = np.asarray(k["covariance"])[np.ix_(free, free)]

        def rows(S, free=free):
            return S[free]
        out.append((r, "kinematics", f"kinematics:{r}", names,
                    ["rad" if n.rsplit(".", 1)[-1] in _ANGLE else "m" for n in names], cov, rows))
    return out


def error_budget(g: Graph, built: Built, start: Start, r, cal) -> dict:
    """The error budget of a calibration (see the module docstring) and its stated-σ checks.

    Args:
        g, built, start: the cell's graph, problem and start; r: the :class:`jcalib.problems.refine.Refined`;
        cal: the assembled :class:`jcalib.problems.assemble.Calibration`.
    Returns:
        ``{"assumptions": [...], "unknowns": {label: {...}}, "sensitivities": {key: {...}}, "checks": [...],
        "notes": [...]}`` (NumPy arrays; :func:`jcalib.problems.budget_file.attach` writes them).
    """
    pert, items, notes = resolve(g, built, start)
    sens = sensitivities(r.sol, pert, prior_information=_prior_information(items, pert.size)) if pert.size else None
    if sens is not None and not (all(np.all(np.isfinite(d)) for d in sens.dx.values())
                                 and np.all(np.isfinite(sens.information)) and np.all(np.isfinite(sens.score))):
        notes.append("the error budget could not be computed (non-finite sensitivities at the estimate); every σ "
                     "is sampling noise only")
        pert, items, sens = Perturbation(size=0), [], None
    unknowns, sensit = {}, {it.key: {"what": it.what, "columns": it.coords, "units": it.units, "of": {}} for it in items}
    for label, kind, var, coords, units, cov, rows in _unknowns(cal, built, start):
        cov = np.asarray(cov, np.float64)
        S_all = np.zeros((len(coords), pert.size))
        if sens is not None and var in sens.dx:
            S_all = np.array(sens.dx[var][0])
            for hv, _, hc, i in pert.held:  # a held input is its own first-order effect on the reported value
                if hv == var:
                    S_all[list(hc), i:i + len(hc)] += np.eye(len(hc))
            S_all = rows(S_all) if rows is not None else S_all
        combined = cov.copy()
        contrib = {}
        for it in items:
            S = S_all[:, it.start:it.start + it.size]
            C = S @ it.cov @ S.T
            combined = combined + C
            contrib[it.key] = np.sqrt(np.maximum(np.diag(C), 0.0))
            sensit[it.key]["of"][label] = {"coords": coords, "jacobian": S}
        unknowns[label] = {"kind": kind, "coords": coords, "units": units,
                           "sampling": np.sqrt(np.maximum(np.diag(cov), 0.0)), "contributions": contrib,
                           "combined": np.sqrt(np.maximum(np.diag(combined), 0.0)),
                           "covariance_combined": 0.5 * (combined + combined.T)}
    checks = assumption_checks(g, built, r, cal, items, sens)
    assumptions = [{"key": it.key, "what": it.what, "sigma": it.sigma_text, "source": it.source,
                    "columns": it.coords, "units": it.units, "advice": it.advice} for it in items]
    return {"assumptions": assumptions, "unknowns": unknowns, "sensitivities": sensit, "checks": checks,
            "notes": notes}
