"""``jcalib export --at cam0.Zoom=350`` and ``jcalib plan --lens-settings``: zoom lenses in the commands."""

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


def check_lens_specs(specs: list[str] | None) -> None:
    """Refuse malformed ``--lens-settings`` before planning (named, with the expected form)."""
    if specs:
        import numpy as np

        from jcalib.io.plan import make_plan, with_lens_settings

        with_lens_settings(make_plan([np.eye(4)]), specs)


def lens_plan(path: Path, specs: list[str]) -> int:
    """Rewrite the plan at ``path`` with every station visited at each lens setting of ``specs``
    (:func:`jcalib.io.plan.with_lens_settings`), keeping its other keys; the number of stations."""
    import json

    from jcalib.io.atomic import write_json_atomic
    from jcalib.io.plan import load_plan, with_lens_settings

    doc = json.loads(Path(path).read_text(encoding="utf-8"))
    plan = with_lens_settings(load_plan(path), specs)
    doc["stations"] = [s.to_json() for s in plan.stations]
    doc.pop("digest", None)
    write_json_atomic(path, doc)
    return len(plan)
