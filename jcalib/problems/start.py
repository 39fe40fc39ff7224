"""Closed-form start of a cell: intrinsics, per-view poses, then every pose the graph connects.

Order (chosen from the graph, not from the kind of cell):

1. **Intrinsics** per camera: the cell's ``intrinsics``, else a previous result's, else Zhang on the
   camera's views of targets that move in its image; per-view target poses by Zhang or planar PnP
   (6-DOF pose measurements are views as they are).
2. **Poses**, repeated until nothing changes: a pose that follows from a started one through a
   camera–target pair (averaged over the pair's stations; free targets get their per-station poses
   this way); a closed-form hand-eye solve (:func:`jcalib.init.handeye.solve_hand_eye`, after its
   motion check names what degenerate motion leaves undetermined) for a moving pair whose two poses
   are unknown; a closed-form robot-world solve (AX = ZB, Shah) for a robot whose base is unknown.
3. Tools and cell points: :mod:`jcalib.problems.tools`.

Everything here is NumPy on the host; the solve refines it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from jcalib.errors import BadInputError, NotObservableError
from jcalib.geometry.cameras import AbstractCameraModel, camera_model_from_name
from jcalib.geometry.cameras.splined import fov_covering
from jcalib.geometry.se3 import invert, make_pose, rotvec
from jcalib.init import planar_pnp, zhang_init
from jcalib.init.fisheye import bearing_pose, fisheye_bearings, fisheye_init
from jcalib.init.handeye import HandEyeInit, average_poses, relative_motions, solve_hand_eye
from jcalib.init.handeye_motion import (
    MotionDiagnostics,
    analyse_motion,
    check_observable,
    fmt_axis,
    solution_diagnostics,
)
from jcalib.init.robot_world import solve_robot_world_hand_eye
from jcalib.problems.graph import FREE, Graph
from jcalib.problems.lens import start_lens


@dataclass
class Start:
    """The start of a cell's solve (NumPy, m).

    Attributes:
        models: camera -> start model; ``fixed_masks``: camera -> intrinsics held fixed;
            ``aspects``: camera -> ``(flag, ratio)`` of a fixed aspect ratio (``fy = fx / ratio``).
        views: ``(camera, target)`` -> station index -> ``T_cam_target`` start (4, 4).
        known: transform name -> (4, 4): every started pose on its holder and every robot base.
        how: transform name -> how it started (``"cell"``, ``"prior"``, ``"gauge"``,
            ``"hand_eye:<method>"``, ``"from:<...>"``, ``"robot_world:shah"``, ``"contacts"``,
            ``"tip_rays"``...).
        free: free target -> station index -> ``T_<frame>_<target>`` start.
        points: cell point -> (3,) start in the cell frame.
        motions: hand-eye transform -> the motion analysis of its stations.
        inits: hand-eye transform -> its closed-form :class:`jcalib.init.handeye.HandEyeInit`.
        tool_axes: tool -> whether its orientation (the tilt of its z axis) is estimated.
        warnings: what the user should know (weak motion, what was held at a prior).
        unobservable_fixed: ``{"transform", "axis", "frame", "value_m", "sigma_m"}`` when a hand-eye
            translation along the common rotation axis is held at a prior (``fix_unobservable``).
        lenses: camera -> :class:`jcalib.problems.lens.LensStart` of the cameras with a zoom lens (their
            ``models`` entry is the camera at the lowest calibrated setting).
    """

    models: dict[str, AbstractCameraModel] = field(default_factory=dict)
    fixed_masks: dict[str, np.ndarray] = field(default_factory=dict)
    aspects: dict[str, tuple[float, float]] = field(default_factory=dict)
    views: dict[tuple[str, str], dict[int, np.ndarray]] = field(default_factory=dict)
    known: dict[str, np.ndarray] = field(default_factory=dict)
    how: dict[str, str] = field(default_factory=dict)
    free: dict[str, dict[int, np.ndarray]] = field(default_factory=dict)
    points: dict[str, np.ndarray] = field(default_factory=dict)
    motions: dict[str, MotionDiagnostics] = field(default_factory=dict)
    inits: dict[str, HandEyeInit] = field(default_factory=dict)
    tool_axes: dict[str, bool] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    unobservable_fixed: dict | None = None
    lenses: dict = field(default_factory=dict)


# ------------------------------------------------------------------------------------ intrinsics


def intrinsics_fixed_mask(model: AbstractCameraModel, fix) -> np.ndarray:
    """``(p,)`` bool: the model's parameters named in ``fix`` (``aspect`` holds ``fy``)."""
    names = model.param_names
    unknown = sorted(set(fix) - set(names) - {"aspect"})
    if unknown:
        raise BadInputError(f"fix: unknown intrinsic names {unknown} for model '{model.name}'; "
                            f"allowed: {', '.join(names)}, aspect")
    mask = np.array([n in fix for n in names])
    if "aspect" in fix:
        mask[names.index("fy")] = True
    if "fov_x_deg" in names:  # a splined model's extent is configuration, set by the start
        mask[names.index("fov_x_deg")] = True
    return mask


