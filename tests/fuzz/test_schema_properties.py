"""Property tests over the file schemas: any mutation of a valid document (a value replaced by any
JSON value, a key deleted or added, a mapping turned into a list, a number scaled) is either
accepted or refused with a :class:`BadInputError` of bounded length, never another exception; what
is accepted can be used downstream (cross-checks, exports) without an exception either.
"""

from __future__ import annotations

import copy
import json
import os

import numpy as np
import pytest
from fuzz_files import CELL, observations, pixels, plan, points, result, session_meta, station_record
from hypothesis import given, settings
from hypothesis import strategies as st

from jcalib.errors import BadInputError, InputWarning
from jcalib.io.cell import cell_to_dict, parse_cell
from jcalib.io.export import export_text
from jcalib.io.export._common import comment_text
from jcalib.io.observations import parse_observations
from jcalib.io.plan import plan_from_json
from jcalib.io.result import ResultFile
from jcalib.io.schema import (
    check_cell_observations,
    check_name,
    validate_points_document,
    validate_result_document,
    validate_session_meta,
    validate_station_record,
)

#: Examples per property; ``JCALIB_FUZZ_EXAMPLES=5000`` runs a longer, randomised fuzz (CI: 150, fixed).
pytestmark = pytest.mark.filterwarnings("ignore::jcalib.errors.InputWarning")  # mutations warn, by design

EXAMPLES = int(os.environ.get("JCALIB_FUZZ_EXAMPLES", "150"))
RANDOM = "JCALIB_FUZZ_EXAMPLES" in os.environ

_text = st.text(st.characters(codec="utf-8"), max_size=12) | st.sampled_from(
    ["", " ", "[/x]", "a\nb", "\x00", "cam_hand", "board", "torch", "divot", "T_base_board", "opencv5", "1e-4",
     "nan", "../x", "\u2028", "flange", "base"])
_number = (st.integers(-(2**70), 2**70) | st.floats(allow_nan=True, allow_infinity=True)
           | st.sampled_from([0, 1, -1, 0.5, 1e300, -1e-300, 640, 480, 1000.0]))
json_values = st.recursive(
    st.none() | st.booleans() | _number | _text,
    lambda children: st.lists(children, max_size=4) | st.dictionaries(_text, children, max_size=4),
    max_leaves=12,
)


def _paths(doc, prefix=()):
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, prefix + (i,))


def _get(doc, path):
    for p in path:
        doc = doc[p]
    return doc


@st.composite
def mutated(draw, base):
    doc = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(list(_paths(doc))))
        op = draw(st.sampled_from(["replace", "delete", "add_key", "to_list", "scale", "to_text"]))
        parent, key = (_get(doc, path[:-1]), path[-1]) if path else (None, None)
        node = _get(doc, path)
        if op == "replace" or parent is None and op == "delete":
            new = draw(json_values)
            if parent is None:
                doc = new if not isinstance(new, dict) or draw(st.booleans()) else {**(doc if isinstance(doc, dict)
                                                                                       else {}), **new}
            else:
                parent[key] = new
        elif op == "delete":
            del parent[key]
        elif op == "add_key" and isinstance(node, dict):
            node[draw(_text)] = draw(json_values)
        elif op == "to_list" and isinstance(node, dict) and parent is not None:
            parent[key] = list(node.values())
        elif op == "scale" and isinstance(node, (int, float)) and not isinstance(node, bool) and parent is not None:
            parent[key] = node * draw(st.sampled_from([1000, 1e-3, -1, 1.5, 1e300]))
        elif op == "to_text" and parent is not None:
            parent[key] = json.dumps(node, allow_nan=True)
        if not isinstance(doc, (dict, list)):
            break
    return doc


def _refused_or_accepted(fn, *args):
    """``fn(*args)``: returns its value, or None when it raised a BadInputError of bounded length."""
    try:
        return fn(*args)
    except BadInputError as e:
        assert len(str(e)) < 4000, f"message of {len(str(e))} characters"
        return None


OBS = observations(3)


@settings(max_examples=EXAMPLES, derandomize=not RANDOM)
@given(mutated(CELL), mutated(OBS))
def test_mutated_cell_and_observations_are_accepted_or_refused(cell_doc, obs_doc):
    import warnings

    cell = _refused_or_accepted(parse_cell, cell_doc, "cell.yaml")
    obs = _refused_or_accepted(parse_observations, obs_doc, "obs.json")
    if cell is not None:
        again = parse_cell(cell_to_dict(cell))  # what is accepted round-trips
        assert cell_to_dict(again) == cell_to_dict(cell)
    if cell is not None and obs is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InputWarning)
            _refused_or_accepted(check_cell_observations, cell, obs)


