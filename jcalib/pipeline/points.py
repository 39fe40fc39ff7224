"""``jcalib triangulate`` and ``jcalib frame``: named points from pixels, work-object frames from points.

**Input of triangulate** (``jcalib.pixels/1``, JSON): pixels of named points, per station (one robot
pose) and camera. Pixels follow OpenCV (the centre of the top-left pixel is (0, 0)); metres::

    {"schema": "jcalib.pixels/1",
     "sigma_px": 0.3,                                    # optional, pixel noise per coordinate
     "cameras": {"cam1": {"image_size": [1280, 1024]}},  # needed only for intrinsics from the cell
     "stations": [
       {"id": "s0",
        "T_base_flange": [[1, 0, 0, 0.5], [0, 1, 0, 0], [0, 0, 1, 0.8], [0, 0, 0, 1]],
        "pixels": {"cam0": {"p1": [812.4, 600.1], "p2": [850.2, 601.0]},
                   "cam1": {"p1": [402.0, 511.3]}}}]}

``T_base_flange`` is needed at stations where a flange-mounted camera looks, and for the output
frames ``flange`` or a flange-mounted camera / target. A point is triangulated from every
(station, camera) image that names it (at least two).

**Cameras** come from the result (``--result``; intrinsics with their covariance or ``std``,
``T_base_<cam>`` / ``T_flange_<cam>`` with their covariance) or else from the cell spec
(``intrinsics`` and ``pose``, taken as exact). The cell's ``robot.pose_noise`` is the covariance of
every station's ``T_base_flange`` (right perturbation, flange frame). Views that share a camera, a
hand-eye transform or a station share those errors: the points' covariance includes pixel noise,
intrinsics, camera poses and robot poses with all these correlations (linearised; not model error,
and intrinsics and poses of a result are taken as independent of each other).

**Output frame** (``--frame``): ``base`` (default), ``flange`` (RoboCalib's Hand3D), a camera id
(that camera's frame) or a target id (the target's frame, RoboCalib's Phys3D); all but ``base``
refer to one station (``--station``, or the only one).

**Output** (``jcalib.pipeline.points/1``, written atomically)::

    {"schema": "jcalib.pipeline.points/1", "frame": "base", "sigma_px": 0.3,
     "points": {"p1": {"position": [x, y, z], "frame": "base", "covariance": [[3x3]],
                       "std_mm": [sx, sy, sz], "rms_px": 0.21, "num_views": 3, "parallax_deg": 31.0}},
     "joint_covariance": {"points": ["p1", "p2"], "matrix": [[3M x 3M]]},
     "distances": [{"a": "p1", "b": "p2", "distance_m": 0.1, "std_m": 2e-5}],
     "provenance": {...}}

Positions in m, covariances in m² (``position``/``frame``/``covariance`` read like a result file's
``points``). **frame** reads this file (or any JSON with ``points`` of that form, e.g. a result
file) and writes the frame as a ``jcalib.result/1`` file with the transform ``T_<frame>_<name>``
(matrix and 6x6 covariance), which ``jcalib export`` (and ``--export``) turns into ABB ``wobjdata``
or KUKA ``BASE_DATA``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError

__all__ = [
    "PIXELS_SCHEMA",
    "POINTS_SCHEMA",
    "FrameSummary",
    "TriangulateSummary",
    "frame_file",
    "triangulate_file",
]

PIXELS_SCHEMA = "jcalib.pixels/1"
POINTS_SCHEMA = "jcalib.pipeline.points/1"
#: Pixel noise (px, per coordinate) when neither the file nor the command gives one.
DEFAULT_SIGMA_PX = 0.5
#: Pairwise distances are written for at most this many points.
MAX_DISTANCE_POINTS = 20


# --------------------------------------------------------------------------------------------- reading


def _read_json(path: str | os.PathLike, what: str) -> Any:
    from jcalib.io.schema.reading import read_document

    return read_document(path, what, fmt="json")  # size, UTF-8, depth limits


def _array(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise BadInputError(f"{where}: expected numbers of shape {shape}, got {str(value)[:80]}") from None
    if arr.shape != shape:
        raise BadInputError(f"{where}: expected shape {shape}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise BadInputError(f"{where}: contains NaN or infinity")
    return arr


def _pose(value: Any, where: str) -> np.ndarray:
    T = _array(value, (4, 4), where)
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0 or np.abs(T[3] - [0, 0, 0, 1]).max() > 0:
        raise BadInputError(f"{where}: expected a rigid transform [[R, t], [0, 0, 0, 1]] (m)")
    return T


@dataclass(frozen=True)
class _Station:
    id: str
    T_base_flange: np.ndarray | None
    pixels: dict[str, dict[str, np.ndarray]]  # camera -> point -> (2,)


def _parse_pixels(data: Any, src: str) -> tuple[list[_Station], float | None, dict[str, tuple[int, int]]]:
    if not isinstance(data, dict) or data.get("schema") != PIXELS_SCHEMA:
        got = data.get("schema") if isinstance(data, dict) else type(data).__name__
        raise BadInputError(f"{src}: schema is {got!r}; expected '{PIXELS_SCHEMA}' (see jcalib triangulate --help)")
    from jcalib.io.schema.pixels import validate_pixels_document

    validate_pixels_document(data, src)  # types, names, pixels in the image, poses within reach
    unknown = sorted(set(data) - {"schema", "sigma_px", "cameras", "stations"})
    if unknown:
        raise BadInputError(f"{src}: unknown key(s) {unknown}; allowed: schema, sigma_px, cameras, stations")
    sigma = data.get("sigma_px")
    if sigma is not None and not (isinstance(sigma, (int, float)) and np.isfinite(sigma) and sigma > 0):
        raise BadInputError(f"{src}: sigma_px: expected a positive number of pixels, got {sigma!r}")
    sizes = {}
    for cam, entry in (data.get("cameras") or {}).items():
        size = entry.get("image_size") if isinstance(entry, dict) else None
        if not (isinstance(size, list) and len(size) == 2 and all(isinstance(s, int) and s > 0 for s in size)):
            raise BadInputError(f"{src}: cameras.{cam}.image_size: expected [width, height] in pixels, got {size!r}")
        sizes[str(cam)] = (size[0], size[1])
    stations_in = data.get("stations")
    if not isinstance(stations_in, list) or not stations_in:
        raise BadInputError(f"{src}: stations: expected a non-empty list of stations")
    stations, seen = [], set()
    for k, st in enumerate(stations_in):
        where = f"{src}: stations[{k}]"
        if not isinstance(st, dict):
            raise BadInputError(f"{where}: expected an object with id, pixels and optional T_base_flange")
        unknown = sorted(set(st) - {"id", "T_base_flange", "pixels"})
        if unknown:
            raise BadInputError(f"{where}: unknown key(s) {unknown}; allowed: id, T_base_flange, pixels")
        sid = str(st.get("id", f"s{k}"))
        if sid in seen:
            raise BadInputError(f"{where}: station id {sid!r} is used twice")
        seen.add(sid)
        where = f"{src}: station {sid}"
        T = _pose(st["T_base_flange"], f"{where}: T_base_flange") if st.get("T_base_flange") is not None else None
        pix_in = st.get("pixels")
        if not isinstance(pix_in, dict):
            raise BadInputError(f"{where}: pixels: expected {{camera: {{point: [u, v]}}}}")
        pixels: dict[str, dict[str, np.ndarray]] = {}
        for cam, pts in pix_in.items():
            if not isinstance(pts, dict):
                raise BadInputError(f"{where}: pixels.{cam}: expected {{point: [u, v]}}")
            pixels[str(cam)] = {str(p): _array(uv, (2,), f"{where}: pixels.{cam}.{p}") for p, uv in pts.items()}
        stations.append(_Station(sid, T, pixels))
    return stations, None if sigma is None else float(sigma), sizes


# --------------------------------------------------------------------------------------------- cameras


def _camera_model_and_cov(name: str, cell, result, sizes, src: str):
    """(camera model, intrinsics covariance or None) from the result, else the cell spec."""
    from jcalib.geometry.cameras import camera_from_opencv

    entry = result.cameras.get(name) if result is not None else None
    if entry is not None:
        model = camera_from_opencv(entry.K, entry.dist, entry.image_size, fisheye=entry.model == "fisheye")
        names = tuple(model.param_names)
        if tuple(entry.param_names) != names:
            raise BadInputError(
                f"result: cameras.{name}: intrinsics {list(entry.param_names)} do not match the model's {list(names)}"
            )
        if entry.covariance is not None:
            cov = np.asarray(entry.covariance)
        elif entry.std:
            cov = np.diag([entry.std.get(n, 0.0) ** 2 for n in names])
        else:
            cov = None
        return model, cov
    spec = cell.cameras[name]
    if spec.K is None:
        raise BadInputError(
            f"camera '{name}': no intrinsics: the result {'has no such camera' if result is not None else 'was not given'}"
            f" and {cell.source} gives no cameras.{name}.intrinsics; pass --result RESULT.json"
        )
    if name not in sizes:
        raise BadInputError(
            f"{src}: cameras.{name}.image_size is needed (intrinsics of '{name}' come from {cell.source}, which "
            f"has no image size)"
        )
    dist = np.zeros(0) if spec.dist is None else spec.dist
    return camera_from_opencv(spec.K, dist, sizes[name], fisheye=spec.model == "fisheye"), None


def _known_pose(kind: str, name: str, mount: str, spec_pose, cell, result) -> tuple[np.ndarray, np.ndarray | None]:
    """``T_<mount>_<name>`` and its covariance from the result, else the cell spec (exact)."""
    key = f"T_{mount}_{name}"
    if result is not None and key in result.transforms:
        entry = result.transforms[key]
        return np.asarray(entry.matrix), None if entry.covariance is None else np.asarray(entry.covariance)
    if spec_pose is not None:
        return np.asarray(spec_pose), None
    raise BadInputError(
        f"{kind} '{name}' (mount {mount}): its pose {key} is unknown: the result "
        f"{'has no ' + key if result is not None else 'was not given'} and {cell.source} gives no pose; "
        f"calibrate it first and pass --result"
    )


@dataclass(frozen=True)
class TriangulateSummary:
    """What :func:`triangulate_file` wrote: the points (in ``frame``) and the output path."""

    points: Any  # jcalib.init.triangulation.TriangulatedPoints
    frame: str
    path: Path


def triangulate_file(
    observations: str | os.PathLike,
    cell: str | os.PathLike,
    out: str | os.PathLike,
    *,
    result: str | os.PathLike | None = None,
    frame: str = "base",
    station: str | None = None,
    sigma_px: float | None = None,
) -> TriangulateSummary:
    """Triangulate the named points of a ``jcalib.pixels/1`` file and write ``jcalib.pipeline.points/1``.

    Args:
        observations: the pixels file (format in the module docstring).
        cell: the cell spec (``jcalib.cell/1``): camera mounts, intrinsics/poses if no result,
            ``robot.pose_noise``.
        out: the points file to write (atomically).
        result: optional calibration result (``jcalib.result/1``) with the cameras.
        frame: ``base``, ``flange``, a camera id or a target id.
        station: the station the frame refers to (``flange``, camera, flange-mounted target).
        sigma_px: pixel noise per coordinate, px (overrides the file's ``sigma_px``; default 0.5).

    Returns:
        :class:`TriangulateSummary`.

    Raises:
        BadInputError: malformed files, unknown camera/point/frame/station, missing poses or
            intrinsics, a point seen in fewer than two images.
        NotObservableError: nearly parallel rays or rays meeting behind a camera (naming the point).
    """
    from jcalib.init.pose_chains import compose_pose_chains
    from jcalib.init.triangulation import triangulate_points
    from jcalib.io.atomic import write_json_atomic
    from jcalib.io.cell import load_cell
    from jcalib.io.result import Provenance, hash_inputs, load_result

    src = str(observations)
    cell_spec = load_cell(cell)
    res = load_result(result) if result is not None else None
    stations, file_sigma, sizes = _parse_pixels(_read_json(observations, "pixels file"), src)
    sigma = sigma_px if sigma_px is not None else (file_sigma if file_sigma is not None else DEFAULT_SIGMA_PX)
    if not (np.isfinite(sigma) and sigma > 0):
        raise BadInputError(f"--sigma-px: expected a positive number of pixels, got {sigma!r}")

    # views: (station, camera) pairs in file order; points in order of first appearance
    views: list[tuple[_Station, str]] = []
    point_names: list[str] = []
    for st in stations:
        for cam in st.pixels:
            if cam not in cell_spec.cameras:
                raise BadInputError(
                    f"{src}: station {st.id}: camera '{cam}' is not in {cell_spec.source} "
                    f"(it has: {', '.join(cell_spec.cameras)})"
                )
            views.append((st, cam))
            point_names += [p for p in st.pixels[cam] if p not in point_names]
    if not point_names:
        raise BadInputError(f"{src}: no pixels: every station's pixels are empty")
    for name in point_names:
        seen = [f"{st.id}/{cam}" for st, cam in views if name in st.pixels[cam]]
        if len(seen) < 2:
            raise BadInputError(
                f"{src}: point {name!r} is seen in {len(seen)} image(s) ({', '.join(seen)}); triangulation needs "
                f"at least two (station, camera) images of it"
            )

    # uncertain poses (sources) and the chain of each view's camera pose in the output frame
    sources: dict[str, tuple[np.ndarray, np.ndarray | None]] = {}
    robot = cell_spec.robot
    C_robot = None
    if robot is not None and robot.pose_noise_translation_m is not None:
        C_robot = np.diag(np.concatenate([np.radians(robot.pose_noise_rotation_deg), robot.pose_noise_translation_m]) ** 2)
    by_id = {st.id: st for st in stations}

    def flange_pose(st: _Station, why: str) -> str:
        if st.T_base_flange is None:
            raise BadInputError(f"{src}: station {st.id}: T_base_flange is needed ({why})")
        sources[f"T_base_flange@{st.id}"] = (st.T_base_flange, C_robot)
        return f"T_base_flange@{st.id}"

    def camera_chain(cam: str, st: _Station) -> list[str]:
        spec = cell_spec.cameras[cam]
        if spec.mount == "free":
            raise BadInputError(
                f"camera '{cam}' is mount free in {cell_spec.source}: it has no pose in the cell, so its rays cannot "
                f"be placed; triangulation needs cameras mounted on the base or the flange"
            )
        key = f"T_{spec.mount}_{cam}"
        if key not in sources:
            sources[key] = _known_pose("camera", cam, spec.mount, spec.pose, cell_spec, res)
        if spec.mount == "base":
            return [key]
        return [flange_pose(st, f"camera '{cam}' is on the flange"), key]

    frame_station: list[_Station] = []  # the station the output frame refers to, when it moves

    def the_station() -> _Station:
        if station is not None:
            if station not in by_id:
                raise BadInputError(f"--station: no station {station!r} in {src} (have {', '.join(by_id)})")
            st = by_id[station]
        elif len(stations) != 1:
            raise BadInputError(
                f"--frame {frame}: the frame moves with the robot; name the station it refers to with --station "
                f"({', '.join(by_id)})"
            )
        else:
            st = stations[0]
        frame_station[:] = [st]
        return st

    def inverse(chain: list[str]) -> list[str]:
        return [c[1:] if c.startswith("~") else "~" + c for c in reversed(chain)]

    if frame == "base":
        prefix: list[str] = []
    elif frame == "flange":
        prefix = inverse([flange_pose(the_station(), "--frame flange")])
    elif frame in cell_spec.cameras:
        on_flange = cell_spec.cameras[frame].mount == "flange"
        prefix = inverse(camera_chain(frame, the_station() if on_flange else stations[0]))
    elif frame in cell_spec.targets:
        spec = cell_spec.targets[frame]
        if spec.mount == "free":
            raise BadInputError(f"--frame {frame}: target '{frame}' is mount free: it has no pose in the cell")
        key = f"T_{spec.mount}_{frame}"
        sources[key] = _known_pose("target", frame, spec.mount, spec.pose, cell_spec, res)
        chain = [key] if spec.mount == "base" else [flange_pose(the_station(), f"target '{frame}' is on the flange"), key]
        prefix = inverse(chain)
    else:
        raise BadInputError(
            f"--frame: expected base, flange, a camera ({', '.join(cell_spec.cameras)}) or a target "
            f"({', '.join(cell_spec.targets) or 'none'}), got {frame!r}"
        )
    chains = [prefix + camera_chain(cam, st) for st, cam in views]
    T_frame_cam, pose_cov = compose_pose_chains(sources, chains)

    models: dict[str, Any] = {}
    for _, cam in views:
        if cam not in models:
            models[cam] = _camera_model_and_cov(cam, cell_spec, res, sizes, src)
    cameras = [models[cam][0] for _, cam in views]
    intr_cov = [models[cam][1] for _, cam in views]
    px = np.full((len(point_names), len(views), 2), np.nan)
    for i, (st, cam) in enumerate(views):
        for name, uv in st.pixels[cam].items():
            px[point_names.index(name), i] = uv
    pts = triangulate_points(
        cameras, px, T_base_cam=T_frame_cam, names=point_names, sigma_px=sigma,
        intrinsics_covariance=intr_cov if any(c is not None for c in intr_cov) else None,
        pose_covariance=pose_cov if np.any(pose_cov) else None,
    )  # fmt: skip

    out_points = {}
    for name, p in zip(point_names, pts.points, strict=True):
        out_points[name] = {
            "position": p.p_base.tolist(),
            "frame": frame,
            "covariance": p.covariance.tolist(),
            "std_mm": (p.std * 1e3).tolist(),
            "rms_px": p.rms_px,
            "num_views": p.num_views,
            "parallax_deg": p.parallax_deg,
        }
    doc: dict[str, Any] = {"schema": POINTS_SCHEMA, "frame": frame, "sigma_px": float(sigma), "points": out_points}
    if frame_station:
        doc["station"] = frame_station[0].id
    doc["joint_covariance"] = {"points": list(point_names), "matrix": pts.covariance.tolist()}
    if 2 <= len(point_names) <= MAX_DISTANCE_POINTS:
        doc["distances"] = []
        for i in range(len(point_names)):
            for j in range(i + 1, len(point_names)):
                d, s = pts.distance(i, j)
                doc["distances"].append({"a": point_names[i], "b": point_names[j], "distance_m": d, "std_m": s})
    inputs = [observations, cell] + ([result] if result is not None else [])
    doc["provenance"] = Provenance.now(
        input_hash=hash_inputs(*inputs),
        options={"frame": frame, "sigma_px": float(sigma), "station": frame_station[0].id if frame_station else None},
    ).to_dict()
    path = write_json_atomic(out, doc)
    return TriangulateSummary(pts, frame, path)


# --------------------------------------------------------------------------------------------- frame


@dataclass(frozen=True)
class FrameSummary:
    """What :func:`frame_file` wrote."""

    frame: Any  # jcalib.init.frames.FrameResult
    transform: str  # e.g. "T_base_wobj"
    path: Path
    export_path: Path | None


def _load_points(data: Any, src: str) -> tuple[dict[str, tuple[np.ndarray, np.ndarray | None, str]], dict | None]:
    from jcalib.io.schema.pixels import validate_points_document

    if not isinstance(data, dict) or not isinstance(data.get("points"), dict) or not data["points"]:
        raise BadInputError(
            f"{src}: expected a JSON object with 'points': {{name: {{position: [x, y, z], frame, covariance}}}} "
            f"(as jcalib triangulate writes)"
        )
    validate_points_document(data, src)  # types, names, units
    points = {}
    for name, entry in data["points"].items():
        where = f"{src}: points.{name}"
        if not isinstance(entry, dict) or "position" not in entry:
            raise BadInputError(f"{where}: expected {{position: [x, y, z] (m), frame, covariance (3x3, m^2)}}")
        pos = _array(entry["position"], (3,), f"{where}.position")
        cov = _array(entry["covariance"], (3, 3), f"{where}.covariance") if entry.get("covariance") is not None else None
        frm = entry.get("frame", data.get("frame", "base"))
        if not isinstance(frm, str) or not frm:
            raise BadInputError(f"{where}.frame: expected a frame name, got {frm!r}")
        points[str(name)] = (pos, cov, frm)
    joint = data.get("joint_covariance")
    if joint is not None:
        if not isinstance(joint, dict) or not isinstance(joint.get("points"), list):
            raise BadInputError(f"{src}: joint_covariance: expected {{points: [names], matrix: [[3M x 3M]]}}")
        n = len(joint["points"])
        joint = {"points": [str(p) for p in joint["points"]],
                 "matrix": _array(joint.get("matrix"), (3 * n, 3 * n), f"{src}: joint_covariance.matrix")}  # fmt: skip
    return points, joint


def frame_file(
    points: str | os.PathLike,
    out: str | os.PathLike,
    *,
    method: str = "three-point",
    use: Sequence[str] | None = None,
    name: str = "wobj",
    origin: str = "first",
    sigma_mm: float | None = None,
    export: str | None = None,
    export_out: str | os.PathLike | None = None,
) -> FrameSummary:
    """A work-object frame from a points file, written as a ``jcalib.result/1`` file.

    Args:
        points: a ``jcalib.pipeline.points/1`` file (or any JSON with ``points`` of that form).
        out: the result file to write (atomically), holding ``T_<frame>_<name>`` with covariance.
        method: ``"three-point"`` (origin, a point on +X, a point on the +Y side; ABB/KUKA) or
            ``"plane"`` (plane fit to all the points; +X from the first to the second, the third on
            the +Y side, origin the first projected onto the plane).
        use: the point names to use, in that order; None = all points in file order (three-point:
            exactly three).
        name: the frame's name (the work object / base).
        origin: three-point only: ``"first"`` or ``"foot"`` (see :func:`frame_from_three_points`).
        sigma_mm: touching / triangulation noise per coordinate (mm) for points without covariance.
        export: also write ``"rapid"`` (``wobjdata``) or ``"krl"`` (``BASE_DATA``) text.
        export_out: where to write it (default: ``out`` with suffix ``.mod`` / ``.dat``).

    Returns:
        :class:`FrameSummary`.

    Raises:
        BadInputError: malformed file, unknown point names, points in different frames, an export
            for points not in the base frame.
        NotObservableError: collinear points, the X point at the origin, the Y point on the X axis.
    """
    from jcalib.init.frames import frame_from_points, frame_from_three_points
    from jcalib.io.atomic import write_text_atomic
    from jcalib.io.export._common import check_identifier
    from jcalib.io.result import Provenance, ResultFile, TransformResult, hash_inputs

    src = str(points)
    pts, joint = _load_points(_read_json(points, "points file"), src)
    if method not in ("three-point", "plane"):
        raise BadInputError(f"--method: expected 'three-point' or 'plane', got {method!r}")
    if export not in (None, "rapid", "krl"):
        raise BadInputError(f"--export: expected 'rapid' or 'krl', got {export!r}")
    check_identifier(name, "--name", 24)
    names = list(pts) if use is None else [str(u) for u in use]
    for n in names:
        if n not in pts:
            raise BadInputError(f"--points: no point {n!r} in {src} (have {', '.join(pts)})")
    if len(set(names)) != len(names):
        raise BadInputError(f"--points: a point is named twice in {names}")
    if method == "three-point" and len(names) != 3:
        raise BadInputError(
            f"--method three-point needs exactly three points (origin, +X, +Y side), got {len(names)}: {names}; "
            f"choose them with --points or use --method plane"
        )
    if len(names) < 3:
        raise BadInputError(f"--method plane needs at least three points, got {len(names)}")
    frames = {pts[n][2] for n in names}
    if len(frames) != 1:
        raise BadInputError(f"{src}: the points are in different frames {sorted(frames)}; expected one frame")
    parent = frames.pop()
    P = np.stack([pts[n][0] for n in names])
    # covariance: the joint one when it covers the points, else per point, else --sigma-mm, else none
    cov = None
    if joint is not None and all(n in joint["points"] for n in names):
        idx = np.concatenate([3 * joint["points"].index(n) + np.arange(3) for n in names])
        cov = joint["matrix"][np.ix_(idx, idx)]
    elif all(pts[n][1] is not None for n in names):
        cov = np.zeros((3 * len(names),) * 2)
        for i, n in enumerate(names):
            cov[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = pts[n][1]
    elif sigma_mm is not None:
        if not (np.isfinite(sigma_mm) and sigma_mm > 0):
            raise BadInputError(f"--sigma-mm: expected a positive number of millimetres, got {sigma_mm!r}")
        cov = float(sigma_mm) * 1e-3
    if method == "three-point":
        res = frame_from_three_points(*P, covariance=cov, origin=origin)
    else:
        res = frame_from_points(P, covariance=cov)
    key = f"T_{parent}_{name}"
    result = ResultFile(
        transforms={key: TransformResult(res.T_base_wobj, res.covariance)},
        stats={"plane_rms_m": res.rms, "num_points": len(names)},
        provenance=Provenance.now(
            input_hash=hash_inputs(points), options={"method": method, "points": names, "origin": origin}
        ),
        extra={"frame_points": {"names": names, "plane_residuals_m": res.plane_residuals.tolist()}},
    )
    path = Path(out)
    result.save(path)
    export_path = None
    if export is not None:
        if parent != "base":
            raise BadInputError(
                f"--export {export}: robot controllers take work objects in the base frame; the points are in "
                f"'{parent}' (triangulate them with --frame base)"
            )
        if export == "rapid":
            from jcalib.io.export.abb_rapid import abb_rapid_module

            text = abb_rapid_module(result, tools=[], wobjs={name: name})
        else:
            from jcalib.io.export.kuka_krl import kuka_config_lines

            text = kuka_config_lines(result, tools=[], bases=[name])
        export_path = Path(export_out) if export_out is not None else path.with_suffix(".mod" if export == "rapid" else ".dat")
        write_text_atomic(export_path, text)
    return FrameSummary(res, key, path, export_path)