@functools.lru_cache(maxsize=32)
def _template(model_name: str, image_size: tuple, skew: bool) -> AbstractCameraModel:
    """The model with its default parameters (immutable: made once per model, size and skew)."""
    return camera_model_from_name(model_name, image_size, skew=skew)


def initial_model(name: str, model_name: str, image_size, skew: bool, fix, K0, dist0,
                  points: list[np.ndarray], pixels: list[np.ndarray]) -> tuple[AbstractCameraModel, list[np.ndarray]]:
    """Start intrinsics (``K0``/``dist0`` when given, else Zhang) and one target pose per view.

    Args:
        points: per view ``(n, 3)`` target points (planar, z = 0, when Zhang runs); pixels: ``(n, 2)``.
    Returns:
        ``(model, [T_cam_target (4, 4) per view])``.
    """
    zhang_poses = None
    if K0 is not None:
        K, dist_given = np.asarray(K0, np.float64), (np.asarray(dist0) if dist0 is not None else np.zeros(0))
    else:
        if not all(np.all(np.abs(p[:, 2]) <= 1e-8) for p in points):
            raise BadInputError(f"camera '{name}': its target is not planar (z != 0); starting the intrinsics needs a "
                                "planar target, or give intrinsics: {K: [[3x3]], dist: [...]} in the cell")
        principal_point = None
        if "cx" in fix and "cy" in fix:
            principal_point = ((image_size[0] - 1) / 2, (image_size[1] - 1) / 2)
        view_names = [f"{name} view {i}" for i in range(len(points))]
        if model_name in ("fisheye", "splined"):
            # Zhang's pinhole homographies do not exist through a fisheye: its own closed form (the
            # equidistant lens, fx = fy, k1..k4 = 0) and the view poses that go with it (a splined
            # model, meant for wide-angle lenses, starts the same way: near the axis its stereographic
            # core and the equidistant lens agree).
            try:
                fe = fisheye_init([p[:, :2] for p in points], pixels, image_size, principal_point=principal_point,
                                  view_names=view_names)
            except NotObservableError as err:
                raise NotObservableError(f"camera '{name}': {err}", [f"{name} {u}" for u in err.unknowns]) from None
            K, dist_given, zhang_poses = fe.K, np.zeros(0), fe.T_cam_target
        else:
            # Cheap Zhang (single pass on the raw homographies): the joint solve does the distortion,
            # and the re-seed check catches a view that starts in the flipped minimum.
            z = zhang_init([p[:, :2] for p in points], pixels, skew=skew,
                           aspect_ratio=1.0 if "aspect" in fix else None, principal_point=principal_point,
                           image_size=image_size, estimate_distortion=False, distortion_iterations=0,
                           refine_homographies=False, view_names=view_names)
            K, dist_given, zhang_poses = z.K, np.zeros(0), z.T_cam_target
    template = _template(model_name, tuple(image_size), bool(skew))
    names = template.param_names
    values = dict(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2])
    if skew:
        values["skew" if "skew" in names else "alpha"] = K[0, 1] if "skew" in names else K[0, 1] / K[0, 0]
    dist_names = [n for n in names if n not in ("fx", "fy", "cx", "cy", "skew", "alpha")]
    for n, value in zip(dist_names, dist_given):
        values[n] = value
    if model_name == "splined" and not len(dist_given):  # the spline's extent covers the image, from the start
        values["fov_x_deg"] = fov_covering((K[0, 0], K[1, 1]), (K[0, 2], K[1, 2]), image_size)
    model = template.with_params(np.array([values.get(n, 0.0) for n in names], np.float64))
    if zhang_poses is not None:  # (the fisheye's and splined model's start poses are the fisheye closed form's)
        return model, list(zhang_poses)
    return model, pnp_poses(model, points, pixels)


