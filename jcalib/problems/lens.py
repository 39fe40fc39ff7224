"""Zoom (focus) lenses in the one builder: each station's setting, the closed-form start of a lens's
functions, and the lens's part of the result.

A camera whose cell entry has ``lens: {settings: [Zoom]}`` gets one more variable kind,
``lens:<cam>`` (the B-spline control points of its transformed intrinsics and axial shift beyond the
first, :mod:`jcalib.geometry.cameras.zoom`); its ``intrinsics:<cam>`` and its pose on its holder are the
camera at the lowest calibrated setting. Its corners use
:func:`jcalib.residuals.reprojection.zoom_reprojection` with each station's spline basis.

Start: Zhang on each setting's views alone (one intrinsic vector per setting and the view poses that go
with it), then a least-squares fit of the control points through them (shift 0); the hand-eye (or
fixed-camera pose) starts from those view poses as for any camera, and the joint solve does the rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.cameras import zoom

#: Fewest views per captured setting for the start (Zhang needs three views of a planar target).
MIN_VIEWS_PER_SETTING = 3


@dataclass
class LensStart:
    """A lens camera's settings and start (host side).

    Attributes:
        setting: the feature name; range_: ``(lo, hi)`` calibrated range (lowest and highest captured).
        degree, knots: the spline; values: ``(N,)`` the setting at each used station (nan: not recorded).
        basis: ``(N, nb)`` the spline basis at each used station.
        lens: ``((nb − 1)(P + 1),)`` start of ``lens:<cam>``; fixed: its mask.
        per_setting: setting -> ``(P,)`` the per-setting Zhang start (for the report).
    """

    setting: str
    range_: tuple[float, float]
    degree: int
    knots: int
    values: np.ndarray
    basis: np.ndarray
    lens: np.ndarray
    fixed: np.ndarray
    per_setting: dict[float, np.ndarray]


def station_values(g, cam) -> np.ndarray:
    """``(N,)`` the lens setting of camera ``cam`` (a :class:`jcalib.io.cell.CameraSpec` with ``lens``)
    at each used station of graph ``g``; a station where ``cam`` saw something must record it."""
    name = cam.lens.settings[0]
    by_id = {st.id: st for st in g.obs.stations}
    seen = {k for (c, _), p in g.pairs.items() if c == cam.name for k in p.views}
    if any(c == cam.name for (c, _) in list(g.tips) + list(g.poses)):
        raise BadInputError(f"{g.cell.source}: camera '{cam.name}' has a zoom lens (lens:), which jcalib models for "
                            "target corners only; tool tips and pose measurements by it are not supported yet")
    out = np.full(len(g.station_ids), np.nan)
    for k, sid in enumerate(g.station_ids):
        value = by_id[sid].lens.get(cam.name, {}).get(name)
        if value is None and k in seen:
            raise BadInputError(f"{g.obs.source}: station '{sid}': camera '{cam.name}' has a zoom lens (lens: "
                                f"{{settings: [{name}]}} in the cell) but the station does not record its setting; add "
                                f"\"lens\": {{\"{cam.name}\": {{\"{name}\": <value>}}}} to the station")
        if value is not None:
            out[k] = float(value)
    return out


#: Settings closer than this fraction of the captured range, or of the setting's magnitude, are one setting
#: for the start and for counting settings (a camera may read back a commanded setting with a little jitter);
#: each station still uses its own recorded value in the solve.
SETTING_GROUP_FRACTION = 0.005
SETTING_GROUP_RELATIVE = 0.001


def setting_groups(values) -> dict[float, float]:
    """Sorted distinct settings -> the mean of their group (neighbours closer than
    :data:`SETTING_GROUP_FRACTION` of the range or :data:`SETTING_GROUP_RELATIVE` of the largest magnitude
    are one group)."""
    values = sorted(float(v) for v in values)
    if not values:
        return {}
    tol = max(SETTING_GROUP_FRACTION * (values[-1] - values[0]),
              SETTING_GROUP_RELATIVE * max(abs(values[0]), abs(values[-1])))
    groups, current = [], [values[0]]
    for v in values[1:]:
        if v - current[-1] <= tol:
            current.append(v)
        else:
            groups.append(current)
            current = [v]
    groups.append(current)
    return {v: float(np.mean(gr)) for gr in groups for v in gr}


def start_lens(g, cam, cam_pairs, initial_model, fixed_mask_of):
    """The start of a lens camera: ``(model at the lowest setting, mask, LensStart, {(cam, target):
    {station: T_cam_target}})``.

    ``initial_model`` and ``fixed_mask_of`` are :func:`jcalib.problems.start.initial_model` and
    :func:`jcalib.problems.start.intrinsics_fixed_mask` (passed in: this module sits below start).

    Raises:
        NotObservableError: fewer distinct settings than the spline has control points (one setting:
            the functions are not observable), or a setting with too few views for its start.
        BadInputError: a station without its setting, a static or non-moving target.
    """
    spec = cam.lens
    name = spec.settings[0]
    if "aspect" in cam.fix:
        raise BadInputError(f"{g.cell.source}: camera '{cam.name}': fix: [aspect] is not supported with a zoom lens; "
                            "hold fx and fy free (their ratio is estimated at every setting)")
    values = station_values(g, cam)
    moving = [p for p in cam_pairs if g.moving(p.camera, p.target)]
    if len(moving) != len(cam_pairs) or not moving:
        raise BadInputError(f"{g.cell.source}: camera '{cam.name}' has a zoom lens, whose start needs targets that "
                            "move in its image (a hand-eye or fixed-camera cell); a target it holds still is not "
                            "supported")
    seen = sorted({float(values[k]) for p in moving for k in p.views})
    group = setting_groups(seen)  # value -> its group's setting (read-back jitter of one commanded setting)
    used = sorted(set(group.values()))
    nb = zoom.num_control_points(spec.degree, spec.knots)
    what = f"lens:{cam.name}"
    if len(used) < 2:
        raise NotObservableError(
            f"{g.cell.source}: camera '{cam.name}' has a zoom lens (lens: {{settings: [{name}]}}) but every station "
            f"was taken at one {name} setting ({used[0] if used else 'none'}), so its functions of {name} ({what}) are "
            f"not observable; capture stations at several {name} settings (at least {nb}; plan --lens-settings "
            f"{cam.name}.{name}=...), or drop lens: and calibrate the camera at that setting", [what])
    if len(used) < nb:
        raise NotObservableError(
            f"{g.cell.source}: camera '{cam.name}': {len(used)} distinct {name} settings cannot determine its lens "
            f"functions ({what}) with {nb} control points (degree {spec.degree}, knots {spec.knots}); capture at least {nb} "
            "settings or lower lens.degree", [what])
    lo, hi = seen[0], seen[-1]
    u = (values - lo) / (hi - lo)
    per_setting, poses = {}, {}
    for value in used:
        pts, pix, where = [], [], []
        for p in moving:
            for j, k in enumerate(p.views):
                if group[float(values[k])] == value:
                    pts.append(p.points[j])
                    pix.append(p.pixels[j])
                    where.append((p.target, k))
        if len(pts) < MIN_VIEWS_PER_SETTING:
            raise NotObservableError(
                f"camera '{cam.name}' at {name} = {value:g}: {len(pts)} views; starting a zoom lens needs at least "
                f"{MIN_VIEWS_PER_SETTING} views of a moving target at every captured setting", [what])
        model, T = initial_model(f"{cam.name} at {name}={value:g}", cam.model, g.obs.cameras[cam.name], cam.skew,
                                 cam.fix, None, None, pts, pix)
        per_setting[value] = np.asarray(model.params, np.float64)
        for (t, k), T_ct in zip(where, T):
            poses.setdefault((cam.name, t), {})[k] = T_ct
    mask = fixed_mask_of(model, cam.fix)
    P = mask.size
    settings = np.array(used)
    params = np.stack([per_setting[v] for v in used])
    params[:, mask] = params[:, mask].mean(axis=0)  # a held intrinsic is the same at every setting
    ctrl = zoom.fit_control_points((settings - lo) / (hi - lo), params, degree=spec.degree, knots=spec.knots)
    ref = np.asarray(zoom.from_transformed(ctrl[0, :P]))
    fixed = np.tile(np.concatenate([mask, [False]]), (nb - 1, 1))
    start_model = model.with_params(ref)
    ok = np.isfinite(values)
    B = np.zeros((values.size, nb))
    B[ok] = zoom.basis(u[ok], spec.degree, spec.knots)
    ls = LensStart(name, (lo, hi), spec.degree, spec.knots, values, B, ctrl[1:].reshape(-1), fixed.reshape(-1),
                   per_setting)
    return start_model, mask, ls, poses


def lens_result(cam: str, ls: LensStart, model, intrinsics, lens, covariance, mount_name) -> dict:
    """The result-file entry of a lens (``lenses.<cam>`` in ``jcalib.result/1``)."""
    names = list(model.param_names)
    out = {"setting": ls.setting, "range": [float(ls.range_[0]), float(ls.range_[1])],
           "settings_used": sorted(float(v) for v in ls.per_setting),
           "degree": int(ls.degree), "knots": int(ls.knots), "model": model.name,
           "image_size": [int(v) for v in model.image_size], "param_names": names,
           "columns": ["log_fx", "log_fy"] + names[2:] + [zoom.SHIFT],
           "intrinsics": np.asarray(intrinsics, np.float64).tolist(),
           "lens": np.asarray(lens, np.float64).tolist(),
           "control_points": np.asarray(zoom.control_points(np.asarray(intrinsics), np.asarray(lens))).tolist(),
           "mount": mount_name,
           "units": "setting normalised u = (s - lo) / (hi - lo); control points of log fx, log fy (px), the other "
                    "intrinsics and shift_m (m, camera frame along +z); covariance over (intrinsics, lens, mount "
                    "tangent rx..tz)"}
    if covariance is not None:
        out["covariance"] = np.asarray(covariance, np.float64).tolist()
    return out


def lens_function(entry: dict, mount: np.ndarray | None = None) -> zoom.LensFunction:
    """A :class:`jcalib.geometry.cameras.zoom.LensFunction` from a result's ``lenses.<cam>`` entry."""
    try:
        cov = entry.get("covariance")
        return zoom.LensFunction(
            setting=str(entry["setting"]), range_=(float(entry["range"][0]), float(entry["range"][1])),
            degree=int(entry["degree"]), knots=int(entry["knots"]), param_names=tuple(entry["param_names"]),
            intrinsics=np.asarray(entry["intrinsics"], np.float64), lens=np.asarray(entry["lens"], np.float64),
            covariance=None if cov is None else np.asarray(cov, np.float64),
            mount=None if mount is None else np.asarray(mount, np.float64))
    except (KeyError, TypeError, ValueError, IndexError) as err:
        raise BadInputError(f"result: lenses entry is malformed ({err}); it needs setting, range, degree, knots, "
                            "param_names, intrinsics and lens") from None


