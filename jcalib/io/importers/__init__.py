"""Importers: other tools' calibration data sets -> jcalib capture sessions (``jcalib import``).

One module per source format, each exposing ``FORMAT``, ``OPTIONS`` (name -> help) and
``import_source(source, out, *, mount=None, **options) -> ImportSummary``; its docstring states the
conventions it assumes (frames, units, quaternion order) and what it refuses. :func:`import_session`
dispatches by format name.
"""

from __future__ import annotations

import importlib
import os
from typing import Any

from jcalib.errors import BadInputError
from jcalib.io.importers.common import ImportSummary

__all__ = ["FORMATS", "ImportSummary", "import_session", "format_options"]

#: format name -> module
FORMATS: dict[str, str] = {
    "industrial-calibration": "jcalib.io.importers.industrial_calibration",
    "calibration-rs": "jcalib.io.importers.calibration_rs",
    "easy-handeye": "jcalib.io.importers.easy_handeye",
    "moveit": "jcalib.io.importers.moveit",
    "opencv-pairs": "jcalib.io.importers.opencv_pairs",
    "rosbag": "jcalib.io.importers.rosbag",
}


def _module(fmt: str):
    if fmt not in FORMATS:
        raise BadInputError(f"import: unknown format {fmt!r}; expected one of {', '.join(FORMATS)}")
    return importlib.import_module(FORMATS[fmt])


def format_options(fmt: str) -> dict[str, str]:
    """The options a format takes (name -> help)."""
    return dict(_module(fmt).OPTIONS)


def import_session(fmt: str, source: str | os.PathLike, out: str | os.PathLike, *, mount: str | None = None,
                   **options: Any) -> ImportSummary:
    """Turn a data set of another tool into the capture session ``out`` (``jcalib.session/1``).

    Args:
        fmt: one of :data:`FORMATS`.
        source: the data set (file or folder, as the format's module says).
        out: the session folder to create.
        mount: where the camera is, ``flange`` (eye-in-hand) or ``base`` (eye-to-hand), for sources that
            do not record it (refused when it contradicts a source that does).
        options: format-specific (:func:`format_options`).
    Raises:
        BadInputError: unknown format or option, or ambiguous / malformed input (never guessed).
    """
    return _module(fmt).import_source(source, out, mount=mount, **options)