def rays(model: AbstractCameraModel, pixels: np.ndarray) -> np.ndarray:
    """``(n, 3)`` viewing directions ``(x, y, 1)`` of pixels in the camera frame, by OpenCV's
    undistortion (a start needs no more, and it compiles nothing); for the fisheye unit bearing
    vectors instead (:func:`jcalib.init.fisheye.fisheye_bearings`): its rays reach 90° from the axis
    and beyond, where ``(x, y, 1)`` does not exist and ``cv2.fisheye.undistortPoints`` clamps them."""
    import cv2

    if model.name == "splined":  # not an OpenCV model: its own unprojection
        d = np.asarray(model.unproject(np.asarray(pixels, np.float64).reshape(-1, 2)))
        return d / d[:, 2:3]
    K, dist = model.to_opencv()
    if model.name == "fisheye":
        return fisheye_bearings(K, dist, pixels)[0]
    pix = np.asarray(pixels, np.float64).reshape(-1, 1, 2)
    xy = cv2.undistortPointsIter(pix, K, dist if dist.size else None, None, None,
                                 (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12))
    xy = xy.reshape(-1, 2)
    return np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)


#: A fisheye view's planar PnP uses its points within this angle of the optical axis (their
#: ``(x/z, y/z)`` stay well conditioned); a view with fewer than 6 of them starts from all its bearings.
FISHEYE_PNP_MAX_ANGLE_DEG = 75.0


def pnp_poses(model: AbstractCameraModel, points: list[np.ndarray], pixels: list[np.ndarray], second: bool = False):
    """Planar PnP of every view with ``model`` (the better candidate, or the other one)."""
    out = []
    if model.name == "fisheye":
        cos_max = np.cos(np.radians(FISHEYE_PNP_MAX_ANGLE_DEG))
        for pts, pix in zip(points, pixels):
            pts, b = np.asarray(pts, np.float64), rays(model, pix)
            near = b[:, 2] > cos_max
            xy = pts[near, :2]
            spread = np.linalg.svd(xy - xy.mean(axis=0), compute_uv=False) if len(xy) >= 6 else (0.0, 0.0)
            if spread[1] > 1e-6 * spread[0]:
                out.append(planar_pnp(pts[near], b[near, :2] / b[near, 2:], np.eye(3)).T_cam_target[int(second)])
            else:  # a view at the rim: the pose of its bearing homography (one candidate)
                out.append(bearing_pose(pts[:, :2], b))
        return out
    if model.name == "splined":
        for pts, pix in zip(points, pixels):
            out.append(planar_pnp(pts, rays(model, pix)[:, :2], np.eye(3)).T_cam_target[int(second)])
        return out
    K_cv, dist_cv = (np.asarray(a, np.float64) for a in model.to_opencv())
    for pts, pix in zip(points, pixels):
        out.append(planar_pnp(pts, pix, K_cv, dist_cv if dist_cv.size else None).T_cam_target[int(second)])
    return out


