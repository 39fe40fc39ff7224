"""Closed-form start of tools (TCPs) and cell points, with the checks that name what the data leave free.

- A tool that touches cell points (contacts): the tip in the flange and the untouched-before points
  by linear least squares on ``R_k · tip + t_k = p`` (pivot calibration, the robot 4-point method).
- A tool seen by cameras that do not move with it: the tip lies on the viewing ray of each
  detection, ``P_k (W_k · tip − c_k) = 0`` with ``P_k = I − d_k d_kᵀ`` the projector across the ray
  (:func:`jcalib.init.tcp_analytic.tcp_from_camera_ray` generalised to many rays and cameras). The
  ray system is checked before the solve and what it leaves free is named in words (rotations about
  one axis only, a tip seen along one viewing direction).
- The tool's orientation: its z axis (the tool axis) from the planes through each camera centre and
  imaged axis line, ``n_kᵀ R_k a = 0``; the rotation about the axis itself is not observable for a
  symmetric tool and is held at the convention "smallest rotation taking the flange z to the axis".
  Without axis observations the orientation is the cell's ``orientation``/``axis`` or the identity,
  and it is not calibrated.
- Cell points not given in the spec: the mean touched tip position.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.se3 import make_pose, rotation_z_to
from jcalib.init.pivot import DEFAULT_MIN_ROTATION_DEG, check_rotations, rotation_spread
from jcalib.problems.graph import Graph
from jcalib.problems.start import rays

def _fmt(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{c:.4f}" for c in v) + "]"


def _canonical_sign(v: np.ndarray) -> np.ndarray:
    return v * (1.0 if v[np.argmax(np.abs(v))] > 0 else -1.0)


def given_orientation(tool) -> np.ndarray | None:
    """The orientation a cell states for a tool (``orientation: [[3x3]]`` or ``axis: [x, y, z]``), or None."""
    R = getattr(tool, "orientation", None)
    if R is not None:
        return np.asarray(R, np.float64)
    a = getattr(tool, "axis", None)
    if a is not None:
        a = np.asarray(a, np.float64)
        return rotation_z_to(a / np.linalg.norm(a))
    return None


def contact_start(tool: str, tool_contacts: list, T_bf: np.ndarray, point_start: dict, source: str) -> np.ndarray:
    """The tip ``(3,)`` in the flange frame (and the unknown touched points, into ``point_start``).

    Each contact at station ``k`` says ``R_k · tip + t_k = p``: unknowns ``tip`` (flange frame) and
    every touched point not started yet (cell frame); started points enter as constants.
    """
    unknown = sorted({c.point for c in tool_contacts if c.point not in point_start})
    name = f"T_flange_{tool}"
    if unknown:  # a pivot: the tip along an axis the flange never turns away from stays undetermined
        R = T_bf[np.asarray([k for c in tool_contacts if c.point in unknown for k in c.stations]), :3, :3]
        try:
            check_rotations(R, DEFAULT_MIN_ROTATION_DEG, f"tool '{tool}' touching {unknown}")
        except NotObservableError as err:
            raise NotObservableError(f"{source}: {err} ({name} and the touched points)",
                                     [name] + [f"point:{p}" for p in unknown]) from None
    col = {p: 3 + 3 * i for i, p in enumerate(unknown)}
    rows, rhs = [], []
    for c in tool_contacts:
        for k in c.stations:
            A = np.zeros((3, 3 + 3 * len(unknown)))
            A[:, :3] = T_bf[k, :3, :3]
            b = -T_bf[k, :3, 3]
            if c.point in col:
                A[:, col[c.point]:col[c.point] + 3] = -np.eye(3)
            else:
                b = b + point_start[c.point]
            rows.append(A)
            rhs.append(b)
    A, b = np.concatenate(rows), np.concatenate(rhs)
    sv = np.linalg.svd(A, compute_uv=False)
    if A.shape[0] < A.shape[1] or sv[-1] < 1e-6 * sv[0]:
        raise NotObservableError(
            f"{source}: the contacts of tool '{tool}' do not determine its tip ({name}) and the touched points "
            f"{unknown}: the flange orientations at each point must differ by rotations about at least two axes "
            "(a pivot needs the tool tilted in different directions; the 4-point method four distinct orientations)",
            [name] + [f"point:{p}" for p in unknown])
    x = np.linalg.lstsq(A, b, rcond=None)[0]
    for p in unknown:
        point_start[p] = x[col[p]:col[p] + 3]
    return x[:3]


def _check_rays(M, R, idx_pose, dirs, n_det, free_centre, min_rotation_deg, name) -> None:
    """NotObservableError naming the tip directions the linear ray system leaves free."""
    M = 0.5 * (M + M.T) / max(n_det, 1)
    evals, evecs = np.linalg.eigh(M)
    lim = np.deg2rad(min_rotation_deg)
    weak = np.sqrt(np.maximum(evals, 0.0)) < lim
    if not weak.any():
        return
    spread, axes = rotation_spread(R)
    P = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
    unknowns = []
    for k in np.flatnonzero(weak):
        v = _canonical_sign(evecs[:, k])
        if spread[-1] < lim and free_centre:
            unknowns = [f"{name} offset (all components): the flange does not rotate and the camera position is free"]
            break
        if spread[0] < lim and abs(v @ axes[:, 0]) > np.cos(np.deg2rad(10.0)):
            a = _canonical_sign(axes[:, 0])
            unknowns.append(f"{name} offset along the rotation axis {_fmt(a)} of the flange (all rotations are about "
                            f"one axis{'' if free_centre else ' parallel to the viewing ray'})")
            continue
        across = np.linalg.norm(np.einsum("kab,kbc,c->ka", P, R[idx_pose], v), axis=1)
        if np.max(across) < 0.2:
            unknowns.append(f"{name} offset along the viewing ray (depth), {_fmt(v)} of the flange: fewer than 2 "
                            "distinct views of the tip (it is seen along one direction only)")
            continue
        unknowns.append(f"{name} offset along {_fmt(v)} of the flange"
                        + (" (with a free camera position the image measures no distances: motions that are all "
                           "rotations about one point leave the scale free; add flange translations)" if free_centre
                           else ""))
    raise NotObservableError(
        f"the poses and views do not determine the tool tip of {name} (RMS spread "
        f"{np.rad2deg(np.sqrt(max(evals[0], 0.0))):.3g} deg < {min_rotation_deg} deg about the weakest direction): "
        "not observable: " + "; ".join(unknowns)
        + ". Rotate the flange about two different axes (across the viewing ray) or add a second view.", unknowns)


def tip_ray_start(name: str, tip_views: list, free_centre: bool = False,
                  min_rotation_deg: float = DEFAULT_MIN_ROTATION_DEG) -> np.ndarray:
    """The tip ``(3,)`` in the holder's (flange) frame from the viewing rays of its detections.

    Args:
        tip_views: per camera ``(model, T_frame_cam (4, 4), T_frame_flange (n, 4, 4), pixels (n, 2))``.
        free_centre: the camera positions are unknown too (eliminated from the ray system).
    """
    rows_A, rows_b, Rs, idx, dirs_all, cam_of = [], [], [], [], [], []
    off = 0
    for ci, (model, Tc, Tb, px) in enumerate(tip_views):
        d = rays(model, px) @ Tc[:3, :3].T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        dirs_all.append(d)
        Rs.append(Tb[:, :3, :3])
        idx.append(off + np.arange(len(px)))
        cam_of.append(np.full(len(px), ci))
        off += len(px)
        P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
        rows_A.append(np.einsum("nij,njk->nik", P, Tb[:, :3, :3]))
        rows_b.append(np.einsum("nij,nj->ni", P, Tc[:3, 3][None] - Tb[:, :3, 3]))
    A, b = np.concatenate(rows_A), np.concatenate(rows_b)
    dirs, cams = np.concatenate(dirs_all), np.concatenate(cam_of)
    R = np.concatenate(Rs)
    n_cam = len(tip_views)
    if free_centre:  # unknowns (x, δc_0 .. δc_{C-1}); the centres are eliminated (pseudo-inverse)
        P = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
        full = np.zeros((A.shape[0], 3, 3 + 3 * n_cam))
        full[:, :, :3] = A
        for k, cc in enumerate(cams):
            full[k, :, 3 + 3 * cc: 6 + 3 * cc] = -P[k]
        N = np.einsum("kab,kac->bc", full, full)
        rhs = np.einsum("kab,ka->b", full, b)
        Ncc = np.linalg.pinv(N[3:, 3:], rcond=1e-10)
        M = N[:3, :3] - N[:3, 3:] @ Ncc @ N[3:, :3]
        x = np.linalg.lstsq(N, rhs, rcond=None)[0][:3]
    else:
        M = np.einsum("kab,kac->bc", A, A)
        x = np.linalg.lstsq(M, np.einsum("kab,ka->b", A, b), rcond=None)[0]
    _check_rays(M, R, np.arange(len(dirs)), dirs, len(dirs), free_centre, min_rotation_deg, name)
    return x


def axis_start(name: str, axis_views: list, tip: np.ndarray) -> np.ndarray:
    """The tool axis ``(3,)`` (unit, flange frame, pointing from the flange towards the tip) from the
    planes through each camera centre and imaged axis line.

    Args:
        axis_views: per detection with axis points ``(model, T_frame_cam, T_frame_flange (4, 4),
            tip pixel (2,), axis points (L, 2))``.
    """
    normals, Rs = [], []
    for model, Tc, Tb, tip_px, pts in axis_views:
        px = np.concatenate([tip_px[None], pts])
        d = rays(model, px) @ Tc[:3, :3].T
        # the plane through the camera centre containing every ray of the imaged axis
        _, _, Vt = np.linalg.svd(d)
        normals.append(Vt[-1])
        Rs.append(Tb[:3, :3])
    A = np.einsum("ka,kab->kb", np.stack(normals), np.stack(Rs))
    _, s, Vt = np.linalg.svd(A)
    a = Vt[-1]
    if s.size < 2 or s[-2] < 1e-6 * max(s[0], 1e-300):
        raise NotObservableError(
            f"the imaged tool axis lines do not determine the tool axis direction of {name} (seen in fewer than 2 "
            "sufficiently different orientations)", [f"{name} axis direction (TCP orientation)"])
    if float(a @ tip) < 0.0:  # the axis points from the flange towards the tip
        a = -a
    return a / np.linalg.norm(a)


def _check_in_front(source: str, tool: str, tips: list, views: list, tip: np.ndarray, station_ids) -> None:
    """Raise when the started tip lies behind a camera that sees it (the ray system ignores the sign
    of each ray, so a camera pose that maps the wrong way round would otherwise fit silently)."""
    for t, (model, Tc, Twf, px) in zip(tips, views):
        d = np.asarray(model.unproject(jnp.asarray(px))) @ Tc[:3, :3].T
        depth = np.einsum("na,na->n", d, Twf[:, :3, :3] @ tip + Twf[:, :3, 3] - Tc[:3, 3])
        if np.any(depth <= 0.0):
            k = t.stations[int(np.argmax(depth <= 0.0))]
            raise BadInputError(
                f"{source}: the start puts the tip of tool '{tool}' behind camera '{t.camera}' at station "
                f"'{station_ids[k]}'; check the camera's pose (it maps camera to cell coordinates) and the "
                "tip detections")


def start_tools(g: Graph, start, *, min_rotation_deg: float = DEFAULT_MIN_ROTATION_DEG) -> None:
    """Start every tool's ``T_flange_<tool>`` and every cell point (into ``start.known`` / ``points``).

    A camera whose pose is unknown and that sees no target (its pose is estimated from the tool tips
    alone, e.g. ``calibrate_tcp(free_camera_pose=True)``) has its centre eliminated from the ray system.
    """
    cell = g.cell

    def centre_free(camera: str) -> bool:
        spec = cell.cameras[camera]
        held = spec.name in cell.fixed or g.mount_name(spec) in cell.fixed
        return not held and not any(c == camera for (c, _) in g.pairs)

    for n, pt in cell.points.items():
        if pt.position is not None:
            start.points[n] = np.asarray(pt.position, np.float64)

    def world_flange(r):
        b = g.base_name(r)
        return g.flange[r] if b is None else start.known[b] @ g.flange[r]

    for tool in cell.tools.values():
        name = f"T_flange_{tool.name}"
        tips = [t for (c, tn), t in g.tips.items() if tn == tool.name]
        contacts = [c for (tn, _), c in g.contacts.items() if tn == tool.name]
        R0 = given_orientation(tool)
        has_axis = any(len(a) for t in tips for a in t.axis) and R0 is None and name not in g.cell.fixed
        start.tool_axes[tool.name] = has_axis
        if name in start.known:
            if R0 is not None:
                start.known[name] = make_pose(R0, start.known[name][:3, 3])
            continue
        T_wf = world_flange(g.holder(tool))
        if contacts:
            tip = contact_start(tool.name, contacts, T_wf, start.points, g.obs.source)
            start.how[name] = "contacts"
        elif tips:
            views = []
            for t in tips:
                cam = cell.cameras[t.camera]
                cam_name = g.mount_name(cam)
                if g.holder(cam) is not None:
                    raise NotObservableError(
                        f"{cell.source}: camera '{t.camera}' sees tool '{tool.name}' from a flange; a tool's tip is "
                        "started from cameras fixed in the cell", [name])
                if cam_name not in start.known:
                    raise NotObservableError(
                        f"{cell.source}: camera '{t.camera}' sees tool '{tool.name}' but its pose {cam_name} is not "
                        "determined by the targets; give it a pose or let it see a target", [cam_name])
                ks = np.asarray(t.stations)
                views.append((start.models[t.camera], start.known[cam_name], T_wf[ks], np.stack(t.pixels)))
            tip = tip_ray_start(name, views, free_centre=any(centre_free(t.camera) for t in tips),
                                min_rotation_deg=min_rotation_deg)
            _check_in_front(cell.source, tool.name, tips, views, tip, g.station_ids)
            start.how[name] = "tip_rays"
        else:
            raise NotObservableError(f"{g.obs.source}: tool '{tool.name}' has no tip detections and no contacts; "
                                     f"{name} is undetermined", [name])
        R = R0 if R0 is not None else np.eye(3)
        if has_axis:
            axis_views = []
            for t in tips:
                cam_name = g.mount_name(cell.cameras[t.camera])
                for k, px, pts in zip(t.stations, t.pixels, t.axis):
                    if len(pts):
                        axis_views.append((start.models[t.camera], start.known[cam_name], T_wf[k], px, pts))
            R = rotation_z_to(axis_start(name, axis_views, tip))
        start.known[name] = make_pose(R, tip)
    for point in cell.points:
        if point in start.points:
            continue
        touches = [c for (_, pn), c in g.contacts.items() if pn == point]
        if not touches:
            raise NotObservableError(f"{g.obs.source}: cell point '{point}' is touched in no station (no contacts); its "
                                     "position is undetermined. Touch it with a tool or give its position",
                                     [f"point:{point}"])
        tips_world = []
        for c in touches:
            T_wf = world_flange(g.holder(cell.tools[c.tool]))
            tip = start.known[f"T_flange_{c.tool}"]
            tips_world += [T_wf[k, :3, :3] @ tip[:3, 3] + T_wf[k, :3, 3] for k in c.stations]
        start.points[point] = np.mean(tips_world, axis=0)
