"""What every importer shares: writing the capture session, reading poses, checking options.

An importer turns another tool's data set into a ``jcalib.session/1`` folder (docs/design.md, "Capture
session"): ``session.json`` with the cell spec the source describes, ``stations.jsonl`` with one record
per robot station (``T_base_flange`` in metres, the images of each camera), ``images/<camera>/<station>.png``
(PNG sources copied byte for byte, other formats decoded and re-encoded losslessly as PNG), and a copy
of the cell spec as ``cell.yaml`` so that ``jcalib calibrate SESSION/cell.yaml SESSION/observations.json``
runs after ``jcalib detect --session SESSION``. ``session.json`` also records ``imported_from``: the
format, the source path and the conventions the importer assumed.

Sources that hold pose pairs without images (hand-eye samples of easy_handeye, MoveIt, camodocal) give
stations without images and an ``observations.json`` whose stations carry 6-DOF target poses measured
by the camera: ``"poses": [{"camera": c, "target": t, "T_cam_target": [[4x4]]}]`` (metres). The cell
then names the marker as a ``type: points`` target (docs/design.md: points known from the observations).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import make_pose, matrix_from_quat

__all__ = [
    "ImportSummary",
    "ImportedStation",
    "MOUNTS",
    "check_options",
    "cell_entries_for_mount",
    "natural_key",
    "pose_from_matrix",
    "pose_from_xyz_quat",
    "pose_pair_session",
    "resolve_source",
    "write_session",
]

#: Where the camera hangs: ``flange`` (eye-in-hand: target fixed in the base) or ``base``
#: (eye-to-hand: target on the flange).
MOUNTS = ("flange", "base")
#: Largest deviation of |q| from 1 accepted (then normalised); more is not a rotation quaternion.
QUAT_NORM_TOL = 1e-3
#: Largest deviation of R^T R from I accepted in a rotation matrix (then re-orthonormalised).
ROTATION_TOL = 1e-3


@dataclass
class ImportedStation:
    """One station of an imported data set.

    Attributes:
        id: station id in the session (``s000``, ...).
        T_base_flange: (4, 4) flange pose in the robot base, m; None without a robot.
        images: camera id -> source image file, or an (H, W[, C]) uint8/uint16 array in OpenCV's BGR order.
        poses: 6-DOF measurements ``{"camera", "target", "T_cam_target": (4, 4) m}`` (pose-pair sources).
        joints_deg: joint positions as controllers report them (degrees; prismatic mm), or None.
        time: UTC time of the station (ISO 8601) where the source has one, else None.
        source: what the station came from (file names, message stamps), for the record.
    """

    id: str
    T_base_flange: np.ndarray | None
    images: dict[str, Any] = field(default_factory=dict)
    poses: list[dict[str, Any]] = field(default_factory=list)
    joints_deg: list[float] | None = None
    time: str | None = None
    source: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class ImportSummary:
    """What an import wrote.

    Attributes:
        out: the session folder.  format: importer name.  num_stations: stations written.
        cameras: camera ids.  notes: what the user should know (ignored fields, assumptions).
        next_steps: the commands that calibrate the session.
    """

    out: Path
    format: str
    num_stations: int
    cameras: tuple[str, ...]
    notes: tuple[str, ...] = ()
    next_steps: tuple[str, ...] = ()


def check_options(fmt: str, options: dict[str, Any], allowed: dict[str, str]) -> None:
    """Refuse options the importer does not know, naming the ones it does (``allowed``: name -> help)."""
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        known = "; ".join(f"{k}: {v}" for k, v in allowed.items()) or "none"
        raise BadInputError(f"import {fmt}: unknown option(s) {', '.join(unknown)}; this format takes: {known}")


def resolve_source(source: str | os.PathLike, default_name: str | None, what: str) -> Path:
    """The source file: ``source`` itself, or ``source/default_name`` when ``source`` is a folder."""
    p = Path(source)
    if p.is_dir() and default_name is not None:
        p = p / default_name
    if not p.is_file():
        raise BadInputError(f"{what}: {p} does not exist" + (f" (expected {default_name} or its folder)" if default_name else ""))
    return p


def natural_key(s: str) -> list:
    """Sort key that orders digit runs by value (``im2`` before ``im10``)."""
    return [(0, int(t), t) if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", s) if t != ""]


def pose_from_xyz_quat(xyz: Any, q_xyzw: Any, where: str, scale: float = 1.0) -> np.ndarray:
    """(4, 4) pose from a translation and a Hamilton quaternion given as ``(x, y, z, w)``.

    Args:
        xyz: (3,) translation in the source's unit; ``scale`` converts it to metres.
        q_xyzw: (4,) quaternion, ROS order (x, y, z, w).
        where: file / entry for messages.
    Raises:
        BadInputError: non-finite values, or |q| further than ``QUAT_NORM_TOL`` from 1.
    """
    t = np.asarray(xyz, dtype=np.float64).reshape(-1)
    q = np.asarray(q_xyzw, dtype=np.float64).reshape(-1)
    if t.shape != (3,) or q.shape != (4,) or not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))):
        raise BadInputError(f"{where}: expected a finite translation (3) and quaternion (4), got {t.tolist()}, {q.tolist()}")
    n = float(np.linalg.norm(q))
    if abs(n - 1.0) > QUAT_NORM_TOL:
        raise BadInputError(
            f"{where}: quaternion {q.tolist()} has norm {n:.6f}, not 1: not a rotation (wrong field order or "
            "Euler angles given as a quaternion?)"
        )
    q_wxyz = np.array([q[3], q[0], q[1], q[2]]) / n
    return make_pose(matrix_from_quat(q_wxyz), t * scale)


def pose_from_matrix(value: Any, where: str, scale: float = 1.0) -> np.ndarray:
    """(4, 4) pose from a 4x4 (or 16 row-major values) homogeneous matrix; translation times ``scale`` -> m.

    The rotation block is re-orthonormalised (SVD) when it is within ``ROTATION_TOL`` of a rotation.

    Raises:
        BadInputError: wrong shape, non-finite, last row not [0 0 0 1], or not a proper rotation.
    """
    try:
        T = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise BadInputError(f"{where}: expected a 4x4 matrix, got {str(value)[:80]}") from None
    if T.size == 16:
        T = T.reshape(4, 4)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise BadInputError(f"{where}: expected a finite 4x4 matrix (16 row-major values), got shape {T.shape}")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise BadInputError(f"{where}: the last row is {T[3].tolist()}, expected [0, 0, 0, 1]: not a homogeneous pose "
                            "(a column-major or transposed matrix?)")
    R = T[:3, :3]
    if np.max(np.abs(R.T @ R - np.eye(3))) > ROTATION_TOL or np.linalg.det(R) < 0:
        raise BadInputError(f"{where}: the rotation block is not a proper rotation (R^T R != I or det < 0)")
    U, _, Vt = np.linalg.svd(R)
    return make_pose(U @ Vt, T[:3, 3] * scale)


def cell_entries_for_mount(mount: str | None, fmt: str, why: str) -> tuple[str, str]:
    """``(camera mount, target mount)`` for a hand-eye source: the camera on the flange sees a target
    fixed in the base, a fixed camera sees a target on the flange. ``mount`` None: refused (``why``)."""
    if mount is None:
        raise BadInputError(f"import {fmt}: {why}; say where the camera is mounted with --mount flange "
                            "(eye-in-hand) or --mount base (eye-to-hand)")
    if mount not in MOUNTS:
        raise BadInputError(f"import {fmt}: --mount: expected flange or base, got {mount!r}")
    return (mount, "base" if mount == "flange" else "flange")


def _image_bytes(image: Any) -> bytes:
    """PNG bytes of an image file (PNG copied as is, other formats decoded and re-encoded, lossless) or
    of a BGR array."""
    import cv2

    if isinstance(image, np.ndarray):
        ok, buf = cv2.imencode(".png", np.ascontiguousarray(image))
        if not ok:
            raise BadInputError(f"image: cannot encode as PNG (shape {image.shape}, dtype {image.dtype})")
        return buf.tobytes()
    path = Path(image)
    data = path.read_bytes()
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return data
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise BadInputError(f"{path}: not an image OpenCV can read")
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise BadInputError(f"{path}: cannot encode as PNG (shape {img.shape}, dtype {img.dtype})")
    return buf.tobytes()


def write_session(
    out: str | os.PathLike,
    cell: dict,
    stations: list[ImportedStation],
    *,
    fmt: str,
    source: Path,
    conventions: str,
    extra: dict | None = None,
    validate_cell: bool = True,
    notes: tuple[str, ...] = (),
) -> ImportSummary:
    """Write the session folder ``out`` (created; must not hold a session yet).

    Args:
        cell: the cell spec (``jcalib.cell/1`` mapping).
        stations: in order; ids unique.
        fmt, source, conventions: recorded under ``imported_from`` in ``session.json``.
        extra: more ``imported_from`` entries (e.g. the source tool's initial guesses or answer).
        validate_cell: parse the cell spec first (pose-pair cells name a ``points`` marker, which the
            cell parser accepts once the pose-measurement factors are in).
    Raises:
        BadInputError: an invalid cell, no station, duplicate ids, or ``out`` holding a session.
    """
    import yaml

    from jcalib.io.atomic import write_bytes_atomic, write_json_atomic
    from jcalib.io.cell import parse_cell
    from jcalib.io.session import SessionWriter, utc_now

    if not stations:
        raise BadInputError(f"import {fmt}: {source} holds no station (no image/pose pair)")
    ids = [s.id for s in stations]
    if len(set(ids)) != len(ids):
        raise BadInputError(f"import {fmt}: duplicate station ids in {source}")
    if validate_cell:
        parse_cell(cell, source=f"cell spec made from {source}")
    info = {"format": fmt, "source": str(Path(source).resolve()), "conventions": conventions, **(extra or {})}
    with SessionWriter.create(out, cell=cell, extra={"imported_from": info}) as w:
        for st in stations:
            rel_images = {}
            for cam, src in st.images.items():
                rel = w.image_path(cam, st.id)
                write_bytes_atomic(w.directory / rel, _image_bytes(src))
                rel_images[cam] = rel
            rec = {
                "id": st.id,
                "T_base_flange": None if st.T_base_flange is None else np.asarray(st.T_base_flange).tolist(),
                "joints_deg": st.joints_deg,
                "time": st.time or utc_now(),
                "images": rel_images,
                "status": "ok",
            }
            if st.source:
                rec["source"] = st.source
            w.append_station(rec)
        d = w.directory
    write_bytes_atomic(d / "cell.yaml", yaml.safe_dump(cell, sort_keys=False).encode("utf-8"))
    steps = [f"jcalib calibrate {d / 'cell.yaml'} {d / 'observations.json'} -o result.json"]
    if any(st.poses for st in stations):
        obs = {
            "schema": "jcalib.observations/1",
            "cameras": {},
            "targets": {},
            "stations": [
                {
                    "id": st.id,
                    **({} if st.T_base_flange is None else {"T_base_flange": np.asarray(st.T_base_flange).tolist()}),
                    "detections": [],
                    "poses": [{**p, "T_cam_target": np.asarray(p["T_cam_target"]).tolist()} for p in st.poses],
                }
                for st in stations
            ],
        }
        write_json_atomic(d / "observations.json", obs)
    else:
        steps.insert(0, f"jcalib detect --session {d}")
    cams = sorted({c for st in stations for c in st.images} | {p["camera"] for st in stations for p in st.poses})
    return ImportSummary(out=d, format=fmt, num_stations=len(stations), cameras=tuple(cams), notes=tuple(notes),
                         next_steps=tuple(steps))


def pose_pair_session(
    out: str | os.PathLike,
    pairs: list[tuple[np.ndarray, np.ndarray]],
    *,
    mount: str,
    fmt: str,
    source: Path,
    conventions: str,
    camera: str = "cam0",
    target: str = "marker",
    extra: dict | None = None,
    notes: tuple[str, ...] = (),
) -> ImportSummary:
    """Write a session of hand-eye pose pairs ``(T_base_flange, T_cam_target)`` (m) without images.

    The cell has one camera (``mount``) and one marker (the other mount) of ``type: points``; every
    station carries its flange pose and the camera's measurement of the marker pose (module docstring).
    """
    cam_mount, tgt_mount = cell_entries_for_mount(mount, fmt, "")
    cell = {
        "schema": "jcalib.cell/1",
        "cameras": {camera: {"model": "pinhole", "mount": cam_mount}},
        "targets": {target: {"type": "points", "mount": tgt_mount}},
        "robot": {},
    }
    stations = [
        ImportedStation(id=f"s{i:03d}", T_base_flange=Tb, poses=[{"camera": camera, "target": target, "T_cam_target": Tc}],
                        source={"pair": i})
        for i, (Tb, Tc) in enumerate(pairs)
    ]
    notes = notes + (
        "pose pairs without images: observations.json holds each station's 6-DOF T_cam_target ('poses'); "
        "calibrate needs the problem builder's pose-measurement factors and a 'points' target type",
    )
    return write_session(out, cell, stations, fmt=fmt, source=source, conventions=conventions, extra=extra,
                         validate_cell=False, notes=notes)