def start_intrinsics(g: Graph, start: Start, seed=None) -> None:
    """Fill ``start.models``, ``fixed_masks``, ``aspects`` and ``views`` (see :class:`Start`)."""
    cell = g.cell
    for cam in cell.cameras.values():
        if cam.name in cell.sensors:
            continue  # a pose sensor: no lens
        cam_pairs = [p for (c, _), p in g.pairs.items() if c == cam.name]
        if not cam_pairs and not any(c == cam.name for (c, _) in g.tips) and any(c == cam.name for (c, _) in g.poses):
            continue  # a pose sensor only (6-DOF measurements): no lens to calibrate
        if cam.lens is not None:  # a zoom lens: one start per setting, then its functions
            model, mask, ls, views = start_lens(g, cam, cam_pairs, initial_model, intrinsics_fixed_mask)
            start.models[cam.name], start.fixed_masks[cam.name], start.aspects[cam.name] = model, mask, (0.0, 1.0)
            start.lenses[cam.name] = ls
            start.views.update(views)
            continue
        K0, dist0 = cam.K, cam.dist
        if K0 is None and seed is not None and cam.name in seed.cameras and seed.cameras[cam.name].model == cam.model:
            K0, dist0 = np.asarray(seed.cameras[cam.name].K), np.asarray(seed.cameras[cam.name].dist)
        moving = [p for p in cam_pairs if g.moving(p.camera, p.target)]
        use = cam_pairs if K0 is not None else moving
        if K0 is None and not moving:
            if not cam_pairs and not any(c == cam.name for (c, _) in g.tips) and not g.has_robot:
                g.check_views(cam.name)
            raise BadInputError(
                f"{cell.source}: camera '{cam.name}' (mount {cam.mount}) sees no moving target, so its views do not "
                "determine its intrinsics on their own; give intrinsics: {K: [[3x3]], dist: [...]} in the cell "
                "(e.g. from a camera calibration) or pass a previous result as the prior")
        points = [pt for p in use for pt in p.points]
        pixels = [px for p in use for px in p.pixels]
        if points:
            model, poses = initial_model(cam.name, cam.model, g.obs.cameras[cam.name], cam.skew, cam.fix, K0, dist0,
                                         points, pixels)
        else:  # only tool tips: the given intrinsics
            model, poses = initial_model(cam.name, cam.model, g.obs.cameras[cam.name], cam.skew, cam.fix, K0, dist0,
                                         [], [])
        mask = intrinsics_fixed_mask(model, cam.fix)
        ratio = float(K0[0, 0] / K0[1, 1]) if K0 is not None else 1.0
        flag = 1.0 if "aspect" in cam.fix else 0.0
        if flag:
            prm = np.asarray(model.params).copy()
            prm[1] = prm[0] / ratio
            model = model.with_params(prm)
        start.models[cam.name], start.fixed_masks[cam.name], start.aspects[cam.name] = model, mask, (flag, ratio)
        i = 0
        for p in use:
            start.views[(cam.name, p.target)] = dict(zip(p.views, poses[i:i + len(p.views)]))
            i += len(p.views)
        for p in cam_pairs:  # static pairs of a camera started by Zhang: PnP with the start model
            if (cam.name, p.target) not in start.views:
                start.views[(cam.name, p.target)] = dict(zip(p.views, pnp_poses(model, p.points, p.pixels)))
    for key, pm in g.poses.items():
        start.views.setdefault(key, {}).update({k: T for k, T in zip(pm.stations, pm.T_cam_target)
                                                if k not in start.views.get(key, {})})


# ------------------------------------------------------------------------------------ poses


