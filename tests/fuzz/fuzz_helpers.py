"""Helpers of the fuzz suite: the CLI run in-process, file digests."""

from __future__ import annotations

import contextlib
import hashlib
import io
from pathlib import Path


def run_cli(*args) -> tuple[int, str]:
    """``jcalib ARGS`` in this process: (exit status, stderr + stdout). Fails on any traceback or
    internal error: the CLI must answer every input with a message."""
    from jcalib.app.cli import main

    err, out = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            main([str(a) for a in args])
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    text = err.getvalue() + out.getvalue()
    assert "Traceback" not in text, text
    assert "internal error" not in text, text
    return code, text


def digest(path: Path) -> str:
    """Hash of a file, or of every file under a folder (names and bytes)."""
    h = hashlib.sha256()
    paths = sorted(p for p in Path(path).rglob("*") if p.is_file()) if Path(path).is_dir() else [Path(path)]
    for p in paths:
        h.update(str(p).encode())
        h.update(p.read_bytes())
    return h.hexdigest()
