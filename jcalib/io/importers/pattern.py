"""File-name patterns of import manifests, matched in linear time (no catastrophic backtracking).

calibration-rs pairs images with robot poses by a regular expression with a named group
(``'^Cam\\d+_(?<view>\\d+)\\.png$'``). The manifest's tool matches it with Rust's ``regex`` crate,
which runs in time linear in the name; Python's ``re`` backtracks, and a pattern such as
``(\\d+)+_`` takes exponential time on a long numeric name. This module compiles the subset of the
syntax that file-name patterns use into a small program and runs it as a Pike VM (Thompson's
simulation with capture slots, leftmost-first like Rust and Python): time
O(len(pattern) x len(name)) whatever the pattern.

Syntax: literals; ``.``; classes ``[a-z0-9_]`` / ``[^...]`` (with ``\\d \\w \\s`` inside);
``\\d \\D \\w \\W \\s \\S``; escaped punctuation (``\\.``); anchors ``^ $ \\A \\z``; groups ``(...)``,
``(?:...)``, named ``(?<name>...)`` or ``(?P<name>...)``; alternation ``|``; repeats ``* + ?``,
``{n} {n,} {n,m}`` (at most :data:`MAX_REPEAT`), each optionally lazy (``*?``). Anything else (flags,
look-around, back-references, ``\\b``) is refused with its position.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["MAX_PATTERN", "MAX_REPEAT", "FilenamePattern", "PatternError"]

#: Longest pattern accepted (characters).
MAX_PATTERN = 1000
#: Largest bound of a counted repeat ``{n,m}``.
MAX_REPEAT = 1000
#: Largest compiled program (instructions): bounds the work per character of a name.
MAX_PROGRAM = 20_000

_CLASSES: dict[str, Callable[[str], bool]] = {
    "d": str.isdecimal,
    "w": lambda c: c.isalnum() or c == "_",
    "s": str.isspace,
}


class PatternError(ValueError):
    """A pattern outside the supported syntax; the message names the position."""


@dataclass
class _Node:
    kind: str  # char, cat, alt, rep, group, assert
    pred: Callable[[str], bool] | None = None
    items: list | None = None
    lo: int = 0
    hi: int | None = None
    greedy: bool = True
    index: int | None = None
    what: str = ""


class _Parser:
    def __init__(self, text: str):
        self.s, self.i, self.names = text, 0, {}

    def fail(self, msg: str) -> PatternError:
        return PatternError(f"{msg} at position {self.i}")

    def peek(self) -> str | None:
        return self.s[self.i] if self.i < len(self.s) else None

    def take(self) -> str:
        c = self.peek()
        if c is None:
            raise self.fail("unexpected end of the pattern")
        self.i += 1
        return c

    def parse(self) -> _Node:
        node = self.alt()
        if self.peek() is not None:
            raise self.fail(f"unexpected {self.peek()!r}")
        return node

    def alt(self) -> _Node:
        items = [self.cat()]
        while self.peek() == "|":
            self.i += 1
            items.append(self.cat())
        return items[0] if len(items) == 1 else _Node("alt", items=items)

    def cat(self) -> _Node:
        items = []
        while self.peek() not in (None, "|", ")"):
            items.append(self.repeat(self.atom()))
        return _Node("cat", items=items)

    def number(self) -> int:
        start = self.i
        while self.peek() is not None and self.peek().isdigit() and self.i - start < 6:
            self.i += 1
        if start == self.i:
            raise self.fail("expected a number in {n,m}")
        return int(self.s[start:self.i])

    def repeat(self, node: _Node) -> _Node:
        while self.peek() in ("*", "+", "?", "{"):
            if node.kind == "assert":
                raise self.fail("a repeat of an anchor")
            c = self.take()
            if c == "{":
                lo = self.number()
                hi: int | None = lo
                if self.peek() == ",":
                    self.i += 1
                    hi = None if self.peek() == "}" else self.number()
                if self.take() != "}":
                    raise self.fail("expected '}'")
                if lo > MAX_REPEAT or (hi is not None and (hi > MAX_REPEAT or hi < lo)):
                    raise self.fail(f"repeat bounds {{{lo},{hi}}} (at most {MAX_REPEAT}, lower <= upper)")
            else:
                lo, hi = {"*": (0, None), "+": (1, None), "?": (0, 1)}[c]
            greedy = True
            if self.peek() == "?":
                self.i += 1
                greedy = False
            node = _Node("rep", items=[node], lo=lo, hi=hi, greedy=greedy)
        return node

    def atom(self) -> _Node:
        c = self.take()
        if c == "(":
            index = None
            if self.peek() == "?":
                self.i += 1
                kind = self.take()
                if kind == ":":
                    pass
                elif kind == "<" or (kind == "P" and self.take() == "<"):
                    end = self.s.find(">", self.i)
                    name = self.s[self.i:end] if end > 0 else ""
                    if not name.isidentifier():
                        raise self.fail("a group name must be letters, digits and '_'")
                    if name in self.names:
                        raise self.fail(f"group name {name!r} used twice")
                    self.i = end + 1
                    index = self.names[name] = len(self.names) + 1
                else:
                    raise self.fail("flags and look-around are not supported in file-name patterns")
            else:
                index = len(self.names) + 1
                self.names[f"_{index}"] = index
            inner = self.alt()
            if self.take() != ")":
                raise self.fail("expected ')'")
            return _Node("group", items=[inner], index=index)
        if c == "[":
            return _Node("char", pred=self.char_class())
        if c == ".":
            return _Node("char", pred=lambda ch: ch != "\n")
        if c == "^":
            return _Node("assert", what="start")
        if c == "$":
            return _Node("assert", what="end")
        if c == "\\":
            e = self.take()
            if e in "Az":
                return _Node("assert", what="start" if e == "A" else "end")
            return _Node("char", pred=self.escape(e))
        if c in "*+?{)":
            raise self.fail(f"{c!r} with nothing to repeat or close")
        return _Node("char", pred=c.__eq__)

    def escape(self, e: str) -> Callable[[str], bool]:
        if e.lower() in _CLASSES:
            f = _CLASSES[e.lower()]
            return f if e.islower() else (lambda ch: not f(ch))
        if e in "nt":
            return {"n": "\n", "t": "\t"}[e].__eq__
        if not e.isalnum():
            return e.__eq__
        raise self.fail(f"the escape \\{e} is not supported in file-name patterns")

    def char_class(self) -> Callable[[str], bool]:
        negate = self.peek() == "^"
        if negate:
            self.i += 1
        preds: list[Callable[[str], bool]] = []
        first = True
        while True:
            c = self.take()
            if c == "]" and not first:
                break
            first = False
            if c == "\\":
                preds.append(self.escape(self.take()))
                continue
            if self.peek() == "-" and self.i + 1 < len(self.s) and self.s[self.i + 1] != "]":
                self.i += 1
                hi = self.take()
                if hi == "\\":
                    hi = self.take()
                if hi < c:
                    raise self.fail(f"range {c}-{hi} is reversed")
                preds.append(lambda ch, a=c, b=hi: a <= ch <= b)
            else:
                preds.append(c.__eq__)
        if negate:
            return lambda ch: ch != "\n" and not any(p(ch) for p in preds)
        return lambda ch: any(p(ch) for p in preds)


# program instructions: (op, a, b) with op in CHAR (a = predicate), SPLIT (a preferred, b), JMP a,
# SAVE a (slot), ASSERT a (start / end), MATCH
_CHAR, _SPLIT, _JMP, _SAVE, _ASSERT, _MATCH = range(6)


def _emit(node: _Node, prog: list) -> None:
    if len(prog) > MAX_PROGRAM:
        raise PatternError(f"the pattern compiles to more than {MAX_PROGRAM} steps; use smaller repeat counts")
    if node.kind == "char":
        prog.append([_CHAR, node.pred, None])
    elif node.kind == "assert":
        prog.append([_ASSERT, node.what, None])
    elif node.kind == "cat":
        for n in node.items or []:
            _emit(n, prog)
    elif node.kind == "group":
        if node.index is not None:
            prog.append([_SAVE, 2 * node.index, None])
        _emit(node.items[0], prog)
        if node.index is not None:
            prog.append([_SAVE, 2 * node.index + 1, None])
    elif node.kind == "alt":
        jumps = []
        for n in node.items[:-1]:
            split = len(prog)
            prog.append([_SPLIT, split + 1, None])
            _emit(n, prog)
            jumps.append(len(prog))
            prog.append([_JMP, None, None])
            prog[split][2] = len(prog)
        _emit(node.items[-1], prog)
        for j in jumps:
            prog[j][1] = len(prog)
    else:  # rep
        body = node.items[0]
        for _ in range(node.lo):
            _emit(body, prog)
        if node.hi is None:
            loop = len(prog)
            prog.append([_SPLIT, None, None])
            _emit(body, prog)
            prog.append([_JMP, loop, None])
            _set_split(prog[loop], loop + 1, len(prog), node.greedy)
        else:
            splits = []
            for _ in range(node.hi - node.lo):
                splits.append(len(prog))
                prog.append([_SPLIT, None, None])
                _emit(body, prog)
            for s in splits:
                _set_split(prog[s], s + 1, len(prog), node.greedy)


def _set_split(ins: list, body: int, out: int, greedy: bool) -> None:
    ins[1], ins[2] = (body, out) if greedy else (out, body)


@dataclass(frozen=True)
class PatternMatch:
    """The groups of a match: name -> text (None: the group took no part)."""

    groups: dict[str, str | None]

    def group(self, name: str) -> str | None:
        return self.groups.get(name)


class FilenamePattern:
    """A compiled file-name pattern (module docstring).

    Raises:
        PatternError: a pattern outside the supported syntax, or too large.
    """

    def __init__(self, pattern: str):
        if not isinstance(pattern, str):
            raise PatternError(f"expected a pattern (text), got {type(pattern).__name__}")
        if len(pattern) > MAX_PATTERN:
            raise PatternError(f"the pattern has {len(pattern)} characters, more than {MAX_PATTERN}")
        parser = _Parser(pattern)
        tree = parser.parse()
        self.groupindex = {k: v for k, v in parser.names.items() if not k.startswith("_")}
        self._slots = 2 * (len(parser.names) + 1)
        prog: list = []
        _emit(tree, prog)
        prog.append([_MATCH, None, None])
        self._prog = [tuple(p) for p in prog]

    def _add(self, threads: list, seen: set, pc: int, caps: tuple, pos: int, n: int) -> None:
        stack = [(pc, caps)]
        prog = self._prog
        while stack:
            pc, caps = stack.pop()
            if pc in seen:
                continue
            seen.add(pc)
            op, a, b = prog[pc]
            if op == _JMP:
                stack.append((a, caps))
            elif op == _SPLIT:
                stack.append((b, caps))
                stack.append((a, caps))
            elif op == _SAVE:
                stack.append((pc + 1, caps[:a] + (pos,) + caps[a + 1:]))
            elif op == _ASSERT:
                if (a == "start" and pos == 0) or (a == "end" and pos == n):
                    stack.append((pc + 1, caps))
            else:
                threads.append((pc, caps))

    def search(self, text: str) -> PatternMatch | None:
        """The leftmost-first match anywhere in ``text`` (as ``re.search``), or None."""
        n = len(text)
        start = (None,) * self._slots
        current: list = []
        seen: set = set()
        matched = None
        for i in range(n + 1):
            if matched is None:
                self._add(current, seen, 0, start[:0] + (i,) + start[1:], i, n)
            nxt: list = []
            nseen: set = set()
            for pc, caps in current:
                op, a, _ = self._prog[pc]
                if op == _MATCH:
                    matched = caps
                    break  # lower-priority threads lose
                if i < n and a(text[i]):
                    self._add(nxt, nseen, pc + 1, caps, i + 1, n)
            current, seen = nxt, nseen
            if not current and matched is not None:
                break
        if matched is None:
            return None
        return PatternMatch({name: (None if matched[2 * k] is None or matched[2 * k + 1] is None
                                    else text[matched[2 * k]:matched[2 * k + 1]])
                             for name, k in self.groupindex.items()})