class _Poses:
    """The pose propagation of :func:`start_poses` (state: ``start.known``, ``start.free``)."""

    def __init__(self, g: Graph, start: Start, method: str, rot_noise: float, fix_unobservable, prior_m, prior_sigma):
        self.g, self.s = g, start
        self.method, self.rot_noise = method, rot_noise
        self.fix_unobservable, self.prior_m, self.prior_sigma = fix_unobservable, prior_m, prior_sigma
        self.pairs = sorted(list(g.pairs) + [k for k in g.poses if k not in g.pairs],
                            key=lambda key: -len(start.views.get(key, {})))

    # where things are
    def info(self, key):
        c, t = key
        cs, ts = self.g.cell.cameras[c], self.g.cell.targets[t]
        return self.g.mount_name(cs), self.g.mount_name(ts), self.g.holder(cs), self.g.holder(ts)

    def base_known(self, h) -> bool:
        return h is None or h == FREE or self.g.base_name(h) is None or self.g.base_name(h) in self.s.known

    def holder_pose(self, h, ks):
        """``(n, 4, 4)`` cell-frame pose of robot holder ``h``'s flange at stations ``ks`` (None: fixed)."""
        if h is None:
            return None
        b = self.g.base_name(h)
        F = self.g.flange[h][ks]
        return F if b is None else self.s.known[b] @ F

    def world(self, name, h, thing, ks):
        """``(n, 4, 4)`` cell-frame pose of a thing at stations ``ks``, or None when not started there."""
        if h == FREE:
            poses = self.s.free.get(thing, {})
            return np.stack([poses[k] for k in ks]) if all(k in poses for k in ks) else None
        if name not in self.s.known or not self.base_known(h):
            return None
        W = self.holder_pose(h, ks)
        return np.broadcast_to(self.s.known[name], (len(ks), 4, 4)) if W is None else W @ self.s.known[name]

    def offset(self, T_world, h, ks):
        """A thing's pose on its holder from its cell-frame poses at stations ``ks`` (averaged)."""
        W = self.holder_pose(h, ks)
        return average_poses(T_world if W is None else np.linalg.inv(W) @ T_world)

    def derive(self, key) -> bool:
        s, (c, t) = self.s, key
        X, Y, hc, ht = self.info(key)
        views = s.views[key]
        ks = np.asarray(sorted(views))
        T_ct = np.stack([views[k] for k in ks])
        if hc == ht and hc != FREE:  # static pair: the relative pose alone, whatever the holder's base
            if X in s.known and Y not in s.known:
                s.known[Y], s.how[Y] = average_poses(s.known[X] @ T_ct), f"from:{X}+{c}/{t}"
                return True
            if Y in s.known and X not in s.known:
                s.known[X], s.how[X] = average_poses(s.known[Y] @ np.linalg.inv(T_ct)), f"from:{Y}+{c}/{t}"
                return True
            return False
        if ht == FREE:
            Wc = self.world(X, hc, c, ks)
            if Wc is not None:
                poses = s.free.setdefault(t, {})
                new = [k for k in ks if k not in poses]
                for i, k in enumerate(ks):
                    if k not in poses:
                        poses[k] = Wc[i] @ T_ct[i]
                return bool(new)
            have = [i for i, k in enumerate(ks) if k in s.free.get(t, {})]
            if X is not None and X not in s.known and have and self.base_known(hc):
                Wt = np.stack([s.free[t][ks[i]] for i in have])
                s.known[X] = self.offset(Wt @ np.linalg.inv(T_ct[have]), hc, ks[have])
                s.how[X] = f"from:{t}+{c}/{t}"
                return True
            return False
        Wc, Wt = self.world(X, hc, c, ks), self.world(Y, ht, t, ks)
        if Wc is not None and Wt is None and Y not in s.known and self.base_known(ht):
            s.known[Y], s.how[Y] = self.offset(Wc @ T_ct, ht, ks), f"from:{X}+{c}/{t}"
            return True
        if Wt is not None and Wc is None and X not in s.known and self.base_known(hc):
            s.known[X], s.how[X] = self.offset(Wt @ np.linalg.inv(T_ct), hc, ks), f"from:{Y}+{c}/{t}"
            return True
        if X in s.known and Y in s.known and (not self.base_known(hc)) != (not self.base_known(ht)):
            # both things started, one robot's base unknown: B = W_other · T · F⁻¹ · thing⁻¹
            h = hc if not self.base_known(hc) else ht
            if h == hc:
                Wt = self.world(Y, ht, t, ks)
                B = average_poses(Wt @ np.linalg.inv(T_ct) @ np.linalg.inv(s.known[X]) @ np.linalg.inv(self.g.flange[h][ks]))
            else:
                Wc = self.world(X, hc, c, ks)
                B = average_poses(Wc @ T_ct @ np.linalg.inv(s.known[Y]) @ np.linalg.inv(self.g.flange[h][ks]))
            name = self.g.base_name(h)
            s.known[name], s.how[name] = B, f"from:{X}+{Y}+{c}/{t}"
            return True
        return False

    def hand_eye(self) -> bool:
        """One closed-form hand-eye solve for a moving pair whose two poses are unknown."""
        s = self.s
        todo = []
        for key in self.pairs:
            X, Y, hc, ht = self.info(key)
            if hc != ht and FREE not in (hc, ht) and X not in s.known and Y not in s.known \
                    and self.base_known(hc) and self.base_known(ht):
                todo.append(key)
        if not todo:
            return False
        first_error = None
        for key in todo:
            X, Y, hc, ht = self.info(key)
            ks = np.asarray(sorted(s.views[key]))
            T_ct = np.stack([s.views[key][k] for k in ks])
            if ht is None:  # camera on a flange, target fixed: eye-in-hand
                H, mount = self.holder_pose(hc, ks), "flange"
            elif hc is None:  # camera fixed, target on a flange: eye-to-hand
                H, mount = self.holder_pose(ht, ks), "base"
            else:  # camera on one robot, target on another: the camera's flange in the target's flange
                H, mount = np.linalg.inv(self.holder_pose(ht, ks)) @ self.holder_pose(hc, ks), "flange"
            motion = analyse_motion(H, frame=mount, rotation_noise_deg=self.rot_noise)
            s.motions[X] = motion
            try:
                check_observable(motion, X)
            except NotObservableError as err:
                first_error = first_error or (err, key, H, T_ct, mount, motion)
                continue
            init = solve_hand_eye(H, T_ct, method=self.method, mount=mount, rotation_noise_deg=self.rot_noise)
            self._accept(key, init, motion)
            return True
        err, key, H, T_ct, mount, motion = first_error
        if self.fix_unobservable and motion.rank == 1 and motion.num_stations >= 3:
            X, Y, _, _ = self.info(key)
            init = one_axis_init(H, T_ct, mount, motion, self.prior_m)
            self._accept(key, init, motion)
            axis = np.asarray(motion.dominant_axis, np.float64)
            why = "planar (SCARA-like) motion, every rotation about the base z" if motion.planar else "one-axis rotations"
            s.unobservable_fixed = {"transform": X, "axis": axis.tolist(), "frame": mount,
                                    "value_m": float(self.prior_m), "sigma_m": float(self.prior_sigma)}
            s.warnings.append(
                f"{why}: the translation of {X} along the common rotation axis (axis = {fmt_axis(axis)} in the "
                f"{mount} frame) is not observable from these stations; it is held at the stated prior "
                f"{self.prior_m:g} m ± {self.prior_sigma:g} m (fix_unobservable), and {Y} shifts with it. Everything "
                "else is estimated from the data.")
            return True
        raise err

    def _accept(self, key, init: HandEyeInit, motion: MotionDiagnostics) -> None:
        X, Y, _, _ = self.info(key)
        self.s.known[X], self.s.known[Y] = init.T, init.T_other
        self.s.how[X] = self.s.how[Y] = f"hand_eye:{init.method}"
        self.s.inits[X] = init
        prefix = f"{key[0]}: " if len({k[0] for k in self.pairs}) > 1 else ""
        self.s.warnings += [prefix + w for w in motion.warnings]

    def robot_world(self) -> bool:
        """A robot with an unknown base whose flange thing pairs with something started: AX = ZB."""
        s, g = self.s, self.g
        for key in self.pairs:
            X, Y, hc, ht = self.info(key)
            if hc == ht or FREE in (hc, ht):
                continue
            for P, hP, thP, Q, hQ, cam_is_P in ((X, hc, key[0], Y, ht, True), (Y, ht, key[1], X, hc, False)):
                if P in s.known and self.base_known(hP) and Q not in s.known and not self.base_known(hQ):
                    ks = np.asarray(sorted(s.views[key]))
                    T_ct = np.stack([s.views[key][k] for k in ks])
                    W_Q = self.world(P, hP, thP, ks) @ (T_ct if cam_is_P else np.linalg.inv(T_ct))
                    base = g.base_name(hQ)
                    try:
                        init = solve_robot_world_hand_eye(g.flange[hQ][ks], np.linalg.inv(W_Q), method="shah",
                                                          mount="flange", rotation_noise_deg=self.rot_noise)
                    except NotObservableError as err:
                        raise NotObservableError(f"{g.cell.source}: {g.label(hQ)}'s base ({base}) and {Q} from the "
                                                 f"pair {key[0]}/{key[1]}: {err}", [base, Q]) from None
                    s.known[Q], s.known[base] = init.T, invert(init.T_other)
                    s.how[Q] = s.how[base] = "robot_world:shah"
                    return True
        return False


