"""Target files: a cell's target given by a file, e.g. Kalibr's target YAML (``april_6x6.yaml``).

A cell-spec target entry may name a file instead of listing its geometry::

    targets:
      grid: {file: april_6x6.yaml, mount: base}     # path relative to the cell spec's folder

The file holds either

- a **Kalibr target YAML** (``kalibr_calibrate_cameras --target``), recognised by ``target_type``:
  ``aprilgrid`` (``tagCols``, ``tagRows``, ``tagSize`` m, ``tagSpacing`` = gap / tag size) becomes
  ``{type: aprilgrid, family: tag36h11, cols, rows, tag_size, tag_spacing}`` (Kalibr's grids are
  tag36h11; :mod:`jcalib.geometry.apriltags` for the frame), and ``checkerboard`` (``targetCols``,
  ``targetRows`` inner corners, ``rowSpacingMeters`` = ``colSpacingMeters``) becomes ``{type:
  checkerboard, cols, rows, square}``. Kalibr's ``circlegrid`` is refused: write a ``type: circles``
  entry;
- or a jcalib target entry (a mapping with ``type``, as in the cell spec).

The entry's own keys (``mount``, ``pose``, ``robot``, ``warp``) stay with the cell; the file gives the
geometry, and an entry that also lists geometry keys is refused (which would win?). A cell written
back (:func:`jcalib.io.cell.cell_to_dict`) holds the geometry itself, not the file name.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from jcalib.errors import BadInputError
from jcalib.io.schema.reading import read_document

__all__ = ["expand_target_files", "kalibr_target_entry", "read_target_file"]

#: Keys of a cell-spec target entry that are the cell's, not the target's geometry.
CELL_KEYS = ("mount", "pose", "robot", "warp")


def _number(doc: dict, key: str, where: str, integer: bool = False):
    if key not in doc:
        raise BadInputError(f"{where}: missing {key!r}")
    v = doc[key]
    ok = isinstance(v, int) if integer else isinstance(v, (int, float))
    if isinstance(v, bool) or not ok:
        raise BadInputError(f"{where}: {key} must be {'an integer' if integer else 'a number'}, got {v!r}")
    return int(v) if integer else float(v)


def kalibr_target_entry(doc: Any, where: str) -> dict:
    """The jcalib target entry (geometry only) of a parsed Kalibr target YAML (module docstring).

    Raises:
        BadInputError: not a Kalibr target, an unsupported ``target_type`` or a missing / bad key.
    """
    if not isinstance(doc, dict) or "target_type" not in doc:
        raise BadInputError(f"{where}: expected a Kalibr target YAML with 'target_type', got {str(doc)[:120]}")
    kind = str(doc["target_type"]).strip().strip("'\"")
    if kind == "aprilgrid":
        return {"type": "aprilgrid", "family": "tag36h11", "cols": _number(doc, "tagCols", where, True),
                "rows": _number(doc, "tagRows", where, True), "tag_size": _number(doc, "tagSize", where),
                "tag_spacing": _number(doc, "tagSpacing", where)}
    if kind == "checkerboard":
        row, col = _number(doc, "rowSpacingMeters", where), _number(doc, "colSpacingMeters", where)
        if abs(row - col) > 1e-9 * max(abs(row), abs(col)):
            raise BadInputError(f"{where}: rowSpacingMeters {row!r} and colSpacingMeters {col!r} differ; jcalib's "
                                "checkerboard has square squares")
        return {"type": "checkerboard", "cols": _number(doc, "targetCols", where, True),
                "rows": _number(doc, "targetRows", where, True), "square": row}
    if kind == "circlegrid":
        raise BadInputError(f"{where}: Kalibr's circlegrid target is not read from a Kalibr file; write the cell entry "
                            "{type: circles, cols, rows, spacing, asymmetric} instead")
    raise BadInputError(f"{where}: target_type {kind!r}; expected aprilgrid or checkerboard (Kalibr's names)")


def read_target_file(path: str | os.PathLike) -> dict:
    """The target entry (geometry only) held by a Kalibr target YAML or a jcalib target entry file."""
    doc = read_document(path, "target file", fmt="yaml")
    where = f"target file '{path}'"
    if isinstance(doc, dict) and "target_type" in doc:
        return kalibr_target_entry(doc, where)
    if isinstance(doc, dict) and "type" in doc:
        extra = sorted(k for k in doc if k in CELL_KEYS)
        if extra:
            raise BadInputError(f"{where}: {', '.join(extra)} belong in the cell spec's target entry, not in the "
                                "target file (the file describes the printed target only)")
        return dict(doc)
    raise BadInputError(f"{where}: expected a Kalibr target YAML (target_type: aprilgrid, tagCols, ...) or a jcalib "
                        "target entry (type: checkerboard, cols, ...)")


def expand_target_files(data: Any, base_dir: str | os.PathLike | None, source: str) -> Any:
    """The cell document with every ``targets.<id>.file`` replaced by the geometry it holds.

    Args:
        data: the cell document as read (not validated yet; anything but a mapping is returned as is).
        base_dir: the folder relative file names start from (the cell spec's; None: the working folder).
        source: how messages name the cell spec.
    """
    targets = data.get("targets") if isinstance(data, dict) else None
    if not isinstance(targets, dict) or not any(isinstance(e, dict) and "file" in e for e in targets.values()):
        return data
    out = dict(targets)
    for name, entry in targets.items():
        if not isinstance(entry, dict) or "file" not in entry:
            continue
        where = f"{source}: targets.{name}.file"
        file = entry["file"]
        if not isinstance(file, str) or not file:
            raise BadInputError(f"{where}: expected the path of a target file (a Kalibr target YAML), got {file!r}")
        path = Path(file)
        if not path.is_absolute():
            path = Path(base_dir or ".") / path
        geometry = read_target_file(path)
        clash = sorted(k for k in entry if k not in CELL_KEYS and k != "file")
        if clash:
            raise BadInputError(f"{where}: the entry also lists {', '.join(clash)}; give the geometry in the file or in "
                                f"the entry, not both (the entry keeps only {', '.join(CELL_KEYS)})")
        out[name] = {**geometry, **{k: v for k, v in entry.items() if k in CELL_KEYS}}
    return {**data, "targets": out}
