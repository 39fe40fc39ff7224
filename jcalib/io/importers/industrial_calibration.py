"""ROS-Industrial ``industrial_calibration`` extrinsic hand-eye data sets -> capture session.

(Its kinematic-calibration data sets, ``measurements.yaml``, are read by
:mod:`jcalib.io.importers.industrial_calibration_kinematic`, to which :func:`import_source` hands them.)

Layout (the tool's ``docs/extrinsic_hand_eye_calibration.md`` and ``examples/data/test_set_*``)::

    cal_data.yaml        data: [{image: images/0.png, pose: poses/0.yaml}, ...]   (paths relative to it)
                         intrinsics: {fx, fy, cx, cy}          (px; pinhole, no distortion)
                         camera_mount_to_camera_guess, target_mount_to_target_guess: {x, y, z, qx, qy, qz, qw}
                         target_finder: {type: ..., ...}      (or a target_finder.yaml beside it)
                         static_camera: true | false
                         homography_threshold: px
    poses/N.yaml         x, y, z (m), qx, qy, qz, qw

Conventions assumed (those of the tool's ``ExtrinsicHandEyeProblem2D3D``):

- A pose file is the pose of the moving mount in the robot base, metres, quaternion given by named
  fields ``qx qy qz qw`` (Hamilton): ``static_camera: false`` -> it is ``to_camera_mount``, the camera
  rides on the flange (``mount: flange``, target fixed: ``mount: base``); ``static_camera: true`` -> it
  is ``to_target_mount``, the target rides on the flange (camera ``mount: base``). Either way it is the
  station's ``T_base_flange``. A missing ``static_camera`` is refused (no guess).
- ``intrinsics`` are those of an undistorted pinhole camera that the tool holds fixed: the camera gets
  ``model: pinhole`` with ``intrinsics: {K, dist: []}`` and ``fix: [fx, fy, cx, cy]`` (option
  ``intrinsics=initial`` frees them; without intrinsics in the source they are free and ``model``
  defaults to ``opencv5``). The ``*_guess`` poses are only recorded in ``session.json``
  (``imported_from.guesses``): jcalib starts from its own closed forms.
- Target finders: ``CharucoGridTargetFinder`` (``cv::aruco::CharucoBoard::create(cols, rows,
  chessboard_dim, aruco_marker_dim, dictionary)``, OpenCV's pre-4.6 API, hence ``legacy: true``;
  ``dictionary`` is OpenCV's integer id), ``ModifiedCircleGridTargetFinder`` (``rows x cols`` dots,
  ``spacing`` m between centres, the larger origin dot at the bottom left of the print with x along
  the bottom row and y up: imported as a symmetric circle grid with ``origin_dot: bottom_left``, whose
  point k is the tool's point k and whose labels follow the dot at any camera roll; its frame differs
  from the tool's by a fixed rigid motion that ``T_base_<target>`` absorbs). ``ArucoGridTargetFinder``
  (marker corners of an ArUco GridBoard) is refused: jcalib has no GridBoard target type yet.

Image and pose paths must resolve inside the folder of ``cal_data.yaml`` (symlinks followed) unless
``allow_outside=true``; an image listed twice is refused; numbers are strict (``rows:
7.9`` or ``"7"`` refused) and finite. A malformed ``*_guess`` (unused) is left out with a note.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from jcalib.errors import BadInputError
from jcalib.io.importers.common import (
    ImportedStation,
    check_options,
    integer,
    number,
    pose_from_xyz_quat,
    resolve_source,
    write_session,
)
from jcalib.io.importers.industrial_calibration_kinematic import OPTIONS as KINEMATIC_OPTIONS
from jcalib.io.importers.source import ALLOW_OUTSIDE_HELP, SourceFolder, flag_option

FORMAT = "industrial-calibration"
#: Options of the extrinsic hand-eye data sets (cal_data.yaml).
EXTRINSIC_OPTIONS = {
    "intrinsics": "held (default: as the tool, which holds them fixed) or initial (start values, estimated)",
    "camera_model": "lens model when the source has no intrinsics (default opencv5)",
    "camera": "camera id in the session (default cam0)",
    "target": "target id in the session (default board; kinematic data sets: target)",
    "allow_outside": ALLOW_OUTSIDE_HELP,
}
#: Every option: those of the kinematic data sets (measurements.yaml) too.
OPTIONS = {**{k: f"kinematic data sets (measurements.yaml): {v}" for k, v in KINEMATIC_OPTIONS.items()},
           **EXTRINSIC_OPTIONS}
_POSE_KEYS = ("x", "y", "z", "qx", "qy", "qz", "qw")


def _pose(entry: Any, where: str):
    if not isinstance(entry, dict) or any(k not in entry for k in _POSE_KEYS):
        raise BadInputError(f"{where}: expected a pose with keys {', '.join(_POSE_KEYS)} (m, quaternion)"
                            + ("" if not isinstance(entry, dict) else
                               f"; missing {', '.join(k for k in _POSE_KEYS if k not in entry)}"))
    return pose_from_xyz_quat([entry["x"], entry["y"], entry["z"]], [entry[k] for k in ("qx", "qy", "qz", "qw")], where)


def _dictionary_name(value: Any, where: str) -> str:
    """OpenCV's predefined dictionary name for its integer id (e.g. 10 -> DICT_6X6_250)."""
    import cv2

    from jcalib.geometry.targets import ARUCO_DICTIONARIES

    names = {int(getattr(cv2.aruco, n)): n for n in ARUCO_DICTIONARIES if hasattr(cv2.aruco, n)}
    if isinstance(value, bool) or not isinstance(value, int) or value not in names:
        raise BadInputError(f"{where}: dictionary: expected an OpenCV predefined dictionary id "
                            f"({min(names)}..{max(names)}), got {str(value)[:40]!r}")
    return names[value]


