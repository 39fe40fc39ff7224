"""calibration-rs / vision-calibration ``dataset.toml`` manifests -> capture session.

The manifest (crate ``vision-calibration-dataset``, ``version = 1``) names per camera an image
``glob`` (natural-sorted: ``im2`` before ``im10``) or an explicit ``list``, the ``target``, the robot
pose file and its conventions, and how images pair with poses::

    version = 1
    topology = "single_cam_handeye"          # planar_intrinsics | single_cam_handeye | rig_extrinsics | rig_handeye
    [[cameras]]  id = "cam0"  images = { kind = "glob", pattern = "*.png" }
    [target]     kind = "chessboard"  rows = 17  cols = 28  square_size_m = 0.02
                 (or kind = "charuco", rows/cols = squares, square_size_m, marker_size_m, dictionary = "DICT_4X4_50")
    [robot_poses]      path = "RobotPosesVec.txt"  format = "rowmajor4x4"   (or csv | json | jsonl with
                       [robot_poses.columns] pose_id?, tx, ty, tz, rotation = [...]; or matrix_field)
    [pose_pairing]     kind = "by_index"   (or "shared_filename_token", regex with a named group, group)
    [pose_convention]  transform = "t_base_tcp" | "t_tcp_base" | "t_world_tcp" | "t_tcp_world"
                       rotation_format = "quat_xyzw" | "quat_wxyz" | "euler_xyz_deg" | "euler_xyz_rad" |
                                         "euler_zyx_deg" | "euler_zyx_rad" | "axis_angle_rad" | "matrix4x4_row_major"
                       translation_units = "m" | "mm"

Conventions (the manifest's own, as calibration-rs applies them): a pose row is the gripper ("tcp")
pose in the base (``t_base_tcp``; ``t_tcp_*`` rows are inverted; a world frame plays the base), which
jcalib takes as the station's ``T_base_flange`` (the hand frame of the hand-eye unknown). Euler angles
are intrinsic, composed in the named order: ``xyz`` = Rx(a)·Ry(b)·Rz(c), ``zyx`` = Rz(a)·Ry(b)·Rx(c)
with the values in that order. Matrix rows: translation from the fourth column (``rowmajor4x4`` and
``matrix_field``), else from ``tx ty tz``; rotations are re-orthonormalised within 1e-3. ``by_index``:
pose row i pairs with view i (all cameras need as many images as there are poses); token pairing:
views are the sorted union of the tokens, poses pair by ``pose_id`` (unique). Chessboard ``rows`` and
``cols`` are inner corners (jcalib's ``rows``/``cols``); ChArUco's are squares (``squares_y``/``squares_x``,
OpenCV >= 4.6 layout). The manifest does not say eye-in-hand or eye-to-hand (that is the problem
config): hand-eye topologies need ``--mount``. Intrinsics are free (the manifest holds none).
Refused: other topologies (laser, Scheimpflug), other target kinds, ``_unresolved`` fields, a
camera id given twice, an image file given twice (for one camera or two), a token found in two files,
and paths (image lists, globs, the pose file) that resolve outside the manifest's folder unless
``allow_outside=true``. Pose rows without an image (token pairing) are left out with a note naming
them. The pairing regex runs in linear time (:mod:`jcalib.io.importers.pattern`: the Rust crate's
syntax, without look-around or back-references). Numbers are strict: ``rows = 7.9`` or ``"7"`` is
refused, as are non-finite pose values.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import (
    exp_so3,
    invert,
    make_pose,
    matrix_from_quat,
    rot_x,
    rot_y,
    rot_z,
)
from jcalib.io.importers.common import (
    ImportedStation,
    cell_entries_for_mount,
    check_options,
    integer,
    natural_key,
    number,
    pose_from_matrix,
    resolve_source,
    write_session,
)
from jcalib.io.importers.source import (
    ALLOW_OUTSIDE_HELP,
    SourceFolder,
    flag_option,
    parse_toml,
)

FORMAT = "calibration-rs"
OPTIONS = {"camera_model": "lens model of every camera (default opencv5)", "target": "target id (default board)",
           "allow_outside": ALLOW_OUTSIDE_HELP}
TOPOLOGIES = ("planar_intrinsics", "single_cam_handeye", "rig_extrinsics", "rig_handeye")
ROTATION_LEN = {"quat_xyzw": 4, "quat_wxyz": 4, "euler_xyz_deg": 3, "euler_xyz_rad": 3, "euler_zyx_deg": 3,
                "euler_zyx_rad": 3, "axis_angle_rad": 3, "matrix4x4_row_major": 16}
TRANSFORMS = ("t_base_tcp", "t_tcp_base", "t_world_tcp", "t_tcp_world")


def rotation_from_values(fmt: str, v: np.ndarray, where: str) -> np.ndarray:
    """(3, 3) rotation from the manifest's ``rotation_format`` values."""
    if fmt not in ROTATION_LEN:
        raise BadInputError(f"{where}: rotation_format {fmt!r} unknown; expected one of {', '.join(ROTATION_LEN)}")
    if v.shape != (ROTATION_LEN[fmt],) or not np.all(np.isfinite(v)):
        raise BadInputError(f"{where}: rotation_format {fmt} needs {ROTATION_LEN[fmt]} finite values, got {v.tolist()}")
    if fmt.startswith("quat"):
        q = np.array([v[3], v[0], v[1], v[2]]) if fmt == "quat_xyzw" else v.copy()
        with np.errstate(over="ignore", invalid="ignore"):
            n = float(np.linalg.norm(q))
        if not abs(n - 1.0) <= 1e-3:
            raise BadInputError(f"{where}: quaternion {v.tolist()} has norm {n:.6f}, not 1 (wrong rotation_format?)")
        return matrix_from_quat(q / n)
    if fmt.startswith("euler"):
        a = np.deg2rad(v) if fmt.endswith("deg") else v
        if "xyz" in fmt:
            return rot_x(a[0]) @ rot_y(a[1]) @ rot_z(a[2])
        return rot_z(a[0]) @ rot_y(a[1]) @ rot_x(a[2])
    if fmt == "axis_angle_rad":
        return exp_so3(v)
    return pose_from_matrix(v, where)[:3, :3]


