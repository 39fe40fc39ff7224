"""The subset of URScript the simulated UR controller runs: parsing and splitting the secondary interface's stream.

A real controller compiles any URScript; the simulator (:mod:`~jcalib.acquisition.robots.ur_sim`) knows the
statements jcalib's driver sends and a few more a user may type into a terminal, one per line:

- ``def NAME():`` ... ``end`` around a program (a bare statement is a program of its own, as on a controller);
- ``[local|global] NAME = p[x, y, z, rx, ry, rz]`` (or a joint list ``[q1, ..., q6]``);
- ``set_tcp(POSE)``; ``movej(POSE | JOINTS [, a=..][, v=..][, t=..][, r=..])``; ``movel(POSE [, a=..][, v=..])``;
- ``if not get_inverse_kin_has_solution(POSE):`` ... ``end``;
- ``write_output_integer_register(N, VALUE)`` (N = 0..47, a 32-bit integer);
- ``stopj(a)``, ``stopl(a)``, ``halt``, ``protective_stop()`` (UR's, e-Series 5.x), ``sleep(s)``, ``sync()``,
  ``textmsg("...")``;

where POSE is a pose literal or a variable holding one. Anything else does not compile: the program is refused
as a whole (a controller reports the syntax error and runs nothing). Numbers must be finite.

:func:`split_program` cuts the byte stream of the secondary interface into programs: a ``def``/``sec`` block up
to its matching ``end`` line, or else one line.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

#: Largest program (and largest unfinished block the stream may hold), bytes.
MAX_PROGRAM_BYTES = 65536
MAX_STATEMENTS = 2000
MAX_DEPTH = 16

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_NAME = r"[A-Za-z_][A-Za-z0-9_]*"
_VEC6 = rf"\[\s*{_NUM}(?:\s*,\s*{_NUM}){{5}}\s*\]"
_POSE = rf"p{_VEC6}"
_VALUE = rf"(?:{_POSE}|{_VEC6}|{_NAME})"
_PATTERNS = [
    ("def", re.compile(rf"^def\s+({_NAME})\s*\(\s*\)\s*:$")),
    ("end", re.compile(r"^end$")),
    ("assign", re.compile(rf"^(?:(?:local|global)\s+)?({_NAME})\s*=\s*({_POSE}|{_VEC6})$")),
    ("set_tcp", re.compile(rf"^set_tcp\(\s*({_VALUE})\s*\)$")),
    ("move", re.compile(rf"^(movej|movel)\(\s*({_VALUE})\s*((?:,\s*[avtr]\s*=\s*{_NUM}\s*)*)\)$")),
    ("if_no_ik", re.compile(rf"^if\s+not\s+get_inverse_kin_has_solution\(\s*({_VALUE})\s*\)\s*:$")),
    ("register", re.compile(rf"^write_output_integer_register\(\s*(\d{{1,2}})\s*,\s*([-+]?\d{{1,10}})\s*\)$")),
    ("stop", re.compile(rf"^(stopj|stopl)\(\s*({_NUM})\s*\)$")),
    ("halt", re.compile(r"^halt$")),
    ("protective_stop", re.compile(r"^protective_stop\(\s*\)$")),
    ("sleep", re.compile(rf"^sleep\(\s*({_NUM})\s*\)$")),
    ("sync", re.compile(r"^sync\(\s*\)$")),
    ("textmsg", re.compile(r'^textmsg\(\s*"[^"]*"\s*\)$')),
]
_BLOCK_OPEN = re.compile(r"^(def|sec|thread|if|while|for)\b.*:$")


class ScriptError(ValueError):
    """A program the simulated controller cannot compile (the message names the line)."""


@dataclass
class Statement:
    """One statement: its kind (a key of the grammar), arguments, and the body of an ``if``."""

    kind: str
    args: tuple = ()
    body: list["Statement"] = field(default_factory=list)
    line: int = 0


def _numbers(text: str, line: int) -> tuple[float, ...]:
    values = tuple(float(v) for v in re.findall(_NUM, text))
    if not all(math.isfinite(v) for v in values):
        raise ScriptError(f"line {line}: a number is not finite")
    return values


def _value(text: str, variables: dict[str, str], line: int) -> tuple[str, tuple[float, ...]]:
    """``("pose" | "joints", numbers)`` of a value argument; variables resolve to what was assigned."""
    text = text.strip()
    if text.startswith("p["):
        return "pose", _numbers(text[1:], line)
    if text.startswith("["):
        return "joints", _numbers(text, line)
    if text not in variables:
        raise ScriptError(f"line {line}: variable {text!r} is not defined")
    return _value(variables[text], variables, line)


def _strip(line: str) -> str:
    """The line without its comment and surrounding blanks (a ``#`` inside a string is kept)."""
    out, quoted = [], False
    for ch in line:
        if ch == '"':
            quoted = not quoted
        elif ch == "#" and not quoted:
            break
        out.append(ch)
    return "".join(out).strip()


def parse_program(text: str) -> list[Statement]:
    """The statements of one program (``def`` wrapper removed).

    Raises:
        ScriptError: anything outside the subset (module docstring), unbalanced blocks, non-finite numbers,
            a register out of 0..47, a value out of 32 bits, too long or too deep.
    """
    if len(text) > MAX_PROGRAM_BYTES or not text.isascii():
        raise ScriptError("the program is not ASCII text of at most 64 KiB")
    lines = [(i + 1, _strip(raw)) for i, raw in enumerate(text.split("\n"))]
    lines = [(i, s) for i, s in lines if s]
    if not lines:
        raise ScriptError("empty program")
    wrapped = lines[0][1].startswith("def ")
    if wrapped:
        if not _PATTERNS[0][1].match(lines[0][1]) or lines[-1][1] != "end":
            raise ScriptError(f"line {lines[0][0]}: expected 'def NAME():' ... 'end'")
        lines = lines[1:-1]
    variables: dict[str, str] = {}
    root: list[Statement] = []
    stack = [root]
    count = 0
    for number, s in lines:
        kind, m = next(((k, p.match(s)) for k, p in _PATTERNS if p.match(s)), (None, None))
        if kind is None or kind == "def":
            raise ScriptError(f"line {number}: not understood by the simulated controller: {s[:80]!r}")
        count += 1
        if count > MAX_STATEMENTS:
            raise ScriptError(f"more than {MAX_STATEMENTS} statements")
        if kind == "end":
            if len(stack) == 1:
                raise ScriptError(f"line {number}: 'end' without a block")
            stack.pop()
            continue
        st = Statement(kind, line=number)
        if kind == "assign":
            _value(m.group(2), variables, number)  # checks the numbers
            variables[m.group(1)] = m.group(2)
            continue
        if kind in ("set_tcp", "if_no_ik"):
            what, v = _value(m.group(1), variables, number)
            if what != "pose":
                raise ScriptError(f"line {number}: expected a pose p[...], got a joint list")
            st.args = (v,)
        elif kind == "move":
            what, v = _value(m.group(2), variables, number)
            if m.group(1) == "movel" and what != "pose":
                raise ScriptError(f"line {number}: movel takes a pose p[...]")
            params = dict(re.findall(rf"([avtr])\s*=\s*({_NUM})", m.group(3)))
            opts = {k: _numbers(x, number)[0] for k, x in params.items()}
            if any(v_ < 0 for v_ in opts.values()):
                raise ScriptError(f"line {number}: negative speed, acceleration, time or radius")
            st.args = (m.group(1), what, v, opts)
        elif kind == "register":
            index, value = int(m.group(1)), int(m.group(2))
            if not 0 <= index <= 47 or not -(2**31) <= value < 2**31:
                raise ScriptError(f"line {number}: output integer register {index} = {value} out of range")
            st.args = (index, value)
        elif kind in ("stop", "sleep"):
            values = _numbers(m.group(2) if kind == "stop" else m.group(1), number)
            if values[0] < 0 or (kind == "stop" and values[0] == 0):
                raise ScriptError(f"line {number}: expected a positive number")
            st.args = ((m.group(1),) if kind == "stop" else ()) + values
        stack[-1].append(st)
        if kind == "if_no_ik":
            if len(stack) > MAX_DEPTH:
                raise ScriptError(f"line {number}: blocks nested deeper than {MAX_DEPTH}")
            stack.append(st.body)
    if len(stack) != 1:
        raise ScriptError("a block is not closed with 'end'")
    return root


def split_program(buffer: bytes) -> tuple[str | None, int]:
    """The first complete program in the secondary interface's byte stream, and how many bytes it took.

    Returns ``(None, 0)`` while the program is incomplete, ``("", n)`` for ``n`` bytes of blank lines.

    Raises:
        ScriptError: bytes that are not ASCII text, or an incomplete program longer than
            :data:`MAX_PROGRAM_BYTES` (the connection is dropped).
    """
    try:
        text = buffer.decode("ascii")
    except UnicodeDecodeError:
        raise ScriptError("the stream holds bytes that are not ASCII text") from None
    if "\x00" in text:
        raise ScriptError("the stream holds NUL bytes")
    stripped = text.lstrip()
    skipped = len(text) - len(stripped)
    if not stripped:
        return ("", len(text)) if text else (None, 0)
    first = stripped.split("\n", 1)[0].strip()
    if not re.match(r"^(def|sec)\s", first):
        i = stripped.find("\n")
        if i < 0:
            if len(buffer) > MAX_PROGRAM_BYTES:
                raise ScriptError("a line longer than 64 KiB")
            return None, 0
        return stripped[:i], skipped + i + 1
    depth, pos = 0, 0
    while True:
        i = stripped.find("\n", pos)
        if i < 0:
            if len(buffer) > MAX_PROGRAM_BYTES:
                raise ScriptError("a program longer than 64 KiB")
            return None, 0
        line = _strip(stripped[pos:i])
        pos = i + 1
        if _BLOCK_OPEN.match(line):
            depth += 1
        elif line == "end":
            depth -= 1
            if depth <= 0:
                return stripped[:i], skipped + pos
