"""The building blocks of jcalib's file schemas (pydantic v2) and the one way their errors are reported.

Why pydantic: the schemas are plain typed classes next to the code that reads them (no second
language), validation runs in Rust (a 200k-pixel observations file validates in ~0.2 s), every
error carries its key path (``stations.3.detections.1.pixels.5.1``), strict mode refuses a string
where a number belongs, and ``model_json_schema()`` can publish the schemas for editors.

Conventions of every schema here:

- strict types: no string-to-number coercion in JSON files, no bool for a number, no float for an
  integer (a fractional ``point_index`` is refused, not truncated); YAML files (cell specs, plans,
  scenarios) accept a number written as text such as ``1e-4`` (YAML 1.1 reads exponents without a
  ``.`` as strings), nothing else;
- every number finite: ``NaN`` / ``Infinity`` / ``1e999`` are named with their key path;
- unknown keys are refused with a "did you mean" suggestion where a known key is close;
- names (camera, target, tool, point, robot ids, station ids) are non-empty, at most 64 characters,
  without control characters, path separators, brackets, quotes or surrounding spaces: they become
  file names (``images/<camera>/<station>.png``), controller identifiers and console text.
"""

from __future__ import annotations

import difflib
import re
import reprlib
import unicodedata
from collections.abc import Iterable
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, StringConstraints, ValidationError, model_validator
from pydantic_core import PydanticCustomError

from jcalib.errors import BadInputError

__all__ = [
    "FORBIDDEN_NAME_CHARACTERS",
    "Closed",
    "Int",
    "NAME_PATTERN",
    "NUMERIC_TEXT_PATTERN",
    "Name",
    "NameText",
    "Num",
    "NumericText",
    "Open",
    "SchemaError",
    "StationId",
    "YNum",
    "check_name",
    "did_you_mean",
    "fail",
    "format_value",
    "validate",
]

_short = reprlib.Repr()
_short.maxstring = 60
_short.maxother = 60
_short.maxlist = 6
_short.maxdict = 4
_short.maxlevel = 2


def format_value(value: Any) -> str:
    """A short, single-line repr of a user value for messages (never the whole structure)."""
    text = _short.repr(value)
    return text if len(text) <= 120 else text[:117] + "..."


def did_you_mean(word: Any, choices: Iterable[str]) -> str:
    """``"; did you mean 'x'?"`` when a choice is close to ``word``, else ``""``."""
    if not isinstance(word, str):
        return ""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    if not close:
        lowered = {c.lower(): c for c in choices}
        if word.lower() in lowered:
            close = [lowered[word.lower()]]
    return f"; did you mean {close[0]!r}?" if close else ""


class SchemaError(BadInputError):
    """A file does not follow its schema.

    Attributes:
        source: the file (or ``"<dict>"``).
        problems: ``(key path, message)`` pairs, the first ones found (the message shows up to 5).
    """

    def __init__(self, source: str, problems: list[tuple[str, str]], total: int | None = None):
        self.source = source
        self.problems = problems
        total = len(problems) if total is None else total
        self.total = total
        shown = [f"{path}: {msg}" if path else msg for path, msg in problems[:5]]
        more = f" (and {total - len(shown)} more problems)" if total > len(shown) else ""
        super().__init__(f"{source}: " + "; ".join(shown) + more)

    @property
    def key_path(self) -> str:
        """The key path of the first problem, e.g. ``"cameras.cam0.model"``."""
        return self.problems[0][0] if self.problems else ""


def fail(source: str, path: str, msg: str) -> SchemaError:
    """A :class:`SchemaError` with one problem."""
    return SchemaError(source, [(path, msg)])


# ------------------------------------------------------------------------------------------ names

#: Characters a name may not contain (besides control characters and surrounding spaces).
FORBIDDEN_NAME_CHARACTERS = "/\\[]\"'`"
_MAX_NAME = 64


#: Names made only of ASCII letters, digits, ``_ - .`` and inner spaces, not starting with '.': valid without
#: looking at each character's Unicode category (almost every name; a 100-view document has thousands).
_PLAIN_NAME = re.compile(r"[A-Za-z0-9_-](?:[A-Za-z0-9_. -]*[A-Za-z0-9_.-])?")