def _text(value: Any, where: str) -> str:
    if not isinstance(value, str) or not value:
        raise BadInputError(f"{where}: expected text, got {'nothing' if value is None else type(value).__name__}")
    return value


def _table(spec: dict, key: str, path: Path, required: bool = True) -> dict:
    v = spec.get(key)
    if v is None and not required:
        return {}
    if not isinstance(v, dict):
        raise BadInputError(f"{path}: [{key}]: expected a table, got {'nothing' if v is None else type(v).__name__}")
    return v


def _load_poses(spec: dict, folder: SourceFolder, path: Path) -> list[tuple[str | None, np.ndarray]]:
    """``(pose_id or None, T_base_flange)`` per pose row, in file order."""
    src, conv = _table(spec, "robot_poses", path), _table(spec, "pose_convention", path)
    if any(k not in conv for k in ("transform", "rotation_format", "translation_units")):
        raise BadInputError(f"{path}: pose_convention: give transform, rotation_format and translation_units "
                            "(the manifest has no defaults for them, nor does jcalib guess)")
    transform = _text(conv["transform"], f"{path}: pose_convention.transform")
    if transform not in TRANSFORMS:
        raise BadInputError(f"{path}: pose_convention.transform {transform[:40]!r}; expected one of {', '.join(TRANSFORMS)}")
    units_name = _text(conv["translation_units"], f"{path}: pose_convention.translation_units")
    units = {"m": 1.0, "mm": 1e-3}.get(units_name)
    if units is None:
        raise BadInputError(f"{path}: pose_convention.translation_units {units_name[:40]!r}; expected m or mm")
    rfmt, inv = _text(conv["rotation_format"], f"{path}: pose_convention.rotation_format"), transform.startswith("t_tcp")
    fmt = _text(src.get("format"), f"{path}: robot_poses.format")
    pose_file = folder.file(src.get("path"), str(path), "robot_poses.path")
    rows: list[tuple[str | None, np.ndarray]] = []

    def from_matrix(values: Any, where: str) -> np.ndarray:
        if rfmt != "matrix4x4_row_major":
            raise BadInputError(f"{where}: 4x4 pose rows need pose_convention.rotation_format = matrix4x4_row_major")
        return pose_from_matrix(values, where, scale=units)

    if fmt == "rowmajor4x4":
        text = folder.read_text(pose_file, f"{path}: robot_poses.path")
        for i, line in enumerate(ln for ln in text.splitlines() if ln.strip()):
            try:
                vals = [float(t) for t in line.split()]
            except ValueError:
                raise BadInputError(f"{pose_file} row {i}: expected 16 numbers separated by spaces") from None
            if len(vals) != 16:
                raise BadInputError(f"{pose_file} row {i}: rowmajor4x4 expects 16 values per line, got {len(vals)}")
            rows.append((None, from_matrix(vals, f"{pose_file} row {i}")))
    elif fmt in ("csv", "json", "jsonl"):
        records = _records(folder, pose_file, fmt, path)
        field, cols = src.get("matrix_field"), src.get("columns")
        if field is not None:
            field = _text(field, f"{path}: robot_poses.matrix_field")
        else:
            cols = _columns(cols, path)
        for i, r in enumerate(records):
            where = f"{pose_file} row {i}"
            if field is not None:
                if field not in r:
                    raise BadInputError(f"{where}: matrix_field {field[:40]!r} not in this row")
                rows.append((None, from_matrix(r[field], where)))
                continue

            R = rotation_from_values(rfmt, np.array([_cell(r, c, fmt, where) for c in cols["rotation"]]), where)
            T = make_pose(R, np.array([_cell(r, cols[k], fmt, where) for k in ("tx", "ty", "tz")]) * units)
            pid = cols.get("pose_id")
            if pid is not None and pid not in r:
                raise BadInputError(f"{where}: pose_id column {pid[:40]!r} not found")
            rows.append((None if pid is None else _pose_id(r[pid], where), T))
    else:
        raise BadInputError(f"{path}: robot_poses.format {fmt[:40]!r}; expected rowmajor4x4, csv, json or jsonl")
    return [(pid, invert(T) if inv else T) for pid, T in rows]


