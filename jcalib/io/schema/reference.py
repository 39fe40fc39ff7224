"""Markdown reference pages of the file formats, made from their JSON Schemas (:mod:`jcalib.io.schema.export`).

One table per format: every key by its path (``cameras.<name>.model``, ``stations[].detections[].pixels``),
its type, whether it is required, its default and its description, in the order of the models.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from jcalib.io.schema.base import NAME_PATTERN, NUMERIC_TEXT_PATTERN

__all__ = ["Row", "markdown", "rows"]

_CLOSED = "Unknown keys are refused."
_BOUNDS = {"exclusiveMinimum": ">", "minimum": "≥", "exclusiveMaximum": "<", "maximum": "≤"}
_OPEN = "Unknown keys are kept (a newer file survives a round trip through older code)."


@dataclass(frozen=True)
class Row:
    """One key of a format: ``path`` (``<name>`` for a mapping's keys, ``[]`` for a list's entries)."""

    path: str
    type: str
    required: bool
    default: str
    description: str


class _Walker:
    def __init__(self, schema: dict):
        self.defs = schema.get("$defs", {})

    def resolve(self, s: Any) -> Any:
        while isinstance(s, dict) and "$ref" in s:
            s = self.defs[s["$ref"].rsplit("/", 1)[-1]]
        return s

    def unwrap(self, s: Any) -> Any:
        """``s`` without its ``null`` alternative, resolved."""
        s = self.resolve(s)
        if isinstance(s, dict) and "anyOf" in s:
            rest = [b for b in s["anyOf"] if b.get("type") != "null"]
            if len(rest) == 1:
                return self.resolve(rest[0])
        return s

    def type_text(self, s: Any) -> str:
        if s is True or s == {}:
            return "any"
        ref = s.get("$ref")
        if ref:
            return self.type_text(self.resolve(s))
        if "anyOf" in s:  # a number written as text in YAML is said once on the page, not at every number
            bounds = {k: s[k] for k in _BOUNDS if k in s}  # pydantic puts a YAML number's range beside its anyOf
            parts = [self.type_text({**b, **bounds} if b.get("type") in ("number", "integer") else b)
                     for b in s["anyOf"] if b.get("pattern") != NUMERIC_TEXT_PATTERN]
            return " or ".join(dict.fromkeys(parts))
        if "const" in s:
            return f"`{json.dumps(s['const'])}`"
        if "enum" in s:
            return "one of " + ", ".join(f"`{json.dumps(v) if not isinstance(v, str) else v}`" for v in s["enum"])
        kind = s.get("type")
        if kind == "array":
            items = s.get("items", {})
            n, inner = s.get("minItems"), self.resolve(items)
            if n is not None and n == s.get("maxItems") and inner.get("type") == "array":
                m = inner.get("minItems")
                if m is not None and m == inner.get("maxItems"):
                    return f"{n}x{m} array of {self.type_text(inner.get('items', {}))}"
            size = (f"{n} " if n == s.get("maxItems") and n is not None else
                    "" if not n else f"{n} or more ")
            return f"array of {size}{self.type_text(items)}"
        if kind == "object":
            if "properties" in s:
                return "mapping"
            values = s.get("additionalProperties")
            if isinstance(values, dict) and values:
                text = self.type_text(values)
                keys = "name" if s.get("propertyNames", {}).get("pattern") == NAME_PATTERN else "string"
                return f"mapping of {keys} to {f'({text})' if ' or ' in text else text}"
            return "mapping"
        if kind == "string" and s.get("pattern") == NAME_PATTERN:
            return "name"
        text = kind or "any"
        bounds = [f"{op} {s[k]:g}" for k, op in _BOUNDS.items() if k in s]
        if bounds:
            text += " " + ", ".join(bounds)
        if kind == "string" and "maxLength" in s:
            text += f" (at most {s['maxLength']} characters)"
        return text

    def children(self, prop: Any, path: str) -> list[tuple[str, dict]]:
        """The objects whose keys are listed under ``path``: the value itself, a mapping's values, a list's entries
        (also for each alternative of a union: a number or a list of numbers)."""
        s = self.unwrap(prop)
        out = []
        for branch in s.get("anyOf", [s]) if isinstance(s, dict) else []:
            branch = self.resolve(branch)
            if not isinstance(branch, dict):
                continue
            if "properties" in branch:
                out.append((path, branch))
            elif branch.get("type") == "object" and isinstance(branch.get("additionalProperties"), dict):
                value = self.unwrap(branch["additionalProperties"])
                out += [(f"{path}.<name>", v) for _, v in self.children(value, "") if "properties" in v]
            elif branch.get("type") == "array" and isinstance(branch.get("items"), dict):
                out += [(f"{path}[]", v) for _, v in self.children(branch["items"], "") if "properties" in v]
        return out

    def walk(self, obj: dict, prefix: str, seen: frozenset, out: list[Row]) -> None:
        required = set(obj.get("required", []))
        for key, prop in obj.get("properties", {}).items():
            path = f"{prefix}.{key}" if prefix else key
            target = self.unwrap(prop)
            desc = prop.get("description") or (target.get("description", "") if isinstance(target, dict) else "")
            default = "" if "default" not in prop else f"`{json.dumps(prop['default'])}`"
            out.append(Row(path, self.type_text(prop), key in required, default, desc))
            for sub_path, sub in self.children(prop, path):
                if id(sub) not in seen:
                    self.walk(sub, sub_path, seen | {id(sub)}, out)


def rows(schema: dict) -> list[Row]:
    """Every key of ``schema`` (a JSON Schema of :mod:`jcalib.io.schema.export`), depth first in model order."""
    out: list[Row] = []
    _Walker(schema).walk(schema, "", frozenset({id(schema)}), out)
    return out


def _cell(text: str) -> str:
    """One table cell: one line, ``|`` escaped, and ``[`` ``]`` escaped (``K[0][1]`` is not a link)."""
    parts = " ".join(text.split()).replace("|", "\\|").split("`")
    return "`".join(p if i % 2 else p.replace("[", "\\[").replace("]", "\\]") for i, p in enumerate(parts))


def _target_fields() -> list[str]:
    from jcalib.io.schema.cell import TARGET_FIELDS

    lines = ["", "## Target fields by type", "", "| type | required | optional |", "|---|---|---|"]
    for kind, (req, opt) in TARGET_FIELDS.items():
        lines.append(f"| `{kind}` | {', '.join(f'`{f}`' for f in req) or '—'} | "
                     f"{', '.join(f'`{f}`' for f in opt) or '—'} |")
    return lines


def markdown(schema: dict, fmt: Any) -> str:
    """The reference page of one format (``fmt``: a :class:`jcalib.io.schema.export.Format`)."""
    closed = schema.get("additionalProperties") is False
    lines = [
        f"<!-- Generated by scripts/gen_schemas from {fmt.model.replace(':', '.')}; do not edit. -->",
        f"# {fmt.title} (`{fmt.key}`)",
        "",
        _cell(schema.get("description", "")),
        "",
        f"File: `{fmt.file}`{fmt.note}. JSON Schema (draft 2020-12): `jcalib schema {fmt.name}` prints it; the package holds it "
        f"as `jcalib/io/schema/json/{fmt.name}.schema.json`. {_CLOSED if closed else _OPEN}",
        "",
        "Paths: `<name>` stands for a mapping's keys, `[]` for a list's entries. A name (camera, target, tool, point, "
        "robot, station) has 1 to 64 characters, none of them a control character, `/`, `\\`, `[`, `]`, `\"`, `'` or "
        "a backquote, no spaces around it, and does not start with `.`.",
        "",
        "| key | type | required | default | description |",
        "|---|---|---|---|---|",
    ]
    for r in rows(schema):
        lines.append(f"| `{r.path}` | {_cell(r.type)} | {'yes' if r.required else ''} | {_cell(r.default)} | "
                     f"{_cell(r.description)} |")
    if NUMERIC_TEXT_PATTERN in json.dumps(schema):
        lines += ["", "Numbers may also be written as text (`1e-4`, which YAML 1.1 reads as a string)."]
    if fmt.name == "cell":
        lines += _target_fields()
    return "\n".join(lines) + "\n"
