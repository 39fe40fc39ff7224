"""The source folder of an import: every file an importer reads lies in it and is read within limits.

A manifest (``cal_data.yaml``, ``dataset.toml``, a ROS 2 bag's ``metadata.yaml``) names images and pose
files by path. Each path is resolved against the data set's folder with symlinks followed, and must end
inside that folder: an absolute path, ``..``, a glob or a symlink reaching elsewhere is refused by name,
unless the user passes ``--option allow_outside=true`` (a data set whose images genuinely live on
another disk). Files are read through :mod:`jcalib.io.schema.reading`: a size budget
(``JCALIB_MAX_INPUT_MB``; YAML and TOML 16 MiB), UTF-8, and YAML / JSON with limits on nesting, aliases
and duplicate keys. Error messages name the file and the field, never the file's contents.
"""

from __future__ import annotations

import glob as globlib
import os
from pathlib import Path
from typing import Any

from jcalib.errors import BadInputError
from jcalib.io.schema.reading import (
    MAX_DEPTH,
    check_depth,
    decode_utf8,
    max_file_bytes,
    parse_json,
    parse_yaml,
    read_bytes_limited,
)

__all__ = ["ALLOW_OUTSIDE_HELP", "SourceFolder", "flag_option", "parse_toml"]

ALLOW_OUTSIDE_HELP = ("true: follow image / pose paths that resolve outside the data set's folder (absolute, "
                      "'..', symlinks); default false: such paths are refused")
#: Most files one glob pattern may match.
MAX_GLOB_MATCHES = 100_000


def flag_option(options: dict[str, Any], name: str, fmt: str) -> bool:
    """A true / false option (``true``, ``false``, ``1``, ``0``, ``yes``, ``no``; default false)."""
    value = options.get(name, False)
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("true", "1", "yes"):
        return True
    if text in ("false", "0", "no"):
        return False
    raise BadInputError(f"import {fmt}: option {name}: expected true or false, got {str(value)[:40]!r}")


def _glob_magic(text: str) -> bool:
    return any(c in text for c in "*?[")


class SourceFolder:
    """The folder of a data set and the rule that what it names lies inside it (module docstring).

    Args:
        root: the data set's folder (the manifest's folder).
        fmt: the importer, for messages.
        allow_outside: follow paths outside ``root`` (``--option allow_outside=true``).
    """

    def __init__(self, root: str | os.PathLike, fmt: str, allow_outside: bool = False):
        self.root = Path(root)
        self.fmt = fmt
        self.allow_outside = allow_outside
        self.real = self._resolve(self.root, f"import {fmt}: {self.root}")

    @staticmethod
    def _resolve(path: Path, where: str) -> Path:
        try:
            return path.resolve()
        except (OSError, RuntimeError) as e:  # a symlink loop
            raise BadInputError(f"{where}: cannot resolve {path} ({e.__class__.__name__}: a symlink loop?)") from None

    def inside(self, real: Path) -> bool:
        """Whether the resolved path ``real`` lies in the data set's folder."""
        return real == self.real or real.is_relative_to(self.real)

    def _refuse_outside(self, value: str, real: Path, where: str, field: str) -> None:
        if not self.allow_outside and not self.inside(real):
            raise BadInputError(
                f"{where}: {field} {value[:200]!r} resolves to {real}, outside the data set's folder {self.root}; "
                "an import reads only files inside its source folder: move the file into it, or pass "
                "--option allow_outside=true if the path is meant"
            )

    def file(self, value: Any, where: str, field: str) -> Path:
        """The regular file a manifest names (relative to the folder, or absolute), symlinks resolved.

        Raises:
            BadInputError: not a path, outside the folder (unless allowed), or not an existing file.
        """
        if not isinstance(value, str) or not value.strip() or "\x00" in value:
            raise BadInputError(f"{where}: {field}: expected a file path (text), got {_kind(value)}")
        p = Path(value)
        real = self._resolve(p if p.is_absolute() else self.root / p, where)
        self._refuse_outside(value, real, where, field)
        if not real.is_file():
            raise BadInputError(f"{where}: {field} {value[:200]!r}: no such file under {self.root}"
                                + (" (a glob pattern is not expanded here)" if _glob_magic(value) else ""))
        return real

    def glob(self, pattern: Any, where: str, field: str) -> list[Path]:
        """The files a glob pattern (relative to the folder) matches, each resolved and inside the folder."""
        if not isinstance(pattern, str) or not pattern.strip() or "\x00" in pattern:
            raise BadInputError(f"{where}: {field}: expected a glob pattern (text), got {_kind(pattern)}")
        p = Path(pattern)
        if not self.allow_outside and (p.is_absolute() or ".." in p.parts):
            raise BadInputError(f"{where}: {field} {pattern[:200]!r} reaches outside the data set's folder "
                                f"{self.root} (absolute or '..'); write it relative to the folder, or pass "
                                "--option allow_outside=true")
        full = pattern if p.is_absolute() else os.path.join(globlib.escape(str(self.root)), pattern)
        out = []
        for i, m in enumerate(globlib.iglob(full)):
            if i >= MAX_GLOB_MATCHES:
                raise BadInputError(f"{where}: {field} {pattern[:200]!r} matches more than {MAX_GLOB_MATCHES} files")
            real = self._resolve(Path(m), where)
            if real.is_file():
                self._refuse_outside(m, real, where, f"{field} match")
                out.append(Path(m))
        return out

    def read_bytes(self, path: Path, what: str, kind: str = "json") -> bytes:
        """The bytes of a file inside the folder, within the size budget of ``kind`` (json, yaml)."""
        return read_bytes_limited(path, what, max_file_bytes(kind))

    def read_text(self, path: Path, what: str, kind: str = "json") -> str:
        """UTF-8 text of a file within the budget (a byte-order mark dropped)."""
        return decode_utf8(self.read_bytes(path, what, kind), str(path))

    def read_yaml(self, path: Path, what: str) -> Any:
        """One YAML document, read with the guarded loader (aliases, depth, duplicate keys, 16 MiB)."""
        return parse_yaml(self.read_text(path, what, "yaml"), str(path))

    def read_json(self, path: Path, what: str) -> Any:
        """One JSON document (duplicate keys and deep nesting refused)."""
        return parse_json(self.read_text(path, what), str(path))


def parse_toml(text: str, source: str) -> Any:
    """A TOML document (``tomllib``), nesting at most ``MAX_DEPTH`` levels.

    Raises:
        BadInputError: not TOML (with tomllib's line), or nested too deep.
    """
    import tomllib

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise BadInputError(f"{source}: not valid TOML ({str(e)[:200]})") from None
    except RecursionError:
        raise BadInputError(f"{source}: nested more than {MAX_DEPTH} levels deep; not a manifest") from None
    check_depth(data, source)
    return data


def _kind(value: Any) -> str:
    """A value's type for a message (never its contents)."""
    return "nothing" if value is None else f"a {type(value).__name__}"