def start_poses(g: Graph, start: Start, *, method: str, rot_noise: float, fix_unobservable: bool = False,
                prior_m: float = 0.0, prior_sigma_m: float = 1e-6, tool_robots=frozenset()) -> None:
    """Fill ``start.known`` (every camera and target pose on its holder, every robot base) and
    ``start.free`` (free targets per station) from what is known and the pairs; see the module docstring.

    Raises:
        NotObservableError: a pose nothing determines, degenerate hand-eye motion (naming the
            undetermined part), a robot base not connected to the world frame.
    """
    walk = _Poses(g, start, method, rot_noise, fix_unobservable, prior_m, prior_sigma_m)
    while True:
        while any(walk.derive(key) for key in walk.pairs):
            pass
        if walk.hand_eye() or walk.robot_world():
            continue
        break
    missing = sorted({n for key in walk.pairs for n in walk.info(key)[:2] if n is not None and n not in start.known})
    bases = [r for r in g.used_robots if g.base_name(r) is not None and g.base_name(r) not in start.known]
    if bases:
        _unconnected_base(g, bases[0], missing, bases[0] in tool_robots)
    if missing:
        raise NotObservableError(
            f"{g.cell.source}: the poses {missing} are not determined: their cameras and targets are seen only "
            "together, without a robot motion between them or a known pose; give one of them a pose: [[4x4]] "
            "in the cell", missing)
    for t in g.free_things():
        seen = sorted({k for (c, tt), v in start.views.items() if tt == t for k in v})
        lost = [g.station_ids[k] for k in seen if k not in start.free.get(t, {})]
        if lost:
            raise NotObservableError(
                f"target '{t}' at stations {lost[:5]}{'...' if len(lost) > 5 else ''} is seen only by cameras whose "
                "pose is not determined: those views connect to nothing", [f"{g.free_name(t)} at {lost[0]}"])


