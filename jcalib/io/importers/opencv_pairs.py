"""OpenCV ``FileStorage`` pose-pair files (camodocal's ``TransformPairsInput.yml``) -> session of pose pairs.

Layout (``jhu-lcsr/handeye_calib_camodocal``): ``frameCount`` and, per pair ``i``, ``T1_i`` and ``T2_i`` (4x4
``!!opencv-matrix``, metres). A ``CalibratedTransform.yml`` beside it (the tool's answer, e.g.
``ArmTipToMarkerTagTransform``) is recorded in ``session.json`` (``imported_from.reference``), not used.
:func:`read_transform_pairs` and :func:`read_calibrated_transform` give the arrays to scripts and tests.

Conventions (camodocal's ROS node): ``T1_i`` is the pose of the robot's end effector in its base
(``p_base = T1 p_ee``) = ``T_base_flange``; ``T2_i`` is the pose of the tracked marker in the camera
(``p_cam = T2 p_marker``) = ``T_cam_target``. Whether the camera or the marker rides on the robot is not
in the file: ``--mount`` is required.

The file must be OpenCV's YAML (``%YAML:1.0`` first, as camodocal writes it), within the YAML size
budget, UTF-8, and nested at most :data:`MAX_NESTING` levels before OpenCV's parser sees it (OpenCV's
parser recurses without a limit and crashes the process on a deeply nested file). ``frameCount`` must be
an integer; a key given twice (at the top or in one matrix) is refused (OpenCV would keep one silently); pairs beyond it (``T1_i`` / ``T2_i`` with ``i >= frameCount``) are refused by name rather than
dropped.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from jcalib.errors import BadInputError
from jcalib.io.importers.common import (
    cell_entries_for_mount,
    check_options,
    pose_from_matrix,
    pose_pair_session,
    resolve_source,
)
from jcalib.io.importers.source import SourceFolder

FORMAT = "opencv-pairs"
OPTIONS = {"camera": "camera id (default cam0)", "target": "marker id (default marker)"}
#: Deepest nesting (indentation levels, sequence dashes and brackets together) handed to OpenCV.
MAX_NESTING = 32
#: Most pose pairs in one file.
MAX_PAIRS = 100_000


def nesting_depth(text: str) -> int:
    """An upper bound of a YAML text's nesting: indentation levels + ``- `` markers + open brackets."""
    stack: list[int] = []
    flow = worst = 0
    for line in text.splitlines():
        body = line.lstrip(" ")
        if not body or body.startswith(("#", "%")):
            continue
        indent = len(line) - len(body)
        while stack and stack[-1] >= indent:
            stack.pop()
        stack.append(indent)
        dashes = 0
        while body == "-" or body.startswith("- "):
            dashes += 1
            body = body[2:].lstrip(" ")
        for ch in body:
            if ch in "[{":
                flow += 1
                worst = max(worst, len(stack) + dashes + flow)
            elif ch in "]}":
                flow = max(flow - 1, 0)
        worst = max(worst, len(stack) + dashes + flow)
    return worst


def _storage(folder: SourceFolder, path: Path, what: str):
    """An OpenCV FileStorage over the file's text, after the checks of the module docstring."""
    import cv2

    text = folder.read_text(path, what, "yaml")
    if not text.lstrip().startswith("%YAML"):
        raise BadInputError(f"{path}: not an OpenCV FileStorage YAML file (it starts with %YAML:1.0 as OpenCV writes it)")
    if "\x00" in text:
        raise BadInputError(f"{path}: holds a NUL character; not an OpenCV FileStorage YAML file")
    keys: dict[tuple[str, str], int] = {}
    top = ""
    for n, line in enumerate(text.splitlines(), start=1):
        name = line.split(":", 1)[0].strip()
        if ":" not in line or not name or line[:1] in ("%", "#", "-", "[", "{") or not name.replace("_", "").isalnum():
            continue
        nested = line[:1] in (" ", "\t")
        key = (top if nested else "", name)
        if key in keys:
            raise BadInputError(f"{path} line {n}: the key {'.'.join(k for k in key if k)[:60]!r} appears twice (first "
                                f"on line {keys[key]}); OpenCV keeps one silently: keep one")
        keys[key] = n
        if not nested:
            top = name
    depth = nesting_depth(text)
    if depth > MAX_NESTING:
        raise BadInputError(f"{path}: nested about {depth} levels deep, more than the {MAX_NESTING} read; not a "
                            "pose-pair file")
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as e:
        raise BadInputError(f"{path}: not an OpenCV FileStorage YAML file ({str(e).strip().splitlines()[-1][:120]})") from None
    if not fs.isOpened():
        raise BadInputError(f"{path}: not an OpenCV FileStorage YAML file")
    return fs


