"""Importers: other tools' calibration data sets -> jcalib capture sessions (``jcalib import``).

One module per source format, each exposing ``FORMAT``, ``OPTIONS`` (name -> help) and
``import_source(source, out, *, mount=None, **options) -> ImportSummary``; its docstring states the
conventions it assumes (frames, units, quaternion order) and what it refuses. :func:`import_session`
dispatches by format name.

What every importer guarantees (:mod:`.source`, :mod:`.output`): files are read within the input
limits of :mod:`jcalib.io.schema.reading` (size, UTF-8, YAML aliases and depth, duplicate keys);
paths a manifest names must resolve inside the data set's folder (``allow_outside=true`` where the
format takes it); numbers are strict (an integer field refuses ``7.9``, a number refuses text and
booleans) and finite, flange poses within the reach limit of cell specs; ``--out`` is a new or empty
folder outside the source, written whole or not at all.
"""

from __future__ import annotations

import importlib
import os
from typing import Any

from jcalib.errors import BadInputError
from jcalib.io.importers.common import ImportSummary
from jcalib.io.importers.output import check_output_folder

__all__ = ["FORMATS", "ImportSummary", "format_options", "import_session", "parse_options"]

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


def parse_options(fmt: str, items: list[str] | None) -> dict[str, str]:
    """``--option KEY=VALUE`` items as a mapping (``-`` in a key read as ``_``).

    Raises:
        BadInputError: an item without ``=``, a key given twice (also as ``a-b`` and ``a_b``), or a key the
            format does not take (listing those it does), so that no option is dropped or overrides another.
    """
    from jcalib.io.importers.common import check_options

    known = format_options(fmt)
    options: dict[str, str] = {}
    for item in items or []:
        key, sep, value = str(item).partition("=")
        name = key.strip().replace("-", "_")
        if not sep or not name:
            raise BadInputError(f"--option: expected KEY=VALUE, got {str(item)[:80]!r}")
        if name in options:
            raise BadInputError(f"--option {name[:40]}: given twice; give each option once")
        options[name] = value
    check_options(fmt, options, known)
    return options


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
        BadInputError: unknown format or option, ambiguous / malformed input (never guessed), or an ``out``
            that is a file, a folder holding files, the source or inside it.
    """
    module = _module(fmt)
    check_output_folder(out, source, fmt)
    return module.import_source(source, out, mount=mount, **options)
