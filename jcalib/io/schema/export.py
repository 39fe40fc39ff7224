"""The published JSON Schemas (draft 2020-12) of jcalib's file formats, generated from the pydantic models of
:mod:`jcalib.io.schema`, and their Markdown reference pages.

The models are the authority: a schema is what ``model_json_schema(mode="validation")`` says of the model,
with jcalib's custom types described by their ``json_schema_input_type`` (a name, a number written as text in
YAML, a station id that may be an integer). A file valid under its schema may still be refused when jcalib
reads it: units, rotations, names across sections and pixels inside the image are checked by the loader,
beyond what a JSON Schema can say.

``python -m jcalib.io.schema.export`` (``scripts/gen_schemas``) writes ``jcalib/io/schema/json/<name>.schema.json``
and ``docs/reference/formats/<name>.md``; ``--check`` writes nothing and exits 1 when a file differs from what
the models give now. ``jcalib schema NAME`` prints one schema.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic.json_schema import GenerateJsonSchema

from jcalib.errors import BadInputError

__all__ = ["FORMATS", "Format", "SCHEMA_DIR", "generated_files", "json_schema", "main", "schema_command", "schema_text"]

#: The folder of the bundled ``<name>.schema.json`` files (package data).
SCHEMA_DIR = Path(__file__).parent / "json"
#: The reference pages, relative to the repository root.
REFERENCE_DIR = Path("docs/reference/formats")
DRAFT = "https://json-schema.org/draft/2020-12/schema"


@dataclass(frozen=True)
class Format:
    """One file format.

    Attributes:
        name: the name ``jcalib schema`` takes and the files are named by (``cell``).
        model: ``module:Class`` of its pydantic model.
        key: the value of its ``schema`` key (``jcalib.cell/1``); a stations.jsonl line has none.
        title: what the file is, for people.
        file: its usual file name.
        note: said after the file name on the reference page.
    """

    name: str
    model: str
    key: str
    title: str
    file: str
    note: str = ""

    def model_class(self) -> Any:
        module, cls = self.model.split(":")
        return getattr(importlib.import_module(module), cls)

    @property
    def schema_id(self) -> str:
        version = self.key.rsplit("/", 1)[-1] if "/" in self.key else "1"
        return f"urn:jcalib:schema:{self.name}/{version}"


FORMATS: dict[str, Format] = {f.name: f for f in (
    Format("cell", "jcalib.io.schema.cell:CellDocument", "jcalib.cell/1", "Cell spec", "cell.yaml"),
    Format("observations", "jcalib.io.schema.observations:ObservationsDocument", "jcalib.observations/1",
           "Observations", "observations.json"),
    Format("result", "jcalib.io.schema.result:ResultDocument", "jcalib.result/1", "Calibration result", "result.json"),
    Format("session", "jcalib.io.schema.session:SessionMeta", "jcalib.session/1", "Capture session",
           "SESSION/session.json"),
    Format("station", "jcalib.io.schema.session:StationRecord", "jcalib.session/1", "Capture session station",
           "SESSION/stations.jsonl",
           " (one JSON object per line, appended as each station is finished)"),
    Format("plan", "jcalib.io.schema.plan:PlanDocument", "jcalib.plan/1", "Station plan", "plan.json"),
    Format("exclusions", "jcalib.io.schema.exclusions:ExclusionsDocument", "jcalib.exclusions/1",
           "Session exclusions", "SESSION/exclusions.json"),
)}

#: pydantic's names of numeric constraints it could not place on a type (behind a validator) -> JSON Schema's.
_CONSTRAINTS = {"gt": "exclusiveMinimum", "ge": "minimum", "lt": "exclusiveMaximum", "le": "maximum",
                "multiple_of": "multipleOf"}


class _Generator(GenerateJsonSchema):
    """pydantic's generator without per-field titles (the key is its title); a mapping's keys that must be names
    are stated by ``propertyNames`` (every key checked)."""

    def field_title_should_be_set(self, schema: Any) -> bool:
        return False

    def dict_schema(self, schema: Any) -> Any:
        out = super().dict_schema(schema)
        patterns = out.pop("patternProperties", None)
        if patterns is not None:  # pydantic's form of a key pattern (names): a key that misses it would be unchecked
            (pattern, value), = patterns.items()
            out["additionalProperties"] = value
            out["propertyNames"] = {**out.get("propertyNames", {}), "pattern": pattern}
        return out


def _fix_constraints(node: Any) -> Any:
    if isinstance(node, dict):
        return {(_CONSTRAINTS[k] if k in _CONSTRAINTS and isinstance(v, (int, float)) else k): _fix_constraints(v)
                for k, v in node.items()}
    if isinstance(node, list):
        return [_fix_constraints(v) for v in node]
    return node


def json_schema(name: str) -> dict[str, Any]:
    """The JSON Schema of the format ``name`` (a key of :data:`FORMATS`).

    Raises:
        BadInputError: an unknown name (the message lists the names).
    """
    fmt = FORMATS.get(name)
    if fmt is None:
        from jcalib.io.schema.base import did_you_mean

        raise BadInputError(f"schema: unknown format {name!r} (the formats: {', '.join(FORMATS)})"
                            f"{did_you_mean(name, FORMATS)}")
    model = fmt.model_class()
    body = _fix_constraints(model.model_json_schema(mode="validation", schema_generator=_Generator))
    doc = " ".join((model.__doc__ or "").split())
    key = f" ({fmt.key})" if fmt.name != "station" else f" (a line of stations.jsonl, {fmt.key})"
    head = {
        "$schema": DRAFT,
        "$id": fmt.schema_id,
        "title": f"jcalib {fmt.title.lower()}{key}",
        "description": f"{doc} Generated from {fmt.model.replace(':', '.')}; jcalib checks more when it reads "
                       "the file (units, rotations, names across sections), beyond what a JSON Schema can say.",
    }
    body.pop("title", None)
    body.pop("description", None)
    return {**head, **body}


def schema_text(name: str) -> str:
    """:func:`json_schema` as the text of its ``.schema.json`` file."""
    return json.dumps(json_schema(name), indent=2, ensure_ascii=False) + "\n"


def schema_command(name: str, out: Path | None = None) -> None:
    """``jcalib schema NAME [-o FILE]``: the schema on stdout, or written atomically to ``out``.

    Raises:
        BadInputError: an unknown name, or an ``out`` that cannot be written.
    """
    text = schema_text(name)
    if out is None:
        sys.stdout.write(text)
        return
    from jcalib.io.atomic import write_text_atomic
    from jcalib.io.outputs import check_outputs

    check_outputs({"-o": out})
    write_text_atomic(out, text)


def generated_files() -> dict[Path, str]:
    """Every generated file (path relative to the repository root) -> its text as the models give it now."""
    from jcalib.io.schema.reference import markdown

    package = Path("jcalib/io/schema/json")
    out: dict[Path, str] = {}
    for name, fmt in FORMATS.items():
        out[package / f"{name}.schema.json"] = schema_text(name)
        out[REFERENCE_DIR / f"{name}.md"] = markdown(json_schema(name), fmt)
    return out


def main(argv: list[str] | None = None) -> int:
    """Write (or ``--check``) the schemas and reference pages under ``--root`` (the repository)."""
    parser = argparse.ArgumentParser(prog="python -m jcalib.io.schema.export", description=__doc__.split("\n")[0])
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[3],
                        help="the repository root (default: the one this module is in)")
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 when a file is out of date")
    args = parser.parse_args(argv)
    from jcalib.io.atomic import write_text_atomic

    stale = []
    for rel, text in generated_files().items():
        path = args.root / rel
        if path.is_file() and path.read_text(encoding="utf-8") == text:
            continue
        stale.append(rel)
        if not args.check:
            write_text_atomic(path, text)
    verb = "out of date" if args.check else "written"
    print("\n".join(f"{verb}: {p}" for p in stale) or "all generated files are up to date")
    return 1 if args.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