def parse_at(text: str) -> tuple[str, str, float]:
    """``"cam0.Zoom=350"`` -> ``("cam0", "Zoom", 350.0)``."""
    head, eq, value = str(text).partition("=")
    cam, dot, name = head.partition(".")
    try:
        number = float(value)
    except ValueError:
        number = float("nan")
    if not eq or not dot or not cam or not name or not np.isfinite(number):
        raise BadInputError(f"--at: got {text!r}; expected CAMERA.SETTING=VALUE, e.g. cam0.Zoom=350")
    return cam, name, number


def camera_at(file, camera: str, setting: str, value: float, extrapolate: bool = False):
    """A zoom camera of a result at one setting: ``(CameraResult, mount name or None, TransformResult or
    None)``, with covariances propagated from the lens functions' (first order; sampling noise only, not
    the error of the spline model between the calibrated settings).

    Raises:
        BadInputError: no lens for ``camera`` in the result, another setting name, or (without
            ``extrapolate``) a value outside the calibrated range.
    """
    from jcalib.geometry.cameras import camera_model_from_name
    from jcalib.io.result import CameraResult, TransformResult

    lenses = file.extra.get("lenses") or {}
    if camera not in lenses:
        raise BadInputError(f"result: camera {camera!r} has no lens functions (lenses.{camera}); the result has lens "
                            f"functions for: {', '.join(lenses) or 'no camera'} (a cell camera with lens: gives them)")
    entry = lenses[camera]
    mount = entry.get("mount")
    T = file.transforms[mount].matrix if mount and mount in file.transforms else None
    lf = lens_function(entry, T)
    if setting != lf.setting:
        raise BadInputError(f"--at: camera {camera!r}'s lens depends on {lf.setting}, not {setting!r}; use "
                            f"{camera}.{lf.setting}=VALUE")
    lo, hi = lf.range_
    if not lf.inside(value) and not extrapolate:
        raise BadInputError(f"--at: {camera}.{setting}={value:g} is outside the calibrated range [{lo:g}, {hi:g}] of "
                            f"{setting}; the lens functions are not determined there. Capture stations at that setting "
                            "and calibrate again, or pass --extrapolate to continue the functions' end pieces")
    at = lf.at(value)
    model = camera_model_from_name(entry["model"], tuple(entry["image_size"]), at["params"])
    cam = CameraResult.from_model(model, covariance=at["params_covariance"])
    tr = None
    if T is not None:
        tr = TransformResult(at["mount"], at["mount_covariance"],
                             {"lens_setting": {setting: float(value)}, "shift_m": at["shift_m"]})
    return cam, mount, tr


def file_at(file, at: str, extrapolate: bool = False):
    """The result with a zoom camera at one setting (``"cam0.Zoom=350"``): its ``cameras`` entry and its
    pose on its holder replaced by the ones at that setting (what ``jcalib export --at`` writes)."""
    from dataclasses import replace as dc_replace

    camera, setting, value = parse_at(at)
    cam, mount, tr = camera_at(file, camera, setting, value, extrapolate)
    cameras = {**file.cameras, camera: cam}
    transforms = dict(file.transforms)
    if tr is not None:
        transforms[mount] = tr
    stats = {**file.stats, "lens_setting": {camera: {setting: float(value)}}}
    return dc_replace(file, cameras=cameras, transforms=transforms, stats=stats)