def _cell(row: dict, name: str, fmt: str, where: str) -> float:
    """The number in column ``name`` of a pose row (CSV text parsed; JSON needs a number)."""
    if name not in row:
        raise BadInputError(f"{where}: column {name[:40]!r} not found")
    v = row[name]
    if fmt == "csv" and isinstance(v, str):
        try:
            v = float(v)
        except ValueError:
            raise BadInputError(f"{where}: column {name[:40]!r} is not a number") from None
    return number(v, f"{where}: column {name[:40]!r}")


def _pose_id(value: Any, where: str) -> str:
    if isinstance(value, bool) or not isinstance(value, (str, int)) or (isinstance(value, str) and len(value) > 200):
        raise BadInputError(f"{where}: pose_id: expected text or an integer")
    return str(value)


def _records(folder: SourceFolder, pose_file: Path, fmt: str, path: Path) -> list[dict]:
    """The rows of a csv / json / jsonl pose file, as mappings."""
    from jcalib.io.schema.reading import parse_json

    text = folder.read_text(pose_file, f"{path}: robot_poses.path")
    if fmt == "csv":
        try:
            records: Any = list(csv.DictReader(ln for ln in text.splitlines() if ln.strip()))
        except csv.Error as e:
            raise BadInputError(f"{pose_file}: not a CSV file ({e})") from None
        if any(None in r or any(v is None for v in r.values()) for r in records):
            raise BadInputError(f"{pose_file}: a row has more or fewer values than the header has columns")
    elif fmt == "json":
        records = parse_json(text, str(pose_file))
    else:
        records = [parse_json(ln, f"{pose_file} line {k + 1}") for k, ln in enumerate(text.splitlines()) if ln.strip()]
    if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
        raise BadInputError(f"{pose_file}: expected one object per pose")
    return records