def _matrix(fs: Any, key: str, path: Path) -> np.ndarray:
    import cv2

    node = fs.getNode(key)
    if node.empty() or node.isNone():
        raise BadInputError(f"{path}: {key} is missing (frameCount says it should be there)")
    try:
        m = node.mat()
    except cv2.error:
        m = None
    if m is None or np.shape(m) != (4, 4):
        raise BadInputError(f"{path}: {key}: expected a 4x4 !!opencv-matrix, got {None if m is None else np.shape(m)}")
    return np.asarray(m, np.float64)


def read_pairs(folder: SourceFolder, path: Path) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """``(T1 list, T2 list)`` of (4, 4) matrices from a pose-pair file (module docstring)."""
    fs = _storage(folder, path, f"import {FORMAT}: pose pairs")
    try:
        node = fs.getNode("frameCount")
        if not node.isInt():
            raise BadInputError(f"{path}: frameCount: expected an integer (the number of pose pairs)")
        n = int(node.real())
        if not 1 <= n <= MAX_PAIRS:
            raise BadInputError(f"{path}: frameCount: got {n}, expected 1 to {MAX_PAIRS} pairs")
        names = fs.root().keys()  # a FileNode's method, not a dict's
        beyond = sorted(k for k in names if k[:3] in ("T1_", "T2_") and k[3:].isdigit() and int(k[3:]) >= n)
        if beyond:
            raise BadInputError(f"{path}: holds {', '.join(beyond[:6])}{' ...' if len(beyond) > 6 else ''} beyond "
                                f"frameCount {n}; fix frameCount (or remove the extra pairs): none is dropped silently")
        T1 = [_matrix(fs, f"T1_{i}", path) for i in range(n)]
        T2 = [_matrix(fs, f"T2_{i}", path) for i in range(n)]
    finally:
        fs.release()
    return T1, T2


def read_transform_pairs(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """``(T1 (N, 4, 4), T2 (N, 4, 4))`` of a camodocal ``TransformPairsInput.yml`` (metres), read with every
    check of :func:`read_pairs` (the one reader of the format; for scripts and tests that want the arrays)."""
    path = Path(path)
    if not path.is_file():
        raise BadInputError(f"{path}: no such file (expected a camodocal TransformPairsInput.yml)")
    T1, T2 = read_pairs(SourceFolder(path.parent, FORMAT), path)
    return np.stack(T1), np.stack(T2)


def read_calibrated_transform(path: str | os.PathLike, key: str = "ArmTipToMarkerTagTransform") -> np.ndarray:
    """The ``(4, 4)`` transform ``key`` of a camodocal ``CalibratedTransform.yml`` (metres)."""
    path = Path(path)
    if not path.is_file():
        raise BadInputError(f"{path}: no such file (expected a camodocal CalibratedTransform.yml)")
    fs = _storage(SourceFolder(path.parent, FORMAT), path, f"{FORMAT}: calibrated transform")
    try:
        return _matrix(fs, key, path)
    finally:
        fs.release()


def import_source(source: str | os.PathLike, out: str | os.PathLike, *, mount: str | None = None, **options: Any):
    """Import a camodocal / OpenCV FileStorage pose-pair file (or its folder) into session ``out``.

    Raises:
        BadInputError: not a pose-pair file, a matrix that is not a pose, or no ``mount``.
    """
    check_options(FORMAT, options, OPTIONS)
    path = resolve_source(source, "TransformPairsInput.yml", f"import {FORMAT}")
    cell_entries_for_mount(mount, FORMAT, "the pose-pair file does not say whether the camera or the marker "
                                          "rides on the robot")
    folder = SourceFolder(path.parent, FORMAT)
    T1, T2 = read_pairs(folder, path)
    pairs = [(pose_from_matrix(a, f"{path}: T1_{i}"), pose_from_matrix(b, f"{path}: T2_{i}"))
             for i, (a, b) in enumerate(zip(T1, T2, strict=True))]
    extra, notes = None, ()
    if (path.parent / "CalibratedTransform.yml").exists():
        try:
            ref = folder.file("CalibratedTransform.yml", str(path), "CalibratedTransform.yml beside it")
            fs = _storage(folder, ref, f"import {FORMAT}: reference")
            try:
                T = pose_from_matrix(_matrix(fs, "ArmTipToMarkerTagTransform", ref), f"{ref}: ArmTipToMarkerTagTransform")
            finally:
                fs.release()
            extra = {"reference": {"file": ref.name, "ArmTipToMarkerTagTransform": T.tolist()}}
        except BadInputError as e:
            notes = (f"CalibratedTransform.yml not recorded (it is not used): {e}",)
    return pose_pair_session(out, pairs, mount=mount, fmt=FORMAT, source=path,
                             conventions="T1_i = T_base_flange (p_base = T1 p_ee), T2_i = T_cam_target "
                                         "(p_cam = T2 p_marker), 4x4, m",
                             camera=str(options.get("camera", "cam0")), target=str(options.get("target", "marker")),
                             extra=extra, notes=notes, source_root=path.parent if Path(source).is_dir() else path)
