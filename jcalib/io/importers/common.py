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
by the camera, which the cell names as a pose sensor (``sensors: {cam0: {kind: pose, mount: ...}}``: its
images were processed by the other tool, so no lens and no image size are known or needed):
``"poses": [{"sensor": c, "target": t, "T_sensor_target": [[4x4]]}]`` (metres), the marker a
``type: points`` target. ``jcalib calibrate SESSION/cell.yaml SESSION/observations.json`` solves them
(pose-measurement factors, hand-eye from pose pairs) with no detection step.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import make_pose, matrix_from_quat
from jcalib.io.importers.output import check_output_folder, staged_folder
from jcalib.io.schema.common import (
    MAX_CELL_EXTENT_M,
    MAX_IMAGE_SIDE_PX,
    max_reach_m,
    pose_problem,
)

__all__ = [
    "MOUNTS",
    "ImportSummary",
    "ImportedStation",
    "cell_entries_for_mount",
    "check_options",
    "integer",
    "json_safe",
    "natural_key",
    "number",
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
    unknown = sorted(str(k) for k in set(options) - set(allowed))
    if unknown:
        known = "; ".join(f"{k}: {v}" for k, v in allowed.items()) or "none"
        raise BadInputError(f"import {fmt}: unknown option(s) {', '.join(k[:40] for k in unknown)}; this format "
                            f"takes: {known}")


def resolve_source(source: str | os.PathLike, default_name: str | None, what: str) -> Path:
    """The source file: ``source`` itself, or ``source/default_name`` when ``source`` is a folder (which
    must then lie in that folder, symlinks resolved)."""
    p = Path(source)
    if p.is_dir() and default_name is not None:
        p = p / default_name
        try:
            inside = p.resolve().is_relative_to(Path(source).resolve())
        except (OSError, RuntimeError):
            inside = False
        if not inside:
            raise BadInputError(f"{what}: {p} is a symlink out of {source} (or a loop); give the file itself")
    if not p.is_file():
        raise BadInputError(f"{what}: {p} does not exist or is not a file"
                            + (f" (expected {default_name} or its folder)" if default_name else ""))
    return p


def natural_key(s: str) -> list:
    """Sort key that orders digit runs by value (``im2`` before ``im10``), without regular expressions:
    linear in the name, and a digit run longer than Python converts is compared by length, then text."""
    out: list = []
    i, n = 0, len(s)
    while i < n:
        j = i
        digit = s[i].isdigit()
        while j < n and s[j].isdigit() == digit:
            j += 1
        t = s[i:j]
        if digit and t.isascii():
            d = t.lstrip("0") or "0"
            out.append((0, len(d), d, t))
        else:
            out.append((1, 0, t, t))
        i = j
    return out


def number(value: Any, where: str, *, positive: bool = False) -> float:
    """A finite number from a parsed file: an int or float (not a boolean, text or list).

    Raises:
        BadInputError: naming ``where`` and the type received (never the value of a long text).
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise BadInputError(f"{where}: expected a number, got {_describe(value)}")
    try:
        x = float(value)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        raise BadInputError(f"{where}: expected a finite number, got {x}")
    if positive and not x > 0:
        raise BadInputError(f"{where}: expected a positive number, got {x:g}")
    return x


def integer(value: Any, where: str, *, minimum: int = 1, maximum: int = 100_000) -> int:
    """An integer from a parsed file (``7``; not ``7.9``, ``7.0``, ``"7"`` or ``true``), within bounds."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise BadInputError(f"{where}: expected an integer, got {_describe(value)}")
    if not minimum <= int(value) <= maximum:
        raise BadInputError(f"{where}: expected an integer from {minimum} to {maximum}, got {int(value)}")
    return int(value)


def _describe(value: Any) -> str:
    """A value for a message: short numbers as they are, anything else by its type (and length) only."""
    if isinstance(value, (bool, int, float)) and len(repr(value)) <= 32:
        return repr(value)
    if isinstance(value, str):  # never the text itself: the file may be one that should not be shown
        return f"text ({len(value)} characters)"
    return "nothing" if value is None else f"a {type(value).__name__}"


def _numbers(values: Any, where: str, n: int) -> np.ndarray:
    if isinstance(values, np.ndarray) and values.dtype.kind in "iuf":
        flat = values.reshape(-1)
        if flat.size != n:
            raise BadInputError(f"{where}: expected {n} numbers, got {flat.size}")
        return np.array([number(v, where) for v in flat.tolist()])
    if not isinstance(values, (list, tuple)) or len(values) != n:
        raise BadInputError(f"{where}: expected {n} numbers, got {_describe(values)}"
                            + (f" of {len(values)}" if isinstance(values, (list, tuple)) else ""))
    return np.array([number(v, f"{where}[{k}]") for k, v in enumerate(values)])


def pose_from_xyz_quat(xyz: Any, q_xyzw: Any, where: str, scale: float = 1.0) -> np.ndarray:
    """(4, 4) pose from a translation and a Hamilton quaternion given as ``(x, y, z, w)``.

    Args:
        xyz: (3,) translation in the source's unit; ``scale`` converts it to metres.
        q_xyzw: (4,) quaternion, ROS order (x, y, z, w).
        where: file / entry for messages.
    Raises:
        BadInputError: values that are not finite numbers, or |q| further than ``QUAT_NORM_TOL`` from 1.
    """
    t = _numbers(list(xyz) if isinstance(xyz, tuple) else xyz, f"{where} translation", 3)
    q = _numbers(list(q_xyzw) if isinstance(q_xyzw, tuple) else q_xyzw, f"{where} quaternion", 4)
    with np.errstate(over="ignore", invalid="ignore"):
        n = float(np.linalg.norm(q))
    if not abs(n - 1.0) <= QUAT_NORM_TOL:
        raise BadInputError(
            f"{where}: quaternion {q.tolist()} has norm {n:.6f}, not 1: not a rotation (wrong field order or "
            "Euler angles given as a quaternion?)"
        )
    q_wxyz = np.array([q[3], q[0], q[1], q[2]]) / n
    with np.errstate(over="ignore", invalid="ignore"):
        t = t * scale
    if not np.all(np.isfinite(t)):
        raise BadInputError(f"{where}: the translation is too large to be a position")
    return make_pose(matrix_from_quat(q_wxyz), t)


def pose_from_matrix(value: Any, where: str, scale: float = 1.0) -> np.ndarray:
    """(4, 4) pose from a 4x4 (or 16 row-major values) homogeneous matrix; translation times ``scale`` -> m.

    The rotation block is re-orthonormalised (SVD) when it is within ``ROTATION_TOL`` of a rotation.

    Raises:
        BadInputError: wrong shape, a value that is not a finite number, last row not [0 0 0 1], or not a
            proper rotation.
    """
    if isinstance(value, (list, tuple)) and len(value) == 4 and all(isinstance(r, (list, tuple)) for r in value):
        rows = [_numbers(list(r), f"{where} row {k}", 4) for k, r in enumerate(value)]
        T = np.stack(rows)
    elif isinstance(value, np.ndarray) and value.shape == (4, 4):
        T = _numbers(value, where, 16).reshape(4, 4)
    else:
        if isinstance(value, tuple):
            value = list(value)
        T = _numbers(value, f"{where} (a 4x4 matrix: 16 row-major values)", 16).reshape(4, 4)
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise BadInputError(f"{where}: the last row is {T[3].tolist()}, expected [0, 0, 0, 1]: not a homogeneous pose "
                            "(a column-major or transposed matrix?)")
    R = T[:3, :3]
    with np.errstate(over="ignore", invalid="ignore"):
        err = float(np.max(np.abs(R.T @ R - np.eye(3))))
        det = float(np.linalg.det(R)) if np.all(np.isfinite(R)) else -1.0
        t = T[:3, 3] * scale
    if not err <= ROTATION_TOL or not det > 0:
        raise BadInputError(f"{where}: the rotation block is not a proper rotation (R^T R != I or det < 0)")
    if not np.all(np.isfinite(t)):
        raise BadInputError(f"{where}: the translation is too large to be a position")
    U, _, Vt = np.linalg.svd(R)
    return make_pose(U @ Vt, t)


def cell_entries_for_mount(mount: str | None, fmt: str, why: str) -> tuple[str, str]:
    """``(camera mount, target mount)`` for a hand-eye source: the camera on the flange sees a target
    fixed in the base, a fixed camera sees a target on the flange. ``mount`` None: refused (``why``)."""
    if mount is None:
        raise BadInputError(f"import {fmt}: {why}; say where the camera is mounted with --mount flange "
                            "(eye-in-hand) or --mount base (eye-to-hand)")
    if mount not in MOUNTS:
        raise BadInputError(f"import {fmt}: --mount: expected flange or base, got {str(mount)[:40]!r}")
    return (mount, "base" if mount == "flange" else "flange")


def json_safe(value: Any, depth: int = 0) -> Any:
    """``value`` as JSON can hold it, for the record (``imported_from``): text cut to 200 characters,
    non-finite numbers and anything deeper than 6 levels or longer than 100 entries dropped (None)."""
    if isinstance(value, bool) or value is None:
        return value
    if isinstance(value, int):
        return value if abs(value) < 2**63 else None
    if isinstance(value, float):
        return value if math.isfinite(value) and abs(value) < 1e300 else None
    if isinstance(value, str):
        return value[:200]
    if depth >= 6:
        return None
    if isinstance(value, dict):
        return {str(k)[:64]: json_safe(v, depth + 1) for k, v in list(value.items())[:100]}
    if isinstance(value, (list, tuple)):
        return [json_safe(v, depth + 1) for v in list(value)[:100]]
    return None


def _png_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG's IHDR chunk, or None if the header is not a PNG's."""
    if len(data) < 24 or data[12:16] != b"IHDR":
        return None
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def _image_bytes(image: Any, where: str) -> bytes:
    """PNG bytes of an image file (PNG copied as is, other formats decoded and re-encoded, lossless) or
    of a BGR array; ``where`` names the station and camera."""
    import cv2

    from jcalib.io.schema.reading import read_bytes_limited

    if isinstance(image, np.ndarray):
        if image.size == 0 or image.ndim not in (2, 3) or max(image.shape[:2]) > MAX_IMAGE_SIDE_PX:
            raise BadInputError(f"{where}: image of shape {image.shape}: expected a non-empty image of at most "
                                f"{MAX_IMAGE_SIDE_PX} px a side")
        try:
            ok, buf = cv2.imencode(".png", np.ascontiguousarray(image))
        except cv2.error:
            ok = False
        if not ok:
            raise BadInputError(f"{where}: cannot encode as PNG (shape {image.shape}, dtype {image.dtype})")
        return buf.tobytes()
    path = Path(image)
    data = read_bytes_limited(path, f"{where}: image")
    if not data:
        raise BadInputError(f"{where}: image {path} is empty (0 bytes); replace it or remove its entry")
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        size = _png_size(data)
        if size is None or min(size) < 1 or max(size) > MAX_IMAGE_SIDE_PX:
            raise BadInputError(f"{where}: image {path}: a PNG whose header gives no valid size (corrupt file?)")
        return data
    try:
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        img = None
    if img is None or img.size == 0:
        raise BadInputError(f"{where}: {path} is not an image OpenCV can read")
    try:
        ok, buf = cv2.imencode(".png", img)
    except cv2.error:
        ok = False
    if not ok:
        raise BadInputError(f"{where}: {path}: cannot encode as PNG (shape {img.shape}, dtype {img.dtype})")
    return buf.tobytes()


def _check_station(st: ImportedStation, fmt: str, source: Path) -> None:
    """Units and finiteness of what a station records (the reach limit of cell specs for the flange)."""
    where = f"import {fmt}: {source}: station {st.id} ({json.dumps(json_safe(st.source))[:200]})"
    if st.T_base_flange is not None:
        why = pose_problem(st.T_base_flange, max_reach_m(), "flange translation")
        if why:
            raise BadInputError(f"{where}: T_base_flange: {why} (JCALIB_MAX_REACH_M raises the limit)")
    for p in st.poses:
        why = pose_problem(p["T_cam_target"], MAX_CELL_EXTENT_M, "target translation")
        if why:
            raise BadInputError(f"{where}: T_cam_target: {why}")
    if st.joints_deg is not None and not all(math.isfinite(v) and abs(v) < 1e7 for v in st.joints_deg):
        raise BadInputError(f"{where}: joint positions must be finite (got {st.joints_deg[:12]})")


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
    source_root: str | os.PathLike | None = None,
) -> ImportSummary:
    """Write the session folder ``out``: a new or empty folder outside the source (written to a
    temporary sibling and renamed at the end: a failed import leaves nothing).

    Args:
        cell: the cell spec (``jcalib.cell/1`` mapping).
        stations: in order; ids unique.
        fmt, source, conventions: recorded under ``imported_from`` in ``session.json``.
        extra: more ``imported_from`` entries (e.g. the source tool's initial guesses or answer).
        validate_cell: parse the cell spec first.
        source_root: what the import read (the data set's folder; default ``source``), which ``out``
            may not be, lie in or hold.
    Raises:
        BadInputError: an invalid cell, no station, duplicate ids, a flange beyond the reach limit,
            or an ``out`` that is a file, not empty, or the source.
    """
    import yaml

    from jcalib.io.atomic import write_bytes_atomic, write_json_atomic
    from jcalib.io.cell import parse_cell
    from jcalib.io.session import SessionWriter, utc_now

    out = check_output_folder(out, source if source_root is None else source_root, fmt)
    if not stations:
        raise BadInputError(f"import {fmt}: {source} holds no station (no image/pose pair)")
    ids = [s.id for s in stations]
    if len(set(ids)) != len(ids):
        raise BadInputError(f"import {fmt}: duplicate station ids in {source}")
    for st in stations:
        _check_station(st, fmt, source)
    if validate_cell:
        parse_cell(cell, source=f"cell spec made from {source}")
    info = {"format": fmt, "source": str(Path(source).resolve()), "conventions": conventions,
            **json_safe(extra or {})}
    with staged_folder(out, fmt) as tmp:
        with SessionWriter.create(tmp, cell=cell, extra={"imported_from": info}) as w:
            for st in stations:
                rel_images = {}
                for cam, src in st.images.items():
                    rel = w.image_path(cam, st.id)
                    write_bytes_atomic(w.directory / rel, _image_bytes(src, f"import {fmt}: station {st.id} camera {cam}"))
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
                    rec["source"] = json_safe(st.source)
                w.append_station(rec)
        write_bytes_atomic(tmp / "cell.yaml", yaml.safe_dump(cell, sort_keys=False).encode("utf-8"))
        if any(st.poses for st in stations):
            write_json_atomic(tmp / "observations.json", _pose_observations(stations, set(cell.get("sensors") or {})))
    steps = [f"jcalib calibrate {out / 'cell.yaml'} {out / 'observations.json'} -o result.json"]
    if not any(st.poses for st in stations):
        steps.insert(0, f"jcalib detect --session {out}")
    cams = sorted({c for st in stations for c in st.images} | {p["camera"] for st in stations for p in st.poses})
    return ImportSummary(out=out, format=fmt, num_stations=len(stations), cameras=tuple(cams), notes=tuple(notes),
                         next_steps=tuple(steps))


def _pose_measurement(p: dict, sensors: set[str]) -> dict:
    """A station's pose measurement in the observations' form: the sensor form for a pose sensor of the cell."""
    T = np.asarray(p["T_cam_target"]).tolist()
    if p["camera"] in sensors:
        return {"sensor": p["camera"], "target": p["target"], "T_sensor_target": T}
    return {**p, "T_cam_target": T}


def _pose_observations(stations: list[ImportedStation], sensors: set[str]) -> dict:
    return {
        "schema": "jcalib.observations/1",
        "cameras": {},
        "targets": {},
        "stations": [
            {
                "id": st.id,
                **({} if st.T_base_flange is None else {"T_base_flange": np.asarray(st.T_base_flange).tolist()}),
                **({} if st.joints_deg is None else {"joints_deg": list(st.joints_deg)}),
                "detections": [],
                "poses": [_pose_measurement(p, sensors) for p in st.poses],
            }
            for st in stations
        ],
    }


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
    source_root: str | os.PathLike | None = None,
) -> ImportSummary:
    """Write a session of hand-eye pose pairs ``(T_base_flange, T_cam_target)`` (m) without images.

    The cell has one camera as a pose sensor (``sensors: {camera: {kind: pose, mount}}``: the other tool
    measured the marker in its images, so no lens and no image size) and one marker (the other mount) of
    ``type: points``; every station carries its flange pose and the camera's measurement of the marker pose
    (module docstring).
    A pair repeated exactly (a sample saved twice) is kept once, with a note naming it.
    """
    cam_mount, tgt_mount = cell_entries_for_mount(mount, fmt, "")
    cell = {
        "schema": "jcalib.cell/1",
        "sensors": {camera: {"kind": "pose", "mount": cam_mount}},
        "targets": {target: {"type": "points", "mount": tgt_mount}},
        "robot": {},
    }
    seen: set[bytes] = set()
    kept, repeated = [], []
    for i, (Tb, Tc) in enumerate(pairs):
        key = np.asarray(Tb, dtype=np.float64).tobytes() + np.asarray(Tc, dtype=np.float64).tobytes()
        if key in seen:
            repeated.append(i)
            continue
        seen.add(key)
        kept.append((i, Tb, Tc))
    if repeated:
        notes = notes + (f"pair(s) {', '.join(map(str, repeated[:20]))} repeat an earlier pair exactly: kept once",)
    stations = [
        ImportedStation(id=f"s{k:03d}", T_base_flange=Tb, poses=[{"camera": camera, "target": target, "T_cam_target": Tc}],
                        source={"pair": i})
        for k, (i, Tb, Tc) in enumerate(kept)
    ]
    notes = notes + (
        (f"pose pairs without images: the camera is the cell's pose sensor {camera!r} (no lens, no image size) and "
         "observations.json holds each station's 6-DOF T_sensor_target ('poses'); jcalib calibrate solves them "
         "directly (no detect step)"),
    )
    return write_session(out, cell, stations, fmt=fmt, source=source, conventions=conventions, extra=extra,
                         notes=notes, source_root=source_root)
