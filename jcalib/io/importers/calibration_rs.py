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
Refused: other topologies (laser, Scheimpflug), other target kinds, ``_unresolved`` fields.
"""

from __future__ import annotations

import csv
import glob as globlib
import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.geometry.se3 import invert, make_pose, matrix_from_quat, rot_x, rot_y, rot_z, exp_so3
from jcalib.io.importers.common import (
    ImportedStation,
    cell_entries_for_mount,
    check_options,
    natural_key,
    pose_from_matrix,
    resolve_source,
    write_session,
)

FORMAT = "calibration-rs"
OPTIONS = {"camera_model": "lens model of every camera (default opencv5)", "target": "target id (default board)"}
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
        n = float(np.linalg.norm(q))
        if abs(n - 1.0) > 1e-3:
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


def _load_poses(spec: dict, root: Path) -> list[tuple[str | None, np.ndarray]]:
    """``(pose_id or None, T_base_flange)`` per pose row, in file order."""
    src, conv = spec.get("robot_poses"), spec.get("pose_convention")
    if not isinstance(src, dict) or "path" not in src or "format" not in src:
        raise BadInputError(f"{root}: robot_poses: a hand-eye topology needs [robot_poses] path and format")
    if not isinstance(conv, dict) or any(k not in conv for k in ("transform", "rotation_format", "translation_units")):
        raise BadInputError(f"{root}: pose_convention: give transform, rotation_format and translation_units "
                            "(the manifest has no defaults for them, nor does jcalib guess)")
    if conv["transform"] not in TRANSFORMS:
        raise BadInputError(f"{root}: pose_convention.transform {conv['transform']!r}; expected one of {', '.join(TRANSFORMS)}")
    units = {"m": 1.0, "mm": 1e-3}.get(conv["translation_units"])
    if units is None:
        raise BadInputError(f"{root}: pose_convention.translation_units {conv['translation_units']!r}; expected m or mm")
    rfmt, inv = str(conv["rotation_format"]), conv["transform"].startswith("t_tcp")
    path = Path(src["path"]) if Path(src["path"]).is_absolute() else root / src["path"]
    if not path.is_file():
        raise BadInputError(f"{root}: robot_poses.path: {path} does not exist")
    fmt, text = src["format"], path.read_text(encoding="utf-8")
    rows: list[tuple[str | None, np.ndarray]] = []

    def from_matrix(values: Any, where: str) -> np.ndarray:
        if rfmt != "matrix4x4_row_major":
            raise BadInputError(f"{where}: 4x4 pose rows need pose_convention.rotation_format = matrix4x4_row_major")
        return pose_from_matrix(values, where, scale=units)

    if fmt == "rowmajor4x4":
        for i, line in enumerate(ln for ln in text.splitlines() if ln.strip()):
            try:
                vals = [float(t) for t in line.split()]
            except ValueError:
                raise BadInputError(f"{path} row {i}: not 16 numbers: {line[:80]!r}") from None
            if len(vals) != 16:
                raise BadInputError(f"{path} row {i}: rowmajor4x4 expects 16 values per line, got {len(vals)}")
            rows.append((None, from_matrix(vals, f"{path} row {i}")))
    elif fmt in ("csv", "json", "jsonl"):
        if fmt == "csv":
            records = list(csv.DictReader(ln for ln in text.splitlines() if ln.strip()))
        elif fmt == "json":
            records = json.loads(text)
        else:
            records = [json.loads(ln) for ln in text.splitlines() if ln.strip()]
        if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
            raise BadInputError(f"{path}: expected one object per pose")
        field, cols = src.get("matrix_field"), src.get("columns")
        for i, r in enumerate(records):
            where = f"{path} row {i}"
            if field is not None:
                if field not in r:
                    raise BadInputError(f"{where}: matrix_field {field!r} not in this row")
                rows.append((None, from_matrix(r[field], where)))
                continue
            if not isinstance(cols, dict) or any(k not in cols for k in ("tx", "ty", "tz", "rotation")):
                raise BadInputError(f"{path}: robot_poses.columns needs tx, ty, tz and rotation (column names)")

            def num(name: str) -> float:
                if name not in r:
                    raise BadInputError(f"{where}: column {name!r} not found")
                try:
                    return float(r[name])
                except (TypeError, ValueError):
                    raise BadInputError(f"{where}: column {name!r}: {r[name]!r} is not a number") from None

            R = rotation_from_values(rfmt, np.array([num(c) for c in cols["rotation"]]), where)
            T = make_pose(R, np.array([num(cols[k]) for k in ("tx", "ty", "tz")]) * units)
            pid = cols.get("pose_id")
            rows.append((None if pid is None else str(r.get(pid)), T))
    else:
        raise BadInputError(f"{root}: robot_poses.format {fmt!r}; expected rowmajor4x4, csv, json or jsonl")
    return [(pid, invert(T) if inv else T) for pid, T in rows]


def _images(cam: dict, root: Path, where: str) -> list[Path]:
    imgs = cam.get("images")
    if not isinstance(imgs, dict) or imgs.get("kind") not in ("glob", "list"):
        raise BadInputError(f"{where}.images: expected {{kind = \"glob\", pattern}} or {{kind = \"list\", paths}}")
    if imgs["kind"] == "glob":
        pattern = str(imgs.get("pattern", ""))
        full = pattern if Path(pattern).is_absolute() else str(root / pattern)
        paths = sorted((Path(p) for p in globlib.glob(full) if Path(p).is_file()), key=lambda p: natural_key(str(p)))
        if not paths:
            raise BadInputError(f"{where}.images: pattern {pattern!r} matched no file under {root}")
        return paths
    paths = [Path(p) if Path(p).is_absolute() else root / p for p in imgs.get("paths", [])]
    for p in paths:
        if not p.is_file():
            raise BadInputError(f"{where}.images: {p} does not exist")
    return paths


def _target(t: Any, root: Path) -> dict:
    if not isinstance(t, dict):
        raise BadInputError(f"{root}: [target] missing")
    kind = t.get("kind")
    try:
        if kind == "chessboard":
            return {"type": "checkerboard", "cols": int(t["cols"]), "rows": int(t["rows"]), "square": float(t["square_size_m"])}
        if kind == "charuco":
            return {"type": "charuco", "squares_x": int(t["cols"]), "squares_y": int(t["rows"]),
                    "square": float(t["square_size_m"]), "marker": float(t["marker_size_m"]),
                    "dictionary": str(t["dictionary"])}
    except KeyError as e:
        raise BadInputError(f"{root}: [target] {kind} needs {e.args[0]}") from None
    raise BadInputError(f"{root}: target kind {kind!r} has no jcalib target type (chessboard and charuco have)")


def import_source(source: str | os.PathLike, out: str | os.PathLike, *, mount: str | None = None, **options: Any):
    """Import a calibration-rs ``dataset.toml`` (or its folder) into session ``out`` (module docstring).

    Raises:
        BadInputError: an invalid or unsupported manifest, a pairing that does not match, or a hand-eye
            topology without ``mount``.
    """
    import tomllib

    check_options(FORMAT, options, OPTIONS)
    path = resolve_source(source, "dataset.toml", f"import {FORMAT}")
    root = path.parent
    try:
        spec = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise BadInputError(f"{path}: not a TOML manifest ({e})") from None
    if spec.get("version", 1) != 1:
        raise BadInputError(f"{path}: version {spec.get('version')!r}; this importer reads version 1")
    if spec.get("_unresolved"):
        raise BadInputError(f"{path}: _unresolved lists {spec['_unresolved']}: resolve them in the manifest first")
    topo = spec.get("topology")
    if topo not in TOPOLOGIES:
        raise BadInputError(f"{path}: topology {topo!r}; jcalib imports {', '.join(TOPOLOGIES)}")
    cams = spec.get("cameras")
    if not isinstance(cams, list) or not cams or not all(isinstance(c, dict) and "id" in c for c in cams):
        raise BadInputError(f"{path}: [[cameras]] with an id each is required")
    if topo.startswith("single") and len(cams) != 1:
        raise BadInputError(f"{path}: single_cam_handeye has exactly one camera, got {len(cams)}")
    notes = []
    for c in cams:
        if c.get("laser_images") is not None:
            raise BadInputError(f"{path}: camera {c['id']}: laser_images belong to laser topologies, not imported")
        if c.get("roi_xywh") is not None:
            notes.append(f"camera {c['id']}: roi_xywh ignored (jcalib detects in the whole image; pixels are in "
                         "the full-image frame either way)")
    images = {str(c["id"]): _images(c, root, f"{path}: camera {c['id']}") for c in cams}
    handeye = topo.endswith("handeye")
    poses = _load_poses(spec, root) if handeye else []
    pairing = (spec.get("pose_pairing") or {}).get("kind", "by_index" if not handeye else None)
    if pairing == "by_index":
        counts = {c: len(v) for c, v in images.items()}
        if len(set(counts.values())) != 1 or (handeye and len(poses) != next(iter(counts.values()))):
            raise BadInputError(f"{path}: by_index pairing needs as many images per camera as poses: images "
                                f"{counts}" + (f", poses {len(poses)}" if handeye else ""))
        views = [(str(i), {c: v[i] for c, v in images.items()}, poses[i][1] if handeye else None)
                 for i in range(next(iter(counts.values())))]
    elif pairing == "shared_filename_token":
        pp = spec["pose_pairing"]
        regex = re.sub(r"\(\?<(?![=!])", "(?P<", str(pp.get("regex", "")))  # Rust (?<name>) -> Python
        try:
            rx = re.compile(regex)
        except re.error as e:
            raise BadInputError(f"{path}: pose_pairing.regex {pp.get('regex')!r}: {e}") from None
        group = str(pp.get("group", ""))
        if group not in rx.groupindex:
            raise BadInputError(f"{path}: pose_pairing.regex has no named group {group!r}")
        by_token: dict[str, dict[str, Path]] = {}
        for c, files in images.items():
            for f in files:
                m = rx.search(f.name)
                if m is None or m.group(group) is None:
                    raise BadInputError(f"{path}: camera {c}: {f.name} does not match the pairing regex")
                slot = by_token.setdefault(m.group(group), {})
                if c in slot:
                    raise BadInputError(f"{path}: camera {c}: token {m.group(group)!r} from two files")
                slot[c] = f
        pose_by_id: dict[str, np.ndarray] = {}
        for pid, T in poses:
            if pid is None:
                raise BadInputError(f"{path}: shared_filename_token pairing needs robot_poses.columns.pose_id")
            if pid in pose_by_id:
                raise BadInputError(f"{path}: duplicate pose_id {pid!r}")
            pose_by_id[pid] = T
        views = []
        for tok in sorted(by_token):
            if handeye and tok not in pose_by_id:
                raise BadInputError(f"{path}: no pose row with pose_id {tok!r} (a view of the cameras has it)")
            views.append((tok, by_token[tok], pose_by_id.get(tok)))
    else:
        raise BadInputError(f"{path}: pose_pairing.kind {pairing!r}; expected by_index or shared_filename_token")
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
    return write_session(out, cell, stations, fmt=FORMAT, source=path, conventions=conventions, notes=tuple(notes))
