"""Where an import writes: a new session folder, all or nothing, and nothing that existed is changed.

``--out`` must be a new folder (in an existing folder) or an empty one; never a file, never the source
or a folder inside it, never a folder holding the source. The session is written into a temporary
sibling ``.<name>.import-<random>`` and renamed to ``--out`` at the end, so an import that fails (bad
input, a full disk, Ctrl-C) leaves no partial session; the temporary folder is removed.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
from collections.abc import Iterator
from pathlib import Path

from jcalib.errors import BadInputError

__all__ = ["check_output_folder", "staged_folder"]


def _real(path: Path) -> Path:
    try:
        return path.resolve()
    except (OSError, RuntimeError):
        raise BadInputError(f"import: --out {path}: cannot resolve the path (a symlink loop?)") from None


def check_output_folder(out: str | os.PathLike, source: str | os.PathLike, fmt: str) -> Path:
    """Refuse an ``--out`` that could change an existing file (module docstring); returns it as a Path.

    Args:
        out: the session folder to create.
        source: what the import reads: the data set's folder, or its file for single-file formats.
        fmt: the importer, for messages.
    Raises:
        BadInputError: naming ``--out`` and what to choose instead.
    """
    out = Path(out)
    where = f"import {fmt}: --out {out}"
    if str(out) in ("", "-", "."):
        raise BadInputError(f"{where}: expected a new folder for the session (e.g. --out session)")
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise BadInputError(f"{where} exists and is not a folder; import never overwrites a file: name a new "
                            "folder for the session")
    out_real, src_real = _real(out), _real(Path(source))
    if out_real == src_real or out_real.is_relative_to(src_real):
        raise BadInputError(f"{where} is the source {source} or lies inside it; the source must stay as it is: "
                            "choose a folder outside the data set")
    if src_real.is_relative_to(out_real):
        raise BadInputError(f"{where} holds the source {source}; choose a folder outside the data set")
    if out.is_dir():
        try:
            with os.scandir(out) as entries:
                empty = next(entries, None) is None
        except OSError as e:
            raise BadInputError(f"{where}: cannot list it ({e.strerror or e})") from None
        if not empty:
            raise BadInputError(f"{where} already holds files; import writes a new session and never changes "
                                "files that exist: name a new (or empty) folder; to replace an old session, move "
                                "or delete it first")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise BadInputError(f"{where}: the folder {parent} does not exist (or is a file); create it first "
                            f"(mkdir -p {parent})")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BadInputError(f"{where}: cannot write in {parent}; choose a writable folder")
    return out


def _fsync_dir(directory: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def staged_folder(out: Path, fmt: str) -> Iterator[Path]:
    """A temporary sibling of ``out`` to write the session into; renamed to ``out`` when the block ends
    without an error, removed otherwise (``out`` must have passed :func:`check_output_folder`)."""
    parent = out.parent if str(out.parent) else Path(".")
    tmp = parent / f".{out.name}.import-{secrets.token_hex(6)}"
    try:
        os.mkdir(tmp)
    except OSError as e:
        raise BadInputError(f"import {fmt}: --out {out}: cannot create a folder in {parent} "
                            f"({e.strerror or e})") from None
    try:
        yield tmp
        try:
            os.rename(tmp, out)  # replaces an empty folder; fails on a folder that filled meanwhile
        except OSError as e:
            raise BadInputError(f"import {fmt}: --out {out}: cannot move the new session there "
                                f"({e.strerror or e}); it must be a new or empty folder") from None
        _fsync_dir(parent)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
