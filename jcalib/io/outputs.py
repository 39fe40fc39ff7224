"""Output paths checked before any work: a result is never lost after a long solve, an input never
overwritten.

Every command that writes a file calls :func:`check_outputs` first, with its outputs and inputs:
an output must be a (new or existing) regular file, not a directory, in an existing, writable
folder (not a path under a file), and none of the inputs (same path, a hard link or a symlink to
it), nor a file of an input folder (a capture session), nor another output of the same command.
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path

from jcalib.errors import BadInputError

__all__ = ["check_output_dir", "check_outputs"]

PathLike = str | os.PathLike


def _same(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.resolve().relative_to(folder.resolve())
        return True
    except ValueError:
        return False


def _check_folder(folder: Path, option: str, path: Path) -> None:
    """``folder`` exists, is a directory and can take a new file."""
    probe = folder
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        raise BadInputError(f"{option} {path}: {probe} is a file, not a folder; choose a path in a folder")
    if not folder.exists():
        raise BadInputError(f"{option} {path}: the folder {folder} does not exist; create it first (mkdir -p {folder})")
    try:
        fd, tmp = tempfile.mkstemp(prefix=".jcalib-write-check.", dir=folder)
        os.close(fd)
        os.unlink(tmp)
    except OSError as e:
        raise BadInputError(
            f"{option} {path}: cannot write in {folder} ({e.strerror or e}); choose a writable folder"
        ) from None


def check_outputs(
    outputs: Mapping[str, PathLike | None],
    inputs: Iterable[PathLike | None] = (),
    input_dirs: Mapping[PathLike, Iterable[str]] | None = None,
) -> None:
    """Refuse output paths that cannot be written or would destroy an input.

    Args:
        outputs: option name (``"-o"``, ``"--export-out"``) -> the file it names (None: not given).
        inputs: the files the command reads (None entries are skipped).
        input_dirs: folders the command reads (a session) -> the names that may be written inside
            them (e.g. ``["observations.json"]``); any other file inside them is refused.

    Raises:
        BadInputError: naming the option, the path and what to do.
    """
    given = {opt: Path(p) for opt, p in outputs.items() if p is not None}
    ins = [Path(p) for p in inputs if p is not None]
    seen: dict[str, str] = {}
    for option, path in given.items():
        if str(path) in ("", "-"):
            raise BadInputError(f"{option}: expected a file path, got {str(path)!r}")
        try:
            st = path.stat()
        except OSError:
            st = None
        if st is not None and stat.S_ISDIR(st.st_mode):
            raise BadInputError(f"{option} {path} is a directory; name a file (e.g. {path / 'out.json'})")
        if st is not None and not stat.S_ISREG(st.st_mode):
            raise BadInputError(f"{option} {path} is not a regular file (a device or a pipe); name a file")
        _check_folder(path.parent if str(path.parent) else Path("."), option, path)
        for inp in ins:
            if _same(path, inp):
                raise BadInputError(f"{option} {path} is also an input ({inp}); writing it would destroy the input: "
                                    "choose another output file")
        for folder, allowed in (input_dirs or {}).items():
            folder = Path(folder)
            if _inside(path, folder) and path.resolve().relative_to(folder.resolve()).as_posix() not in set(allowed):
                raise BadInputError(f"{option} {path} lies inside the input folder {folder}, which must stay as it "
                                    "is; choose a file outside it")
        key = str(path.resolve())
        if key in seen:
            raise BadInputError(f"{option} and {seen[key]} name the same file {path}; give each output its own file")
        seen[key] = option


def check_output_dir(
    option: str, path: PathLike, inputs: Iterable[PathLike | None] = (), managed: Iterable[str] = ()
) -> None:
    """Refuse an output folder (a session, the demo's folder) that is a file, lies under a file, or
    cannot be created or written; an existing folder is accepted (resume).

    Args:
        option: the option naming the folder, for messages.
        path: the folder.
        inputs: the files the command reads: none may be the folder or one of its ``managed`` entries.
        managed: names inside the folder that the command writes (``session.json``, ``images``).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise BadInputError(f"{option} {path} is a file; name a folder (new, or one to resume)")
    for inp in inputs:
        if inp is None:
            continue
        inp = Path(inp)
        if _same(path, inp) or any(_inside(inp, path / m) for m in managed):
            raise BadInputError(f"{option} {path}: the input {inp} is (inside) what this command writes there; "
                                "choose another folder or move the input")
    if path.is_dir():
        _check_folder(path, option, path)
        return
    _check_folder(path.parent if str(path.parent) else Path("."), option, path)