def _unconnected_base(g: Graph, r: str, missing, has_tools: bool):
    """Raise the NotObservableError for robot ``r`` whose base the start could not place."""
    base = g.base_name(r)
    gauge, anchors = g.gauge()
    frame = (f"the world frame is robot '{gauge}''s base (nothing in the cell holds a world pose)" if gauge
             else f"the world frame is fixed by {', '.join(anchors)}")
    linked = [f"{c}/{t}" for (c, t) in g.pairs
              if r in (g.holder(g.cell.cameras[c]), g.holder(g.cell.targets[t]))
              and g.holder(g.cell.cameras[c]) != g.holder(g.cell.targets[t])]
    src = g.cell.source
    if not linked and has_tools:
        raise NotObservableError(
            f"{src}: robot {r}'s base ({base}) cannot be started: {r} is linked to the world frame only "
            f"through tool tips or contacts ({frame}), which do not give a closed-form start for a base. Let a "
            f"camera see a target on {r} (or a camera on {r} see a target off it), or give robots.{r}.base", [base])
    if not linked:
        raise NotObservableError(
            f"{src}: robot {r}'s base ({base}) is not connected to the world frame: no camera or target on "
            f"{r} is seen together with the world or another robot ({frame}). Let a camera fixed in the world or "
            f"on another robot see a target on {r} (or a camera on {r} see a target off it), or give robots.{r}.base "
            f"and list {base} in fixed", [base])
    raise NotObservableError(
        f"{src}: robot {r}'s base ({base}) cannot be started: the pairs that link it ({', '.join(linked)}) "
        f"involve only things whose poses are not determined either ({', '.join(missing) or 'none'}; {frame}). "
        f"Give a known pose to one of them (pose: [[4x4]] listed in fixed) or robots.{r}.base", [base] + missing)