RESULT = result()


@settings(max_examples=EXAMPLES, derandomize=not RANDOM)
@given(mutated(RESULT))
def test_mutated_results_are_accepted_or_refused_and_export_safely(doc):
    def load(d):
        if isinstance(d, dict):
            validate_result_document(d, "result.json")
        return ResultFile.from_dict(d, "result.json")

    res = _refused_or_accepted(load, doc)
    if res is None:
        return
    for fmt in ("opencv", "ros", "rapid", "krl"):
        for cam in list(res.cameras)[:1] if fmt in ("opencv", "ros") else [None]:
            opts = {"cameras": cam} if fmt == "opencv" else {"camera": cam} if fmt == "ros" else {}
            text = _refused_or_accepted(lambda: export_text(res, fmt, **opts))
            if text is not None:
                assert text.count("\n") == len(text.splitlines())


@settings(max_examples=EXAMPLES, derandomize=not RANDOM)
@given(mutated(plan()))
def test_mutated_plans_are_accepted_or_refused(doc):
    _refused_or_accepted(plan_from_json, doc, "plan.json")


@settings(max_examples=EXAMPLES, derandomize=not RANDOM)
@given(mutated(session_meta()), mutated(station_record()))
def test_mutated_session_files_are_accepted_or_refused(meta, record):
    _refused_or_accepted(validate_session_meta, meta, "session.json")
    rec = _refused_or_accepted(validate_station_record, record, "stations.jsonl line 1")
    if rec is not None:
        for path in (rec.images or {}).values():
            assert not path.startswith("/") and ".." not in path.split("/")


@settings(max_examples=EXAMPLES, derandomize=not RANDOM)
@given(mutated(points()))
def test_mutated_point_files_are_accepted_or_refused(doc):
    from jcalib.pipeline import points as pipeline_points

    _refused_or_accepted(validate_points_document, doc, "points.json")
    _refused_or_accepted(pipeline_points._load_points, doc, "points.json")


@settings(max_examples=EXAMPLES, derandomize=not RANDOM)
@given(mutated(pixels()))
def test_mutated_pixel_files_are_accepted_or_refused(doc):
    from jcalib.pipeline import points as pipeline_points

    _refused_or_accepted(pipeline_points._parse_pixels, doc, "pixels.json")


@settings(max_examples=2 * EXAMPLES, derandomize=not RANDOM)
@given(st.text(st.characters(codec="utf-8"), max_size=20))
def test_a_valid_name_is_safe_everywhere_it_goes(name):
    from rich.console import Console
    from rich.markup import render

    try:
        check_name(name)
    except ValueError as e:
        assert len(str(e)) < 400
        return
    assert name == name.strip() and "/" not in name and "[" not in name
    assert comment_text(name) == name  # no control or line-break character
    render(f"[bold]{name}[/]")  # rich markup around a name never fails
    Console(file=open("/dev/null", "w")).print(name)  # noqa: SIM115


@settings(max_examples=2 * EXAMPLES, derandomize=not RANDOM)
@given(st.text(st.characters(codec="utf-8"), max_size=40), st.booleans())
def test_comment_text_never_starts_a_line(text, ascii_only):
    out = comment_text(text, ascii_only)
    assert len(out.splitlines()) <= 1 and "\n" not in out and "\r" not in out
    assert all(ord(c) >= 32 and ord(c) != 127 for c in out)
    if ascii_only:
        assert out.isascii()


@pytest.mark.parametrize("scale", [1000.0, 100.0])
def test_flange_translations_scaled_as_millimetres_are_refused(scale):
    doc = copy.deepcopy(OBS)
    for st_ in doc["stations"]:
        T = np.asarray(st_["T_base_flange"])
        T[:3, 3] *= scale
        st_["T_base_flange"] = T.tolist()
    with pytest.raises(BadInputError, match="millimetres"):
        parse_observations(doc, "obs.json")


SCENARIO = __import__("yaml").safe_load(__import__("fuzz_files").SCENARIO_YAML)


@settings(max_examples=EXAMPLES, derandomize=not RANDOM)
@given(mutated(SCENARIO))
def test_mutated_study_scenarios_are_accepted_or_refused(doc):
    from jcalib.study.scenario import load_scenario

    _refused_or_accepted(load_scenario, doc)
