"""Refuse to replace an existing file that is not a jcalib document of the kind a command writes: ``-o``
pointed by mistake at an image, a cell spec or someone's notes must not turn them into JSON."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from jcalib.errors import BadInputError

__all__ = ["check_replaceable"]

#: Bytes read from an existing file to find its ``schema`` key (a jcalib document writes it first).
PREFIX_BYTES = 4096
#: A larger existing file whose schema key is not at its start is not parsed whole: it is refused.
PARSE_BYTES = 64 << 20


def _schema(path: Path) -> str | None:
    """The ``schema`` of a JSON document (None: not a JSON object with one, or unreadable)."""
    try:
        with open(path, "rb") as f:
            head = f.read(PREFIX_BYTES)
        m = re.match(rb'\s*\{\s*"schema"\s*:\s*"([^"\\]{1,100})"', head)
        if m:
            return m.group(1).decode("utf-8", "replace")
        if path.stat().st_size > PARSE_BYTES:
            return None
        data = json.loads(path.read_bytes())
    except (OSError, ValueError):
        return None
    return data.get("schema") if isinstance(data, dict) and isinstance(data.get("schema"), str) else None


def check_replaceable(option: str, path: str | os.PathLike | None, schema: str, force: bool = False) -> None:
    """Refuse ``path`` when it exists, is not empty and is not a ``schema`` document (unless ``force``).

    Args:
        option: the option naming the file (``"-o"``), for the message.
        path: the output file (None: not given).
        schema: the schema the command writes, e.g. ``"jcalib.observations/1"``.
        force: replace whatever is there (``--force``).

    Raises:
        BadInputError: naming the option, the file, what it holds and what to do.
    """
    if path is None or force:
        return
    p = Path(path)
    try:
        if not p.is_file() or p.stat().st_size == 0:
            return  # nothing there to lose (a directory or a device is refused by check_outputs)
    except OSError:
        return
    found = _schema(p)
    if found == schema:
        return
    what = f"a {found} document" if found else "not a jcalib document"
    raise BadInputError(f"{option} {p} exists and is {what}, not {schema}: jcalib replaces only its own {schema} "
                        "files; choose another file, or pass --force to replace it")