def rotation_between(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``b`` to unit vector ``a`` (3, 3)."""
    v = np.cross(b, a)
    c = float(b @ a)
    if c < -1.0 + 1e-12:  # opposite: half a turn about any axis perpendicular to b
        p = np.cross(b, np.eye(3)[int(np.argmin(np.abs(b)))])
        p /= np.linalg.norm(p)
        return 2.0 * np.outer(p, p) - np.eye(3)
    V = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + V + V @ V / (1.0 + c)


def one_axis_init(T_bf, T_ct, mount: str, motion: MotionDiagnostics, along_m: float) -> HandEyeInit:
    """Closed-form start when every rotation is about one axis ``a`` (``motion.dominant_axis``).

    ``A X = X B`` then fixes the rotation of ``X`` up to an angle ``φ`` about ``a`` (the axis of
    ``B`` maps to ``a``), and the translation equations ``(R_A − I) t = R_X t_B − t_A`` are linear in
    ``(cos φ, sin φ)`` and the two components of ``t`` across ``a``; the component along ``a`` is
    in the null space of every ``R_A − I`` and is set to ``along_m``.
    """
    Hg = T_bf if mount == "flange" else np.linalg.inv(T_bf)
    A, B, _ = relative_motions(Hg, T_ct)
    rA, rB = rotvec(A[:, :3, :3]), rotvec(B[:, :3, :3])
    a = np.asarray(motion.dominant_axis, np.float64)
    a = a / np.linalg.norm(a)
    _, _, vt = np.linalg.svd(rB, full_matrices=False)
    b = vt[0] if np.sum(rB @ vt[0]) * np.sum(rA @ a) >= 0.0 else -vt[0]
    R0 = rotation_between(b, a)
    P = np.linalg.svd(np.eye(3) - np.outer(a, a))[0][:, :2]  # (3, 2) basis across the axis
    u = B[:, :3, 3] @ R0.T  # R0 t_B
    au = u @ a
    RmI = A[:, :3, :3] - np.eye(3)
    M = np.concatenate([RmI @ P, -(u - au[:, None] * a)[..., None], -np.cross(a, u)[..., None]], axis=-1)
    rhs = -A[:, :3, 3] + au[:, None] * a - along_m * (RmI @ a)
    z = np.linalg.lstsq(M.reshape(-1, 4), rhs.reshape(-1), rcond=None)[0]
    phi = float(np.arctan2(z[3], z[2]))
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    R_X = (np.eye(3) + np.sin(phi) * K + (1.0 - np.cos(phi)) * K @ K) @ R0
    rhs = B[:, :3, 3] @ R_X.T - A[:, :3, 3] - along_m * (RmI @ a)  # re-solve t for the rounded rotation
    w = np.linalg.lstsq((RmI @ P).reshape(-1, 2), rhs.reshape(-1), rcond=None)[0]
    X = make_pose(R_X, P @ w + along_m * a)
    per_station = Hg @ X @ T_ct
    Y = average_poses(per_station)
    diagnostics = solution_diagnostics(motion, per_station, Y, A @ X, X @ B)
    return HandEyeInit(T=X, T_other=Y, method="one_axis", mount=mount, diagnostics=diagnostics)