def target_entry(finder: Any, where: str) -> dict:
    """The cell-spec target entry (geometry only) of an industrial_calibration target finder config."""
    if not isinstance(finder, dict) or not isinstance(finder.get("type"), str):
        raise BadInputError(f"{where}: expected a target finder config with a 'type' (text)")
    kind = finder["type"].split("::")[-1].removesuffix("Plugin")

    def need(*keys):
        missing = [k for k in keys if k not in finder]
        if missing:
            raise BadInputError(f"{where}: {kind} needs {', '.join(missing)}")
        return [finder[k] for k in keys]

    if kind == "CharucoGridTargetFinder":
        rows, cols, square, marker, dictionary = need("rows", "cols", "chessboard_dim", "aruco_marker_dim", "dictionary")
        return {"type": "charuco", "squares_x": integer(cols, f"{where}.cols"), "squares_y": integer(rows, f"{where}.rows"),
                "square": number(square, f"{where}.chessboard_dim", positive=True),
                "marker": number(marker, f"{where}.aruco_marker_dim", positive=True),
                "dictionary": _dictionary_name(dictionary, where), "legacy": True}
    if kind == "ModifiedCircleGridTargetFinder":
        rows, cols, spacing = need("rows", "cols", "spacing")
        return {"type": "circles", "cols": integer(cols, f"{where}.cols"), "rows": integer(rows, f"{where}.rows"),
                "spacing": number(spacing, f"{where}.spacing", positive=True), "origin_dot": "bottom_left"}
    if kind == "ArucoGridTargetFinder":
        raise BadInputError(f"{where}: ArucoGridTargetFinder (the corners of an ArUco GridBoard's markers) has no "
                            "jcalib target type yet; detect such boards elsewhere, or use a ChArUco board "
                            "(CharucoGridTargetFinder), a chessboard or a circle grid")
    raise BadInputError(f"{where}: unknown target finder {finder['type'][:80]!r}; expected CharucoGridTargetFinder, "
                        "ModifiedCircleGridTargetFinder or ArucoGridTargetFinder")