def check_name(value: Any, what: str = "name") -> str:
    """``value`` if it is a valid name (see the module docstring), else ValueError saying why."""
    if type(value) is str and len(value) <= _MAX_NAME and _PLAIN_NAME.fullmatch(value):
        return value
    if not isinstance(value, str):
        raise ValueError(f"expected a {what} (text), got {format_value(value)}")
    if not value:
        raise ValueError(f"expected a non-empty {what}")
    if len(value) > _MAX_NAME:
        raise ValueError(f"a {what} has at most {_MAX_NAME} characters, got {len(value)}")
    bad = sorted({c for c in value if unicodedata.category(c)[0] in "CZ" and c != " " or c in FORBIDDEN_NAME_CHARACTERS})
    if bad or value != value.strip() or value.startswith("."):
        why = (f"contains {', '.join(repr(c) for c in bad[:5])}{' and more' if len(bad) > 5 else ''}" if bad else
               "starts with '.'" if value.startswith(".") else "has spaces around it")
        raise ValueError(
            f"the {what} {value!r} {why}; names become file names, controller identifiers and console text: "
            "use letters, digits, '_', '-' or '.'"
        )
    return value


def _name(value: Any) -> Any:
    try:
        return check_name(value)
    except ValueError as e:
        raise PydanticCustomError("jcalib_name", "{why}", {"why": str(e)}) from None


def _station_id(value: Any) -> Any:
    if isinstance(value, int) and not isinstance(value, bool):
        value = str(value)
    return _name(value)


#: What a JSON Schema can say of a name (the published schemas, :mod:`jcalib.io.schema.export`): 1 to 64
#: characters, no control characters or :data:`FORBIDDEN_NAME_CHARACTERS`, no spaces around it, not starting
#: with '.' (:func:`check_name` also refuses other Unicode separators and format characters).
NAME_PATTERN = r"""^(?![.\s])(?!.*\s$)[^\x00-\x1f\x7f/\\\[\]"'`]+$"""
NameText = Annotated[str, StringConstraints(min_length=1, max_length=_MAX_NAME, pattern=NAME_PATTERN)]
#: A name (camera, target, tool, point, robot id): see the module docstring.
Name = Annotated[str, BeforeValidator(_name, json_schema_input_type=NameText)]
#: A station id: a name, or an integer (read as its decimal text).
StationId = Annotated[str, BeforeValidator(_station_id, json_schema_input_type=NameText | int)]

# ---------------------------------------------------------------------------------------- numbers

#: A finite number (int or float, not bool), strict: what JSON files hold.
Num = Annotated[float, Field(strict=True, allow_inf_nan=False)]
_NUMERIC_TEXT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def yaml_number(value: Any) -> Any:
    if isinstance(value, str) and _NUMERIC_TEXT.fullmatch(value.strip()):
        return float(value)
    return value


#: A number written as text in a YAML file (what :func:`yaml_number` reads), for the published schemas.
NUMERIC_TEXT_PATTERN = r"^\s*" + _NUMERIC_TEXT.pattern + r"\s*$"
NumericText = Annotated[str, StringConstraints(pattern=NUMERIC_TEXT_PATTERN)]
#: A finite number in a YAML file: also a number written as text (``1e-4`` is a string in YAML 1.1).
YNum = Annotated[float, BeforeValidator(yaml_number, json_schema_input_type=float | NumericText),
                 Field(strict=True, allow_inf_nan=False)]
#: An integer (not bool, not float).
Int = Annotated[int, Field(strict=True)]


# ----------------------------------------------------------------------------------------- models


class Closed(BaseModel):
    """A mapping with known keys only: an unknown key is refused with a suggestion."""

    model_config = ConfigDict(extra="forbid", strict=True, populate_by_name=False)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            allowed = sorted(f.alias or n for n, f in cls.model_fields.items())
            for key in data:
                if key not in allowed:
                    raise PydanticCustomError(
                        "jcalib_unknown_key", "{why}",
                        {"key": key, "why": f"unknown key{did_you_mean(key, allowed)} (allowed: {', '.join(allowed)})"},
                    )
        return data


class Open(BaseModel):
    """A mapping whose unknown keys are kept (forward compatible formats: results, sessions)."""

    model_config = ConfigDict(extra="allow", strict=True)


# ------------------------------------------------------------------------------------ validation