def _columns(cols: Any, path: Path) -> dict:
    if not isinstance(cols, dict) or any(k not in cols for k in ("tx", "ty", "tz", "rotation")):
        raise BadInputError(f"{path}: robot_poses.columns needs tx, ty, tz and rotation (column names)")
    for k in ("tx", "ty", "tz", "pose_id"):
        if k in cols:
            _text(cols[k], f"{path}: robot_poses.columns.{k}")
    rot = cols["rotation"]
    if not isinstance(rot, list) or not all(isinstance(c, str) and c for c in rot):
        raise BadInputError(f"{path}: robot_poses.columns.rotation: expected a list of column names")
    return cols


def _images(cam: dict, folder: SourceFolder, where: str) -> list[Path]:
    imgs = cam.get("images")
    if not isinstance(imgs, dict) or imgs.get("kind") not in ("glob", "list"):
        raise BadInputError(f"{where}.images: expected {{kind = \"glob\", pattern}} or {{kind = \"list\", paths}}")
    if imgs["kind"] == "glob":
        pattern = imgs.get("pattern")
        paths = sorted(folder.glob(pattern, where, "images.pattern"), key=lambda p: natural_key(str(p)))
        if not paths:
            raise BadInputError(f"{where}.images: pattern {str(pattern)[:200]!r} matched no file under {folder.root}")
        return paths
    listed = imgs.get("paths")
    if not isinstance(listed, list) or not listed:
        raise BadInputError(f"{where}.images.paths: expected a list of image paths")
    return [folder.file(p, where, f"images.paths[{k}]") for k, p in enumerate(listed)]


def _target(t: Any, path: Path) -> dict:
    if not isinstance(t, dict):
        raise BadInputError(f"{path}: [target] missing")
    kind = t.get("kind")
    where = f"{path}: target"
    need = {"chessboard": ("rows", "cols", "square_size_m"),
            "charuco": ("rows", "cols", "square_size_m", "marker_size_m", "dictionary")}.get(kind if isinstance(kind, str) else "")
    if need is None:
        raise BadInputError(f"{where}: kind {str(kind)[:40]!r} has no jcalib target type (chessboard and charuco have)")
    missing = [k for k in need if k not in t]
    if missing:
        raise BadInputError(f"{where}: {kind} needs {', '.join(missing)}")
    cols, rows = integer(t["cols"], f"{where}.cols"), integer(t["rows"], f"{where}.rows")
    square = number(t["square_size_m"], f"{where}.square_size_m", positive=True)
    if kind == "chessboard":
        return {"type": "checkerboard", "cols": cols, "rows": rows, "square": square}
    return {"type": "charuco", "squares_x": cols, "squares_y": rows, "square": square,
            "marker": number(t["marker_size_m"], f"{where}.marker_size_m", positive=True),
            "dictionary": _text(t["dictionary"], f"{where}.dictionary")[:64]}


#: Longest pairing pattern accepted (characters).
MAX_PATTERN = 1000


def filename_pattern(raw: str, where: str):
    """The pairing regex compiled by RE2 (``google-re2``): time linear in the file name whatever the pattern,
    the syntax of the Rust ``regex`` crate calibration-rs uses (named groups ``(?<name>...)``, no
    look-around or back-references). Raises :class:`BadInputError` naming ``where``."""
    import re2

    if len(raw) > MAX_PATTERN:
        raise BadInputError(f"{where}: {len(raw)} characters; a file-name pattern has at most {MAX_PATTERN}")
    options = re2.Options()
    options.log_errors = False  # the reason goes into our message, not to stderr
    try:
        return re2.compile(raw, options=options)
    except re2.error as e:
        why = e.args[0].decode(errors="replace") if e.args and isinstance(e.args[0], bytes) else str(e)
        raise BadInputError(f"{where}: not a regular expression RE2 (the Rust regex crate's syntax) accepts: "
                            f"{why[:120]}") from None