def import_source(source: str | os.PathLike, out: str | os.PathLike, *, mount: str | None = None,
                  **options: Any):
    """Import an industrial_calibration data set (``cal_data.yaml`` or its folder) into session ``out``.

    Args:
        mount: must agree with ``static_camera`` when given (``flange`` for false, ``base`` for true).
        options: see ``OPTIONS``.
    Returns:
        :class:`jcalib.io.importers.common.ImportSummary`.
    Raises:
        BadInputError: a missing or malformed field, file or image, an unsupported target, or ``mount``
            contradicting ``static_camera``.
    """
    from jcalib.io.importers import industrial_calibration_kinematic as kinematic

    if kinematic.is_kinematic_source(source):  # the kinematic-calibration data set (measurements.yaml)
        return kinematic.import_source(source, out, mount=mount, **options)
    check_options(FORMAT, options, EXTRINSIC_OPTIONS)
    path = resolve_source(source, "cal_data.yaml", f"import {FORMAT}")
    root = path.parent
    folder = SourceFolder(root, FORMAT, flag_option(options, "allow_outside", FORMAT))
    cfg = folder.read_yaml(path, f"import {FORMAT}: cal_data")
    if not isinstance(cfg, dict) or not isinstance(cfg.get("data"), list):
        raise BadInputError(f"{path}: expected a mapping with 'data: [{{image: ..., pose: ...}}, ...]'")
    if not isinstance(cfg.get("static_camera"), bool):
        raise BadInputError(f"{path}: static_camera: expected true (camera fixed, target on the flange) or false "
                            f"(camera on the flange), got {_kind(cfg.get('static_camera'))}; the pose files mean a "
                            "different mount in each case, so it is not guessed")
    cam_mount = "base" if cfg["static_camera"] else "flange"
    if mount is not None and mount != cam_mount:
        raise BadInputError(f"{path}: static_camera: {str(cfg['static_camera']).lower()} puts the camera on the "
                            f"{cam_mount}, but --mount {str(mount)[:40]} was given")
    finder = cfg.get("target_finder")
    if finder is None and (root / "target_finder.yaml").exists():
        finder = folder.read_yaml(folder.file("target_finder.yaml", str(path), "target_finder.yaml beside it"),
                                  f"import {FORMAT}: target finder")
    if finder is None:
        raise BadInputError(f"{path}: no target_finder (in cal_data.yaml or a target_finder.yaml beside it)")
    target = target_entry(finder, f"{path}: target_finder")
    cam_id = str(options.get("camera", "cam0"))
    tgt_id = str(options.get("target", "board"))
    intr = cfg.get("intrinsics")
    if intr is None and (root / "camera_intr.yaml").exists():
        doc = folder.read_yaml(folder.file("camera_intr.yaml", str(path), "camera_intr.yaml beside it"),
                               f"import {FORMAT}: intrinsics")
        intr = doc.get("intrinsics") if isinstance(doc, dict) else None
    camera: dict[str, Any] = {"model": str(options.get("camera_model", "opencv5")), "mount": cam_mount}
    held = str(options.get("intrinsics", "held"))
    if held not in ("held", "initial"):
        raise BadInputError(f"import {FORMAT}: intrinsics: expected held or initial, got {held[:40]!r}")
    if intr is not None:
        if not isinstance(intr, dict) or any(k not in intr for k in ("fx", "fy", "cx", "cy")):
            raise BadInputError(f"{path}: intrinsics: expected {{fx, fy, cx, cy}} (px)")
        fx, fy = (number(intr[k], f"{path}: intrinsics.{k}", positive=True) for k in ("fx", "fy"))
        cx, cy = (number(intr[k], f"{path}: intrinsics.{k}") for k in ("cx", "cy"))
        camera = {"model": str(options.get("camera_model", "pinhole")), "mount": cam_mount,
                  "intrinsics": {"K": [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], "dist": []}}
        if held == "held":
            camera["fix"] = ["fx", "fy", "cx", "cy"]
    cell = {
        "schema": "jcalib.cell/1",
        "cameras": {cam_id: camera},
        "targets": {tgt_id: {**target, "mount": "flange" if cam_mount == "base" else "base"}},
        "robot": {},
    }
    stations = []
    seen: dict[Path, int] = {}
    for i, item in enumerate(cfg["data"]):
        where = f"{path}: data[{i}]"
        if not isinstance(item, dict) or "image" not in item or "pose" not in item:
            raise BadInputError(f"{where}: expected {{image: PATH, pose: PATH}}")
        image = folder.file(item["image"], where, "image")
        pose_file = folder.file(item["pose"], where, "pose")
        if image in seen:
            raise BadInputError(f"{where}: image {item['image'][:200]!r} is the same file as data[{seen[image]}]'s; "
                                "an image is one view, with one pose: remove the repeated entry")
        seen[image] = i
        T = _pose(folder.read_yaml(pose_file, f"{where}: pose"), f"{pose_file}")
        stations.append(ImportedStation(id=f"s{i:03d}", T_base_flange=T, images={cam_id: image},
                                        source={"image": item["image"], "pose": item["pose"]}))
    notes = []
    guesses = {}
    for k in ("camera_mount_to_camera_guess", "target_mount_to_target_guess"):
        if k in cfg:
            try:
                _pose(cfg[k], f"{path}: {k}")
                guesses[k] = {n: float(cfg[k][n]) for n in _POSE_KEYS}
            except BadInputError as e:
                notes.append(f"{k} left out (not used by jcalib): {e}")
    conventions = (f"pose files = T_base_flange of the {'target' if cfg['static_camera'] else 'camera'} mount, m, "
                   "quaternion fields qx qy qz qw (Hamilton); intrinsics pinhole without distortion"
                   + (" held fixed" if intr is not None and held == "held" else ""))
    if "homography_threshold" in cfg:
        thr = cfg["homography_threshold"]
        shown = f"{float(thr):g} px" if isinstance(thr, (int, float)) and not isinstance(thr, bool) else "(not a number)"
        notes.append(f"homography_threshold {shown} not applied: jcalib's outlier "
                     "rejection (calibrate --outlier-threshold) and detection checks replace it")
    return write_session(out, cell, stations, fmt=FORMAT, source=path, conventions=conventions,
                         extra={"guesses": guesses} if guesses else None, notes=tuple(notes), source_root=root)


def _kind(value: Any) -> str:
    if isinstance(value, (bool, int, float)) or value is None:
        return repr(value)
    return f"a {type(value).__name__}"