_FRIENDLY = {
    "missing": "missing (required)",
    "string_type": "expected text",
    "int_type": "expected an integer",
    "int_from_float": "expected an integer",
    "float_type": "expected a number",
    "float_parsing": "expected a number",
    "finite_number": "expected a finite number",
    "bool_type": "expected true or false",
    "list_type": "expected a list",
    "dict_type": "expected a mapping",
    "model_type": "expected a mapping",
    "model_attributes_type": "expected a mapping",
    "none_required": "expected null",
}


def _walk(data: Any, loc: tuple) -> tuple[str, Any, bool]:
    """The key path of ``loc`` in ``data``, the value there (the key itself for a bad key), and
    whether the problem is a mapping's key. Segments that are not in the data (a union member's
    type name) are dropped; a missing key ends the path."""
    parts: list[str] = []
    cur: Any = data
    is_key = False
    for i, seg in enumerate(loc):
        if seg == "[key]":
            continue
        key_next = i + 1 < len(loc) and loc[i + 1] == "[key]"
        if isinstance(cur, dict) and seg in cur:
            parts.append(str(seg))
            if key_next:
                cur, is_key = seg, True
                break
            cur = cur[seg]
        elif isinstance(cur, list) and isinstance(seg, int) and not isinstance(seg, bool) and 0 <= seg < len(cur):
            parts.append(f"[{seg}]")
            cur = cur[seg]
        elif isinstance(cur, dict) and isinstance(seg, str) and "[" not in seg and "-" not in seg:
            parts.append(seg)  # a missing key
            cur = None
            break
    path = ""
    for p in parts:
        path += p if (p.startswith("[") or not path) else "." + p
    return path, cur, is_key


def _message(err: dict, value: Any, is_key: bool) -> str:
    kind = err["type"]
    ctx = err.get("ctx") or {}
    if kind.startswith("jcalib_"):
        return str(ctx.get("why", err["msg"]))
    if kind == "value_error":
        msg = str(ctx.get("error", err["msg"]))
        return msg[len("Value error, "):] if msg.startswith("Value error, ") else msg
    if kind == "literal_error":
        expected = ctx.get("expected", "")
        options = re.findall(r"'([^']*)'", expected)
        return f"got {format_value(value)}, expected {expected}{did_you_mean(value, options)}"
    if kind in ("too_short", "too_long"):
        n = len(value) if hasattr(value, "__len__") else "?"
        lo, hi = ctx.get("min_length"), ctx.get("max_length")
        want = ctx.get("field_type", "values").lower()
        if kind == "too_short" and lo is not None:
            expected = f"at least {lo}"
        else:
            expected = f"at most {hi}" if hi is not None else "fewer"
        return f"expected {expected} {'entries' if want in ('list', 'dictionary') else want}, got {n}"
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        op = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}[kind]
        bound = next(iter(ctx.values()), "?")
        return f"expected a number {op} {bound}, got {format_value(value)}"
    if kind == "missing":
        return _FRIENDLY["missing"]
    base = _FRIENDLY.get(kind, err["msg"])
    if is_key:
        return f"a key must be text, got {format_value(value)}"
    if kind == "finite_number":
        return f"{base}, got {value!r} (NaN or infinity); remove or re-measure it"
    return f"{base}, got {format_value(value)}"


def validate(model: type[BaseModel], data: Any, source: str, max_problems: int = 5) -> BaseModel:
    """``model`` validated from ``data``.

    Raises:
        SchemaError: naming ``source``, the key path of each problem (up to ``max_problems``) and
            what was expected, with "did you mean" suggestions for misspelt keys and choices.
    """
    try:
        return model.model_validate(data)
    except ValidationError as e:
        errors = e.errors(include_url=False, include_input=False)
        problems: list[tuple[str, str]] = []
        seen: set[str] = set()
        for err in errors[:10_000]:
            path, value, is_key = _walk(data, tuple(err["loc"]))
            key = (err.get("ctx") or {}).get("key") if err["type"].startswith("jcalib_") else None
            if key is not None:
                path = f"{path}.{key}" if path else str(key)
            if path in seen:  # several reasons for one value (union members): the first one
                continue
            seen.add(path)
            if len(problems) < max_problems:
                problems.append((path, _message(err, value, is_key)))
        raise SchemaError(source, problems, total=max(len(seen), len(problems))) from None