def _token_views(spec: dict, path: Path, images: dict[str, list[Path]], poses: list, handeye: bool,
                 notes: list[str]) -> list:
    """Views paired by a shared file-name token (a named group of the pairing regex)."""
    pp = spec["pose_pairing"]
    raw = pp.get("regex")
    if not isinstance(raw, str):
        raise BadInputError(f"{path}: pose_pairing.regex: expected a regular expression (text)")
    rx = filename_pattern(raw, f"{path}: pose_pairing.regex")
    group = pp.get("group")
    if not isinstance(group, str) or group not in rx.groupindex:
        raise BadInputError(f"{path}: pose_pairing.group: the regex has no named group {str(group)[:40]!r} "
                            f"(it has: {', '.join(rx.groupindex) or 'none'})")
    by_token: dict[str, dict[str, Path]] = {}
    for c, files in images.items():
        for f in files:
            m = rx.search(f.name)
            tok = None if m is None else m.group(group)
            if tok is None:
                raise BadInputError(f"{path}: camera {c}: {f.name} does not match the pairing regex")
            slot = by_token.setdefault(tok, {})
            if c in slot:
                raise BadInputError(f"{path}: camera {c}: token {tok[:40]!r} from two files ({slot[c].name}, {f.name})")
            slot[c] = f
    pose_by_id: dict[str, np.ndarray] = {}
    for pid, T in poses:
        if pid is None:
            raise BadInputError(f"{path}: shared_filename_token pairing needs robot_poses.columns.pose_id")
        if pid in pose_by_id:
            raise BadInputError(f"{path}: duplicate pose_id {pid[:40]!r}")
        pose_by_id[pid] = T
    views = []
    for tok in sorted(by_token, key=natural_key):
        if handeye and tok not in pose_by_id:
            raise BadInputError(f"{path}: no pose row with pose_id {tok[:40]!r} (a view of the cameras has it)")
        views.append((tok, by_token[tok], pose_by_id.get(tok)))
    unused = sorted(set(pose_by_id) - set(by_token), key=natural_key)
    if unused:
        notes.append(f"{len(unused)} pose row(s) without an image left out: pose_id "
                     f"{', '.join(u[:20] for u in unused[:10])}{' ...' if len(unused) > 10 else ''}")
    return views


def _check_unique(images: dict[str, list[Path]], path: Path) -> None:
    seen: dict[Path, str] = {}
    for c, files in images.items():
        for f in files:
            real = f.resolve()
            if real in seen:
                raise BadInputError(f"{path}: image {f.name} is given twice (camera {seen[real]} and camera {c}); "
                                    "each view needs its own image file")
            seen[real] = c


