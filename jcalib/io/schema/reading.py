"""Reading input files safely: size budget, UTF-8, JSON / YAML with limits on depth and aliases.

Every input file jcalib reads (cell specs, observations, results, sessions, plans, pixel and point
files, study scenarios) goes through :func:`read_document` before any validation, so that a file
another program wrote (or an attacker crafted) gives a :class:`~jcalib.errors.BadInputError` naming
the file, the line where known, and what to do, instead of a traceback, a hang or a memory blow-up:

- the file must be a regular file (a FIFO or a device would block or never end) no larger than
  :func:`max_file_bytes` (``JCALIB_MAX_INPUT_MB``, default 256 MiB; YAML 16 MiB, it parses ~100x slower);
- it must be UTF-8 (a byte-order mark is allowed); the first bad byte is named with its line and column;
- JSON: duplicate keys in one object are refused (the second would silently win); ``NaN`` and
  ``Infinity`` are read as floats so that the schema names the key holding them;
- YAML: one document, at most :data:`MAX_ALIASES` aliases, no recursive alias, and aliases may not
  expand the document by more than :data:`MAX_ALIAS_EXPANSION` nodes (the "billion laughs" bomb);
  duplicate keys are refused with their line;
- nesting deeper than :data:`MAX_DEPTH` is refused (jcalib's formats need fewer than 12 levels).
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any

from jcalib.errors import BadInputError

__all__ = [
    "MAX_ALIASES",
    "MAX_ALIAS_EXPANSION",
    "MAX_DEPTH",
    "check_depth",
    "decode_utf8",
    "max_file_bytes",
    "parse_json",
    "parse_yaml",
    "read_bytes_limited",
    "read_document",
]

#: Deepest nesting of mappings / lists accepted in any input file.
MAX_DEPTH = 64
#: Most YAML aliases (``*name``) in one file.
MAX_ALIASES = 1000
#: Most nodes that YAML aliases may add to a document when expanded.
MAX_ALIAS_EXPANSION = 100_000
_DEFAULT_MAX_MB = 256
_DEFAULT_MAX_YAML_MB = 16


def max_file_bytes(kind: str = "json") -> int:
    """The size budget of an input file in bytes (``JCALIB_MAX_INPUT_MB``; YAML at most 16 MiB of it)."""
    raw = os.environ.get("JCALIB_MAX_INPUT_MB", "")
    try:
        mb = float(raw) if raw else float(_DEFAULT_MAX_MB)
    except ValueError:
        raise BadInputError(f"JCALIB_MAX_INPUT_MB: expected a number of megabytes, got {raw!r}") from None
    if not mb > 0:
        raise BadInputError(f"JCALIB_MAX_INPUT_MB: expected a positive number of megabytes, got {raw!r}")
    if kind == "yaml" and not raw:
        mb = _DEFAULT_MAX_YAML_MB
    return int(mb * 2**20)


def read_bytes_limited(path: str | os.PathLike, what: str, limit: int | None = None) -> bytes:
    """The bytes of a regular file no larger than ``limit`` (default :func:`max_file_bytes`).

    Raises:
        BadInputError: missing, a directory, not a regular file, unreadable, or too large.
    """
    path = Path(path)
    limit = max_file_bytes() if limit is None else limit
    try:
        st = path.stat()
    except FileNotFoundError:
        raise BadInputError(f"{what} '{path}' does not exist") from None
    except OSError as e:
        raise BadInputError(f"{what} '{path}': cannot read it ({e.strerror or e})") from None
    if stat.S_ISDIR(st.st_mode):
        raise BadInputError(f"{what} '{path}' is a directory; expected a file")
    if not stat.S_ISREG(st.st_mode):
        raise BadInputError(f"{what} '{path}' is not a regular file (a pipe or a device?); expected a file")
    if st.st_size > limit:
        raise BadInputError(
            f"{what} '{path}' is {st.st_size / 2**20:.1f} MiB, more than the {limit / 2**20:.0f} MiB jcalib reads "
            "(set JCALIB_MAX_INPUT_MB to raise the budget if the file is genuine)"
        )
    try:
        with open(path, "rb") as f:
            data = f.read(limit + 1)
    except OSError as e:
        raise BadInputError(f"{what} '{path}': cannot read it ({e.strerror or e})") from None
    if len(data) > limit:
        raise BadInputError(f"{what} '{path}' grew beyond {limit / 2**20:.0f} MiB while being read")
    return data


def decode_utf8(data: bytes, source: str) -> str:
    """``data`` as text; a byte-order mark is dropped.

    Raises:
        BadInputError: naming the line, column and value of the first byte that is not UTF-8.
    """
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        column = e.start - (data.rfind(b"\n", 0, e.start) + 1) + 1
        raise BadInputError(
            f"{source} line {line} column {column}: byte 0x{data[e.start]:02x} is not UTF-8; save the file as "
            "UTF-8 text (jcalib reads no other encoding)"
        ) from None
    return text[1:] if text.startswith("\ufeff") else text


def check_depth(value: Any, source: str, limit: int = MAX_DEPTH) -> None:
    """Refuse mappings / lists nested deeper than ``limit`` (iteratively: no recursion)."""
    stack = [(value, 1)]
    while stack:
        v, depth = stack.pop()
        if isinstance(v, dict):
            children = v.values()
        elif isinstance(v, list):
            children = v
        else:
            continue
        if depth > limit:
            raise BadInputError(f"{source}: nested more than {limit} levels deep; not a jcalib file")
        stack.extend((c, depth + 1) for c in children if isinstance(c, (dict, list)))


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise _DuplicateKey(key)
        out[key] = value
    return out


class _DuplicateKey(ValueError):
    def __init__(self, key: str):
        super().__init__(key)
        self.key = key


def parse_json(text: str, source: str) -> Any:
    """Parse JSON text (``NaN`` / ``Infinity`` read as floats for the schema to name).

    Raises:
        BadInputError: invalid JSON (line and column), a duplicate key, nesting too deep.
    """
    try:
        data = json.loads(text, object_pairs_hook=_no_duplicates)
    except json.JSONDecodeError as e:
        raise BadInputError(f"{source} line {e.lineno} column {e.colno}: not valid JSON ({e.msg})") from None
    except _DuplicateKey as e:
        raise BadInputError(
            f"{source}: the key {e.key!r} appears twice in one object; keep one (JSON readers disagree on which wins)"
        ) from None
    except RecursionError:
        raise BadInputError(f"{source}: nested more than {MAX_DEPTH} levels deep; not a jcalib file") from None
    except ValueError as e:  # e.g. an integer with more digits than Python converts
        raise BadInputError(f"{source}: not valid JSON ({str(e)[:200]})") from None
    check_depth(data, source)
    return data


def _yaml_loader():
    import yaml

    class Loader(yaml.SafeLoader):
        """SafeLoader with limits: depth, number of aliases, duplicate keys."""

        def __init__(self, stream: str):
            super().__init__(stream)
            self.depth = 0
            self.aliases = 0

        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                self.aliases += 1
                if self.aliases > MAX_ALIASES:
                    raise _Limit(f"more than {MAX_ALIASES} YAML aliases", self.peek_event().start_mark)
            self.depth += 1
            try:
                if self.depth > MAX_DEPTH:
                    raise _Limit(f"nested more than {MAX_DEPTH} levels deep", self.peek_event().start_mark)
                return super().compose_node(parent, index)
            finally:
                self.depth -= 1

        def construct_mapping(self, node, deep=False):
            if isinstance(node, yaml.MappingNode):
                seen: set = set()
                for key_node, _ in node.value:
                    if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                        continue
                    key = self.construct_scalar(key_node)
                    if key in seen:
                        raise _Limit(f"the key {key!r} appears twice in one mapping; keep one", key_node.start_mark)
                    seen.add(key)
            return super().construct_mapping(node, deep=deep)

    return Loader


class _Limit(Exception):
    def __init__(self, msg: str, mark: Any):
        super().__init__(msg)
        self.msg, self.mark = msg, mark


def _check_expansion(root: Any, source: str) -> None:
    """Refuse recursive aliases and aliases that expand the node graph by more than the limit."""
    import yaml

    distinct: set[int] = set()
    expanded: dict[int, int] = {}
    # iterative post-order walk with cycle detection (on the composed node graph)
    stack: list[tuple[Any, bool]] = [(root, False)]
    on_path: set[int] = set()
    while stack:
        node, done = stack.pop()
        key = id(node)
        kids = []
        if isinstance(node, yaml.SequenceNode):
            kids = node.value
        elif isinstance(node, yaml.MappingNode):
            kids = [n for pair in node.value for n in pair]
        if done:
            on_path.discard(key)
            expanded[key] = 1 + sum(expanded[id(k)] for k in kids)
            continue
        if key in expanded:
            continue
        if key in on_path:
            line = node.start_mark.line + 1
            raise BadInputError(f"{source} line {line}: a YAML alias refers to the structure that contains it")
        on_path.add(key)
        distinct.add(key)
        stack.append((node, True))
        for k in kids:
            if id(k) in on_path:
                line = k.start_mark.line + 1
                raise BadInputError(f"{source} line {line}: a YAML alias refers to the structure that contains it")
            if id(k) not in expanded:
                stack.append((k, False))
        if len(distinct) > 50_000_000:  # pragma: no cover - the size budget stops this first
            break
    total = expanded.get(id(root), 0)
    if total - len(distinct) > MAX_ALIAS_EXPANSION:
        raise BadInputError(
            f"{source}: YAML aliases expand the document to {total} values from {len(distinct)} "
            f"(more than {MAX_ALIAS_EXPANSION} added); write the values out or use fewer aliases"
        )


def parse_yaml(text: str, source: str) -> Any:
    """Parse one YAML document safely (``yaml.SafeLoader`` with the limits of this module).

    Raises:
        BadInputError: invalid YAML (with the line), several documents, too many or recursive
            aliases, an alias bomb, a duplicate key, nesting too deep.
    """
    import yaml

    loader = _yaml_loader()(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_expansion(node, source)
        data = loader.construct_document(node)
    except _Limit as e:
        line = f" line {e.mark.line + 1}" if e.mark is not None else ""
        raise BadInputError(f"{source}{line}: {e.msg}") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        line = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise BadInputError(f"{source}{line}: not valid YAML ({problem})") from None
    except RecursionError:
        raise BadInputError(f"{source}: nested more than {MAX_DEPTH} levels deep; not a jcalib file") from None
    finally:
        loader.dispose()
    check_depth(data, source)
    return data


def read_document(path: str | os.PathLike, what: str, fmt: str | None = None) -> Any:
    """Read a JSON or YAML file within the limits of this module.

    Args:
        path: the file.
        what: what the file is, for messages (``"cell spec"``, ``"observations file"``).
        fmt: ``"json"``, ``"yaml"``, or None to choose by suffix (``.json`` / ``.jsonl`` -> JSON,
            otherwise YAML, which also reads JSON).

    Returns:
        The parsed document (plain dicts, lists, strings, numbers, booleans, None).
    """
    path = Path(path)
    if fmt is None:
        fmt = "json" if path.suffix.lower() in (".json", ".jsonl") else "yaml"
    source = str(path)
    text = decode_utf8(read_bytes_limited(path, what, max_file_bytes(fmt)), source)
    return parse_json(text, source) if fmt == "json" else parse_yaml(text, source)
