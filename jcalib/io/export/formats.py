"""``export_result``: one entry point over all export formats (what ``jcalib export`` calls)."""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from jcalib.errors import BadInputError
from jcalib.io.atomic import write_text_atomic
from jcalib.io.export.abb_rapid import abb_rapid_module
from jcalib.io.export.kinematics import kinematics_urdf, kinematics_yaml
from jcalib.io.export.kuka_krl import kuka_config_lines
from jcalib.io.export.opencv_yaml import opencv_yaml
from jcalib.io.export.ros import ros_camera_info
from jcalib.io.export.ur_calibration import ur_calibration_export
from jcalib.io.result import ResultFile, load_result

__all__ = ["DEFAULT_FILE_NAMES", "EXPORT_FORMATS", "FORMAT_DESCRIPTIONS", "export_options", "export_result", "export_text",
           "format_option_names"]

#: Format name -> ``(result, **options) -> str``. Options per format:
#: ``opencv``: ``cameras`` (one id or a pair); ``ros``: ``camera``, ``camera_name``;
#: ``rapid``: ``tools``, ``wobjs``, ``module``, ``loads``; ``krl``: ``tools``, ``bases``;
#: ``kinematics``: ``robots``; ``urdf``, ``ur-calibration``: ``robot`` (all three need a result with calibrated
#: kinematics).
EXPORT_FORMATS: dict[str, Callable[..., str]] = {
    "opencv": opencv_yaml,
    "ros": ros_camera_info,
    "rapid": abb_rapid_module,
    "krl": kuka_config_lines,
    "kinematics": kinematics_yaml,
    "urdf": kinematics_urdf,
    "ur-calibration": ur_calibration_export,
}


#: One line per format, for menus.
FORMAT_DESCRIPTIONS = {
    "opencv": "OpenCV YAML (K, dist; a stereo pair with --camera A,B)",
    "ros": "ROS camera_info YAML",
    "rapid": "ABB RAPID module (tooldata, wobjdata)",
    "krl": "KUKA KRL TOOL_DATA / BASE_DATA lines",
    "kinematics": "calibrated robot kinematics (cell-spec YAML with σ and controller offsets)",
    "urdf": "calibrated robot kinematics as a URDF",
    "ur-calibration": "calibrated UR kinematics as Universal Robots' delta DH (calibration.conf form; applied only by "
                      "UR's own procedure)",
}
#: The file name a download of each format gets.
DEFAULT_FILE_NAMES = {"opencv": "camera_opencv.yaml", "ros": "camera_info.yaml", "rapid": "jcalib_cell.mod",
                      "krl": "jcalib_cell.dat", "kinematics": "kinematics.yaml", "urdf": "robot.urdf",
                      "ur-calibration": "ur_calibration.conf"}
#: ``jcalib export`` option -> the formats that take it.
_OPTION_FORMATS = {"camera": ("opencv", "ros"), "module": ("rapid",), "robot": ("kinematics", "urdf", "ur-calibration"),
                   "tool_orientation": ("rapid", "krl")}


def format_option_names(fmt: str) -> list[str]:
    """The ``jcalib export`` options (``camera``, ``module``, ``robot``, ``tool_orientation``) ``fmt`` takes."""
    return [name for name, formats in _OPTION_FORMATS.items() if fmt in formats]


def export_options(fmt: str, *, camera: str | None = None, module: str | None = None, robot: str | None = None,
                   tool_orientation: list[str] | None = None) -> dict[str, Any]:
    """The exporter options of ``jcalib export --format FMT [--camera ...] [--module ...] [--robot ...]
    [--tool-orientation TOOL=...]`` (the app's export page gives the same), refusing an option the format
    does not take, naming it.

    Raises:
        BadInputError: an unknown format, an option the format does not use, a malformed tool orientation.
    """
    from jcalib.io.export._common import parse_tool_orientation

    if not isinstance(fmt, str) or fmt not in EXPORT_FORMATS:
        raise BadInputError(f"format: expected one of {', '.join(EXPORT_FORMATS)}, got {fmt!r}")
    given = {"camera": camera, "module": module, "robot": robot, "tool_orientation": tool_orientation or None}
    for name, value in given.items():
        if value is not None and fmt not in _OPTION_FORMATS[name]:
            flag = "--" + name.replace("_", "-")
            *rest, last = _OPTION_FORMATS[name]
            which = f"{', '.join(rest)} and {last} formats" if rest else f"{last} format"
            raise BadInputError(f"{flag} applies to the {which}, not {fmt!r}")
        if value is not None and name != "tool_orientation" and not isinstance(value, str):
            raise BadInputError(f"--{name}: expected text, got {value!r}")
    if tool_orientation is not None and (isinstance(tool_orientation, str) or
                                         not all(isinstance(t, str) for t in tool_orientation)):
        raise BadInputError("--tool-orientation: expected a list of TOOL=flange or TOOL=X,Y,Z")
    orientations = dict(parse_tool_orientation(t) for t in tool_orientation or [])
    return {"opencv": {"cameras": camera}, "ros": {"camera": camera},
            "rapid": {"module": module, "orientations": orientations or None},
            "krl": {"orientations": orientations or None}, "kinematics": {"robots": robot},
            "urdf": {"robot": robot}, "ur-calibration": {"robot": robot}}[fmt]  # fmt: skip


def export_text(result: ResultFile | str | os.PathLike, fmt: str, **names: Any) -> str:
    """The text of ``result`` (a :class:`ResultFile` or a path) in format ``fmt``.

    Raises:
        BadInputError: unknown format, an option the format does not take (named with the
            options it does take), or any error of the format's exporter.
    """
    func = EXPORT_FORMATS.get(fmt) if isinstance(fmt, str) else None
    if func is None:
        raise BadInputError(f"format: expected one of {', '.join(EXPORT_FORMATS)}, got {fmt!r}")
    allowed = [p for p in inspect.signature(func).parameters if p != "result"]
    unknown = sorted(set(names) - set(allowed))
    if unknown:
        raise BadInputError(
            f"format {fmt!r} takes the options {', '.join(allowed)}; got unknown option(s) "
            f"{', '.join(unknown)}"
        )
    return func(load_result(result), **{k: v for k, v in names.items() if v is not None})


def export_result(
    result_path: str | os.PathLike | ResultFile, fmt: str, out_path: str | os.PathLike, **names: Any
) -> Path:
    """Read a result file, export it in format ``fmt`` (``opencv``, ``ros``, ``rapid``, ``krl``,
    ``kinematics``, ``urdf``, ``ur-calibration``) and write ``out_path`` atomically. ``names`` are the format's options (see
    :data:`EXPORT_FORMATS`); None values are left to the format's defaults.

    Returns:
        ``out_path`` as a :class:`~pathlib.Path`.
    """
    return write_text_atomic(out_path, export_text(result_path, fmt, **names))