def import_source(source: str | os.PathLike, out: str | os.PathLike, *, mount: str | None = None, **options: Any):
    """Import a calibration-rs ``dataset.toml`` (or its folder) into session ``out`` (module docstring).

    Raises:
        BadInputError: an invalid or unsupported manifest, a pairing that does not match, a path outside
            the manifest's folder, or a hand-eye topology without ``mount``.
    """
    check_options(FORMAT, options, OPTIONS)
    path = resolve_source(source, "dataset.toml", f"import {FORMAT}")
    folder = SourceFolder(path.parent, FORMAT, flag_option(options, "allow_outside", FORMAT))
    spec = parse_toml(folder.read_text(path, f"import {FORMAT}: manifest", "yaml"), str(path))
    if spec.get("version", 1) != 1:
        raise BadInputError(f"{path}: version: this importer reads version 1")
    if spec.get("_unresolved"):
        raise BadInputError(f"{path}: _unresolved lists fields to resolve: resolve them in the manifest first")
    topo = spec.get("topology")
    if topo not in TOPOLOGIES:
        raise BadInputError(f"{path}: topology {str(topo)[:40]!r}; jcalib imports {', '.join(TOPOLOGIES)}")
    cams = spec.get("cameras")
    if not isinstance(cams, list) or not cams or not all(isinstance(c, dict) and isinstance(c.get("id"), str)
                                                         for c in cams):
        raise BadInputError(f"{path}: [[cameras]] with an id (text) each is required")
    ids = [c["id"] for c in cams]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise BadInputError(f"{path}: camera id {dup[0][:40]!r} given twice in [[cameras]]; give each camera its own id")
    if topo.startswith("single") and len(cams) != 1:
        raise BadInputError(f"{path}: single_cam_handeye has exactly one camera, got {len(cams)}")
    notes = []
    for c in cams:
        if c.get("laser_images") is not None:
            raise BadInputError(f"{path}: camera {c['id'][:40]}: laser_images belong to laser topologies, not imported")
        if c.get("roi_xywh") is not None:
            notes.append(f"camera {c['id'][:40]}: roi_xywh ignored (jcalib detects in the whole image; pixels are "
                         "in the full-image frame either way)")
    images = {c["id"]: _images(c, folder, f"{path}: camera {c['id'][:40]}") for c in cams}
    _check_unique(images, path)
    handeye = topo.endswith("handeye")
    poses = _load_poses(spec, folder, path) if handeye else []
    pairing = _table(spec, "pose_pairing", path, required=False).get("kind", "by_index" if not handeye else None)
    if pairing == "by_index":
        counts = {c: len(v) for c, v in images.items()}
        if len(set(counts.values())) != 1 or (handeye and len(poses) != next(iter(counts.values()))):
            raise BadInputError(f"{path}: by_index pairing needs as many images per camera as poses: images "
                                f"{counts}" + (f", poses {len(poses)}" if handeye else ""))
        views = [(str(i), {c: v[i] for c, v in images.items()}, poses[i][1] if handeye else None)
                 for i in range(next(iter(counts.values())))]
    elif pairing == "shared_filename_token":
        views = _token_views(spec, path, images, poses, handeye, notes)
    else:
        raise BadInputError(f"{path}: pose_pairing.kind {str(pairing)[:40]!r}; expected by_index or shared_filename_token")
    model = str(options.get("camera_model", "opencv5"))
    if handeye:
        cam_mount, tgt_mount = cell_entries_for_mount(mount, FORMAT, f"topology {topo} does not say whether the "
                                                      "camera rides on the robot (the manifest leaves it to the problem config)")
    else:
        if mount is not None:
            raise BadInputError(f"import {FORMAT}: --mount given, but topology {topo} has no robot")
        cam_mount = tgt_mount = "free"
    tgt_id = str(options.get("target", "board"))
    cell: dict[str, Any] = {"schema": "jcalib.cell/1",
                            "cameras": {c: {"model": model, "mount": cam_mount} for c in images},
                            "targets": {tgt_id: {**_target(spec.get("target"), path), "mount": tgt_mount}}}
    if handeye:
        cell["robot"] = {}
    stations = [ImportedStation(id=f"s{k:03d}", T_base_flange=T, images=imgs, source={"view": tok})
                for k, (tok, imgs, T) in enumerate(views)]
    conv = spec.get("pose_convention") or {}
    conventions = ("no robot" if not handeye else
                   f"{conv.get('transform')} rows as T_base_flange (t_tcp_* inverted), {conv.get('rotation_format')} "
                   f"(Euler intrinsic, named order), translation {conv.get('translation_units')} -> m; pairing {pairing}")
    return write_session(out, cell, stations, fmt=FORMAT, source=path, conventions=conventions, notes=tuple(notes),
                         source_root=folder.root)
