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
from jcalib.io.result import ResultFile, load_result

__all__ = ["EXPORT_FORMATS", "export_result", "export_text"]

#: Format name -> ``(result, **options) -> str``. Options per format:
#: ``opencv``: ``cameras`` (one id or a pair); ``ros``: ``camera``, ``camera_name``;
#: ``rapid``: ``tools``, ``wobjs``, ``module``, ``loads``; ``krl``: ``tools``, ``bases``;
#: ``kinematics``: ``robots``; ``urdf``: ``robot`` (both need a result with calibrated kinematics).
EXPORT_FORMATS: dict[str, Callable[..., str]] = {
    "opencv": opencv_yaml,
    "ros": ros_camera_info,
    "rapid": abb_rapid_module,
    "krl": kuka_config_lines,
    "kinematics": kinematics_yaml,
    "urdf": kinematics_urdf,
}


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
    ``kinematics``, ``urdf``) and write ``out_path`` atomically. ``names`` are the format's options (see
    :data:`EXPORT_FORMATS`); None values are left to the format's defaults.

    Returns:
        ``out_path`` as a :class:`~pathlib.Path`.
    """
    return write_text_atomic(out_path, export_text(result_path, fmt, **names))
