"""``jcalib export --at cam0.Zoom=350``: a result with its zoom camera at one lens setting."""

from __future__ import annotations

from pathlib import Path

from jcalib.errors import BadInputError
from jcalib.io.result import ResultFile, load_result
from jcalib.problems.lens import file_at, parse_at


def result_at(path: Path | ResultFile, at: str, extrapolate: bool, camera: str | None):
    """``(result at the setting, camera id)`` for the export; ``camera`` (``--camera``) must agree with ``--at``."""
    name = parse_at(at)[0]
    if camera is not None and camera != name:
        raise BadInputError(f"--camera {camera} and --at {at} name different cameras; give one camera")
    return file_at(load_result(path), at, extrapolate), name
