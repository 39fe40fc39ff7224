"""The published JSON Schemas and reference pages of the file formats (jcalib.io.schema.export): the committed
files are what the models generate now, every bundled example file validates under its schema with an
independent validator (jsonschema) as it does under the models, and ``jcalib schema`` prints them."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import jsonschema
import pytest
import yaml

from jcalib.io.schema.export import FORMATS, SCHEMA_DIR, generated_files, json_schema, schema_text
from jcalib.io.schema.reference import rows

ROOT = Path(__file__).resolve().parents[2]
#: The recorded calibrations (their cell spec and observations as the golden tests give them).
GOLDEN_CASES = [p for p in sorted((ROOT / "tests/golden/cases").glob("*.json")) if "cell" in json.loads(p.read_text())]
PLANS = sorted((ROOT / "tests/golden/planning").glob("plan_*.json"))
#: The names another worktree's documentation site links to.
REFERENCE_PAGES = ("cell", "observations", "result", "session", "station", "plan")


@functools.cache
def validator(name: str) -> jsonschema.Draft202012Validator:
    return jsonschema.Draft202012Validator(json.loads((SCHEMA_DIR / f"{name}.schema.json").read_text()))


def assert_valid(name: str, doc: dict, where: str) -> None:
    errors = sorted(validator(name).iter_errors(doc), key=lambda e: list(e.absolute_path))
    assert not errors, f"{where}: {'/'.join(map(str, errors[0].absolute_path))}: {errors[0].message[:300]}"


def test_committed_files_are_what_the_models_generate():
    stale = [str(rel) for rel, text in generated_files().items()
             if not (ROOT / rel).is_file() or (ROOT / rel).read_text(encoding="utf-8") != text]
    assert not stale, f"out of date (run scripts/gen_schemas): {', '.join(stale)}"
    assert {p.name for p in SCHEMA_DIR.glob("*.schema.json")} == {f"{n}.schema.json" for n in FORMATS}


@pytest.mark.parametrize("name", list(FORMATS))
def test_each_schema_is_draft_2020_12_with_id_title_and_descriptions(name):
    schema = json_schema(name)
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["$id"] and schema["title"] and schema["description"]
    for key, prop in schema["properties"].items():
        assert prop.get("description"), f"{name}: top-level key {key!r} has no description"
    text = json.dumps(schema)
    assert '"gt"' not in text and '"ge"' not in text and "patternProperties" not in text  # JSON Schema's words only


def test_reference_pages_list_every_top_level_key():
    for name in FORMATS:
        page = (ROOT / "docs/reference/formats" / f"{name}.md").read_text(encoding="utf-8")
        for key in json_schema(name)["properties"]:
            assert f"| `{key}` |" in page, f"{name}.md lacks {key}"
    assert all((ROOT / "docs/reference/formats" / f"{n}.md").is_file() for n in REFERENCE_PAGES)
    paths = [r.path for r in rows(json_schema("observations"))]
    assert "stations[].detections[].pixels" in paths and "cameras.<name>.image_size" in paths


def _demo_cell() -> dict:
    from jcalib.workflow.simulate import DEMO_CELL

    return yaml.safe_load(DEMO_CELL)


def test_bundled_cell_specs_validate():
    from jcalib.io.schema import validate_cell_document

    demo = ROOT / "benchmarks/data/demo_cell/cell.yaml"
    docs = {"DEMO_CELL": _demo_cell(), "benchmarks/data/demo_cell/cell.yaml": yaml.safe_load(demo.read_text())}
    assert len(GOLDEN_CASES) >= 10
    docs.update({f"{p.name}:cell": json.loads(p.read_text())["cell"] for p in GOLDEN_CASES})
    docs["text numbers"] = {"schema": "jcalib.cell/1", "robot": {"pose_noise": {"translation_m": "1e-4",
                                                                                "rotation_deg": ["1e-2", 0.01, 1]}}}
    for where, doc in docs.items():
        validate_cell_document(doc, where)  # valid under the models: the schema must agree
        assert_valid("cell", doc, where)


def test_bundled_observations_validate():
    from jcalib.io.schema import validate_observations_document

    docs = {"benchmarks/data/demo_cell/observations.json":
            json.loads((ROOT / "benchmarks/data/demo_cell/observations.json").read_text())}
    docs.update({f"{p.name}:observations": json.loads(p.read_text())["observations"] for p in GOLDEN_CASES})
    docs["integer station id"] = {"schema": "jcalib.observations/1", "stations": [{"id": 7}]}
    for where, doc in docs.items():
        validate_observations_document(doc, where)
        assert_valid("observations", doc, where)


def test_bundled_results_and_plans_validate():
    from jcalib.io.schema import validate_plan_document, validate_result_document

    results = {"tests/io/golden/result.json": json.loads((ROOT / "tests/io/golden/result.json").read_text()),
               "taskspace.json:input": json.loads((ROOT / "tests/golden/planning/taskspace.json").read_text())["input"]}
    for where, doc in results.items():
        validate_result_document(doc, where)
        assert_valid("result", doc, where)
    assert PLANS
    for p in PLANS:
        doc = json.loads(p.read_text())
        doc = doc.get("plan", doc)  # plan_demo.json keeps the plan beside its counts
        validate_plan_document(doc, p.name)
        assert_valid("plan", doc, p.name)


def test_an_imported_session_validates(real_data, tmp_path):
    from jcalib.io.importers import import_session
    from jcalib.io.schema import validate_session_meta, validate_station_record

    import_session("opencv-pairs", real_data / "handeye_camodocal_example", tmp_path / "s", mount="base")
    meta = json.loads((tmp_path / "s/session.json").read_text())
    validate_session_meta(meta, "session.json")
    assert_valid("session", meta, "session.json")
    assert_valid("cell", meta["cell"], "session.json: cell")
    lines = (tmp_path / "s/stations.jsonl").read_text().splitlines()
    assert len(lines) == 42
    for i, line in enumerate(lines):
        validate_station_record(json.loads(line), f"stations.jsonl line {i + 1}")
        assert_valid("station", json.loads(line), f"stations.jsonl line {i + 1}")


def test_exclusions_schema_agrees_with_its_reader():
    from jcalib.errors import BadInputError
    from jcalib.io.exclusions import Exclusions, parse_exclusions

    good = Exclusions().with_station("s003", True).with_view("s007", "cam_hand", True).to_json()
    good["excluded"][0]["note"] = "blurred"
    parse_exclusions(good, "good")
    assert_valid("exclusions", good, "good")
    for bad in ({"schema": "jcalib.exclusions/1", "excluded": [{"camera": "cam0"}]},
                {"schema": "jcalib.exclusions/1", "excluded": [{"station": "s0", "why": "x"}]},
                {"schema": "jcalib.exclusions/1", "excluded": [{"station": ""}]},
                {"schema": "jcalib.exclusions/1", "excluded": [{"station": "s0", "camera": None}]},
                {"schema": "jcalib.exclusions/1", "extra": 1}):
        with pytest.raises(BadInputError):
            parse_exclusions(bad, "bad")
        assert not validator("exclusions").is_valid(bad), bad


@pytest.mark.parametrize("name, doc", [
    ("cell", {"schema": "jcalib.cell/1", "cameras": {"cam0": {"model": "opencv5", "moutn": "flange"}}}),
    ("cell", {"schema": "jcalib.cell/1", "cameras": {"cam/0": {"model": "opencv5"}}}),
    ("cell", {"schema": "jcalib.cell/1", "cameras": {".cam": {"model": "opencv5"}}}),
    ("cell", {"schema": "jcalib.cell/1", "targets": {"b": {"type": "checkerboard", "cols": 9, "rows": 6,
                                                           "square": -0.02}}}),
    ("cell", {"schema": "jcalib.cell/1", "robot": {"pose_noise": {"translation_m": "a lot", "rotation_deg": 1}}}),
    ("cell", {"schema": "jcalib.cell/2"}),
    ("observations", {"schema": "jcalib.observations/1", "cameras": {"c": {"image_size": [640]}}}),
    ("observations", {"schema": "jcalib.observations/1", "stations": [{"id": "s0", "T_base_flange": [[1, 0, 0]]}]}),
    ("result", {"schema": "jcalib.result/1", "cameras": {"c": {"model": "opencv5"}}}),
    ("station", {"id": "s0", "images": {"cam0": "../../etc/passwd"}}),
    ("station", {"id": "s0", "images": {"cam0": "/etc/passwd"}}),
    ("plan", {"schema": "jcalib.plan/1", "stations": []}),
])
def test_schema_and_model_refuse_the_same_mistakes(name, doc):
    from jcalib.io.schema import (
        SchemaError,
        validate_cell_document,
        validate_observations_document,
        validate_plan_document,
        validate_result_document,
        validate_station_record,
    )

    check = {"cell": validate_cell_document, "observations": validate_observations_document,
             "result": validate_result_document, "station": validate_station_record, "plan": validate_plan_document}
    with pytest.raises(SchemaError):
        check[name](doc, "doc")
    assert not validator(name).is_valid(doc)


def test_schema_command_prints_writes_and_refuses(run_cli, tmp_path):
    code, text = run_cli("schema", "cell")
    assert code == 0 and text == schema_text("cell")
    out = tmp_path / "station.schema.json"
    code, text = run_cli("schema", "station", "-o", out)
    assert code == 0 and out.read_text() == (SCHEMA_DIR / "station.schema.json").read_text()
    code, text = run_cli("schema", "cel")
    assert code == 2 and "did you mean 'cell'" in text and all(n in text for n in FORMATS) and "Traceback" not in text
    code, text = run_cli("schema", "plan", "-o", tmp_path)
    assert code == 2 and "directory" in text
