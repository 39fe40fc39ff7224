"""ROS-Industrial ``industrial_calibration`` extrinsic hand-eye data sets -> capture session.

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
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from jcalib.errors import BadInputError
from jcalib.io.importers.common import ImportedStation, check_options, pose_from_xyz_quat, resolve_source, write_session

FORMAT = "industrial-calibration"
OPTIONS = {
    "intrinsics": "held (default: as the tool, which holds them fixed) or initial (start values, estimated)",
    "camera_model": "lens model when the source has no intrinsics (default opencv5)",
    "camera": "camera id in the session (default cam0)",
    "target": "target id in the session (default board)",
}
_POSE_KEYS = ("x", "y", "z", "qx", "qy", "qz", "qw")


def _load_yaml(path: Path) -> Any:
    import yaml

    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as e:
        raise BadInputError(f"{path}: not readable YAML ({e})") from None


def _pose(entry: Any, where: str):
    if not isinstance(entry, dict) or any(k not in entry for k in _POSE_KEYS):
        raise BadInputError(f"{where}: expected a pose with keys {', '.join(_POSE_KEYS)} (m, quaternion), got "
                            f"{str(entry)[:120]}")
    return pose_from_xyz_quat([entry["x"], entry["y"], entry["z"]], [entry[k] for k in ("qx", "qy", "qz", "qw")], where)


def _dictionary_name(value: Any, where: str) -> str:
    """OpenCV's predefined dictionary name for its integer id (e.g. 10 -> DICT_6X6_250)."""
    import cv2

    from jcalib.geometry.targets import ARUCO_DICTIONARIES

    names = {int(getattr(cv2.aruco, n)): n for n in ARUCO_DICTIONARIES if hasattr(cv2.aruco, n)}
    if isinstance(value, bool) or not isinstance(value, int) or value not in names:
        raise BadInputError(f"{where}: dictionary: expected an OpenCV predefined dictionary id "
                            f"({min(names)}..{max(names)}), got {value!r}")
    return names[value]


def target_entry(finder: Any, where: str) -> dict:
    """The cell-spec target entry (geometry only) of an industrial_calibration target finder config."""
    if not isinstance(finder, dict) or "type" not in finder:
        raise BadInputError(f"{where}: expected a target finder config with a 'type', got {str(finder)[:120]}")
    kind = str(finder["type"]).split("::")[-1].removesuffix("Plugin")

    def need(*keys):
        missing = [k for k in keys if k not in finder]
        if missing:
            raise BadInputError(f"{where}: {kind} needs {', '.join(missing)}")
        return [finder[k] for k in keys]

    if kind == "CharucoGridTargetFinder":
        rows, cols, square, marker, dictionary = need("rows", "cols", "chessboard_dim", "aruco_marker_dim", "dictionary")
        return {"type": "charuco", "squares_x": int(cols), "squares_y": int(rows), "square": float(square),
                "marker": float(marker), "dictionary": _dictionary_name(dictionary, where), "legacy": True}
    if kind == "ModifiedCircleGridTargetFinder":
        rows, cols, spacing = need("rows", "cols", "spacing")
        return {"type": "circles", "cols": int(cols), "rows": int(rows), "spacing": float(spacing),
                "origin_dot": "bottom_left"}
    if kind == "ArucoGridTargetFinder":
        raise BadInputError(f"{where}: ArucoGridTargetFinder (the corners of an ArUco GridBoard's markers) has no "
                            "jcalib target type yet; detect such boards elsewhere, or use a ChArUco board "
                            "(CharucoGridTargetFinder), a chessboard or a circle grid")
    raise BadInputError(f"{where}: unknown target finder {finder['type']!r}; expected CharucoGridTargetFinder, "
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
    check_options(FORMAT, options, OPTIONS)
    path = resolve_source(source, "cal_data.yaml", f"import {FORMAT}")
    root = path.parent
    cfg = _load_yaml(path)
    if not isinstance(cfg, dict) or not isinstance(cfg.get("data"), list):
        raise BadInputError(f"{path}: expected a mapping with 'data: [{{image: ..., pose: ...}}, ...]'")
    if not isinstance(cfg.get("static_camera"), bool):
        raise BadInputError(f"{path}: static_camera: expected true (camera fixed, target on the flange) or false "
                            f"(camera on the flange), got {cfg.get('static_camera')!r}; the pose files mean a "
                            "different mount in each case, so it is not guessed")
    cam_mount = "base" if cfg["static_camera"] else "flange"
    if mount is not None and mount != cam_mount:
        raise BadInputError(f"{path}: static_camera: {str(cfg['static_camera']).lower()} puts the camera on the "
                            f"{cam_mount}, but --mount {mount} was given")
    finder = cfg.get("target_finder")
    if finder is None and (root / "target_finder.yaml").is_file():
        finder = _load_yaml(root / "target_finder.yaml")
    if finder is None:
        raise BadInputError(f"{path}: no target_finder (in cal_data.yaml or a target_finder.yaml beside it)")
    target = target_entry(finder, f"{path}: target_finder")
    cam_id = str(options.get("camera", "cam0"))
    tgt_id = str(options.get("target", "board"))
    intr = cfg.get("intrinsics")
    if intr is None and (root / "camera_intr.yaml").is_file():
        intr = (_load_yaml(root / "camera_intr.yaml") or {}).get("intrinsics")
    camera: dict[str, Any] = {"model": str(options.get("camera_model", "opencv5")), "mount": cam_mount}
    held = str(options.get("intrinsics", "held"))
    if held not in ("held", "initial"):
        raise BadInputError(f"import {FORMAT}: intrinsics: expected held or initial, got {held!r}")
    if intr is not None:
        if not isinstance(intr, dict) or any(k not in intr for k in ("fx", "fy", "cx", "cy")):
            raise BadInputError(f"{path}: intrinsics: expected {{fx, fy, cx, cy}} (px), got {str(intr)[:120]}")
        fx, fy, cx, cy = (float(intr[k]) for k in ("fx", "fy", "cx", "cy"))
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
    for i, item in enumerate(cfg["data"]):
        where = f"{path}: data[{i}]"
        if not isinstance(item, dict) or "image" not in item or "pose" not in item:
            raise BadInputError(f"{where}: expected {{image: PATH, pose: PATH}}, got {str(item)[:120]}")
        image, pose_file = root / str(item["image"]), root / str(item["pose"])
        for f in (image, pose_file):
            if not f.is_file():
                raise BadInputError(f"{where}: {f} does not exist")
        T = _pose(_load_yaml(pose_file), str(pose_file))
        stations.append(ImportedStation(id=f"s{i:03d}", T_base_flange=T, images={cam_id: image},
                                        source={"image": str(item["image"]), "pose": str(item["pose"])}))
    guesses = {k: cfg[k] for k in ("camera_mount_to_camera_guess", "target_mount_to_target_guess") if k in cfg}
    conventions = (f"pose files = T_base_flange of the {'target' if cfg['static_camera'] else 'camera'} mount, m, "
                   "quaternion fields qx qy qz qw (Hamilton); intrinsics pinhole without distortion"
                   + (" held fixed" if intr is not None and held == "held" else ""))
    notes = []
    if "homography_threshold" in cfg:
        notes.append(f"homography_threshold {cfg['homography_threshold']} px not applied: jcalib's outlier "
                     "rejection (calibrate --outlier-threshold) and detection checks replace it")
    return write_session(out, cell, stations, fmt=FORMAT, source=path, conventions=conventions,
                         extra={"guesses": guesses} if guesses else None, notes=tuple(notes))
