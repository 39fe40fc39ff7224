"""Mutation fuzzing of the newer surfaces (issue 32): kinematic tables in cell specs, plan files and the
``plan`` command's options, ``convert`` and ``compare`` (result files and options), ``cross-validate``'s
options. Shared by ``test_surfaces_fuzz.py`` (fixed seeds, bounded time) and
``benchmarks/bench_surfaces_fuzz.py`` (the table of inputs tried and outcomes).

Cases run the CLI in-process (:func:`fuzz_helpers.run_cli`: no traceback, no "internal error") and record
``(surface, what was mutated, exit status)``. The contract: exit status in {0, 2, 3}, no input file changed,
no output written by a refused command. Every mutant goes through the cheap parser first; the first
``cli_runs`` that it refuses go through the CLI too (which must refuse them, exit 2, before any solve; one
CLI call costs ~0.3 s of typer alone), the rest are tallied as "parser only"; and only ``real_runs``
accepted ones run for real: the solves stay out of the loop.
"""

from __future__ import annotations

import copy
import functools
import json
import math
import random
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from fuzz_files import result as base_result
from fuzz_helpers import digest, run_cli

from jcalib.errors import BadInputError

#: Exit statuses a command may answer hostile input with: success, bad input, not observable.
ALLOWED = (0, 2, 3)

#: Values a mutation puts in place of a number, a string or a subtree.
HOSTILE = [None, True, -1, 0, 1e308, -1e308, 1e-320, float("nan"), float("inf"), "", "x", "1e3", [], {}, [1, 2],
           {"a": 1}, [[1, 2], [3, 4]], 2**70, 3.5, "nan", -0.0]

#: Factors a "scale" mutation multiplies a number by (unit errors: mm as m, rad as deg, sign flips).
SCALES = [1000.0, 1e-3, -1.0, 180.0 / math.pi, math.pi / 180.0, 1e308, 0.0]


@dataclass
class Tally:
    """What a surface was given and how the CLI answered: (mutation kind -> Counter of exit status)."""

    rows: dict[str, dict[str, Counter]] = field(default_factory=dict)

    def add(self, surface: str, kind: str, code: int) -> None:
        self.rows.setdefault(surface, {}).setdefault(kind, Counter())[code] += 1

    def markdown(self) -> str:
        lines = ["| surface | input | tried | exit 0 | exit 1 (differ) | exit 2 | exit 3 | other |",
                 "|---|---|---:|---:|---:|---:|---:|---:|"]
        for surface, kinds in self.rows.items():
            for kind, c in sorted(kinds.items()):
                other = sum(v for k, v in c.items() if k not in (*ALLOWED, 1))
                lines.append(f"| {surface} | {kind} | {sum(c.values())} | {c[0]} | {c[1]} | {c[2]} | {c[3]} | {other} |")
        return "\n".join(lines)


# ---------------------------------------------------------------------------------------------- mutation


def _paths(doc, prefix=()):
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, (*prefix, i))


def _get(doc, path):
    for p in path:
        doc = doc[p]
    return doc


def mutate(doc, rng: random.Random, under: tuple = ()) -> tuple[object, str]:
    """One mutation of ``doc`` (a copy) at a node below ``under``: (new document, kind of mutation)."""
    doc = copy.deepcopy(doc)
    paths = [p for p in _paths(doc) if p[: len(under)] == under and len(p) > len(under)] or [under]
    shallow = [p for p in paths if len(p) <= len(under) + 2]  # half the time a key near the top (a whole entry)
    path = rng.choice(shallow if shallow and rng.random() < 0.5 else paths)
    node = _get(doc, path)
    parent, key = (_get(doc, path[:-1]), path[-1]) if path else (None, None)
    numeric = isinstance(node, (int, float)) and not isinstance(node, bool)
    ops = ["replace", "delete", "to_text"] + (["scale"] * 3 if numeric else []) + (["add_key"] if isinstance(node, dict)
                                                                                    else [])
    op = rng.choice(ops) if parent is not None else "add_key"
    if op == "replace":
        parent[key] = copy.deepcopy(rng.choice(HOSTILE))
    elif op == "delete":
        del parent[key]
    elif op == "to_text":
        parent[key] = json.dumps(node, allow_nan=True)
    elif op == "scale":
        parent[key] = node * rng.choice(SCALES)
    elif op == "add_key" and isinstance(node, dict):
        node[rng.choice(["zz", "extra", "a_m", "convention", "stations"])] = copy.deepcopy(rng.choice(HOSTILE))
    return doc, op


# ---------------------------------------------------------------------------------------------- documents


def kinematic_cell(convention: str) -> dict:
    """A cell whose robot's kinematics is the KUKA preset written as a ``convention`` table (dh, mdh, poe)."""
    return copy.deepcopy(_kinematic_cell(convention))


@functools.cache
def _kinematic_cell(convention: str) -> dict:
    from jcalib.geometry import kinematic_models
    from jcalib.geometry.kinematic_tables import to_spec

    model = kinematic_models.convert(kinematic_models.PRESETS["kuka_kr10_r1100_sixx"](), convention)
    return {"schema": "jcalib.cell/1",
            "cameras": {"cam0": {"model": "opencv5", "mount": "flange"}},
            "targets": {"board": {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.03, "mount": "base"}},
            "robot": {"kinematics": to_spec(model, model.nominal), "calibrate_kinematics": ["joint_offsets"]}}


def estimated_result(scale: float = 1.0) -> dict:
    """The fuzz result with ``cam_hand`` estimated: a covariance on its intrinsics (compare needs one);
    ``scale`` != 1 moves its focal length a little (a second calibration of the same camera)."""
    doc = base_result()
    cam = doc["cameras"]["cam_hand"]
    cam["K"][0][0] *= scale
    cam["covariance"] = np.diag([0.25, 0.25, 0.3, 0.3, 1e-6, 1e-6, 1e-8, 1e-8]).tolist()
    cam["std"] = {"fx": 0.5, "fy": 0.5, "cx": 0.55, "cy": 0.55}
    return doc


def goal_result() -> dict:
    """A result holding what the golden optimal plan's goals name (``cam0``, ``T_flange_cam0``)."""
    doc = estimated_result()
    doc["cameras"] = {"cam0": doc["cameras"]["cam_hand"]}
    doc["transforms"] = {"T_flange_cam0": doc["transforms"]["T_flange_cam_hand"]}
    doc["points"] = {}
    return doc


def optimal_plan(golden: Path) -> dict:
    """The golden goal-driven plan (``plan --kind optimal``), whose goals ``report --plan`` reads."""
    return json.loads(golden.read_text())


# ---------------------------------------------------------------------------------------------- running


def run_checked(args: list, inputs: list[Path], out: Path | None, verdict: bool = False) -> int:
    """``jcalib ARGS``: exit status in :data:`ALLOWED` (and 1 where ``verdict``: compare's "differ", said
    so), the ``inputs`` unchanged, no ``out`` after a refusal."""
    before = {p: digest(p) for p in inputs if Path(p).exists()}
    existed = out is not None and Path(out).exists()
    code, text = run_cli(*args)
    if verdict and code == 1:
        assert ": differ:" in text, text[-2000:]
        return code
    assert code in ALLOWED, (code, args, text[-2000:])
    for p, d in before.items():
        assert digest(p) == d, f"{p} changed by {args}"
    if code not in (0, 1) and out is not None and not existed:
        assert not Path(out).exists(), f"{out} written by a refused {args}"
    if code == 2:
        assert "jcalib error:" in text or "Invalid value" in text or "Error" in text, text[-2000:]
    return code


def write(path: Path, doc, fmt: str = "json") -> Path:
    if fmt == "yaml":
        path.write_text(yaml.safe_dump(doc, allow_unicode=True) if isinstance(doc, (dict, list)) else str(doc))
    else:
        path.write_text(json.dumps(doc, allow_nan=True))
    return path


def parses(fn, *args) -> bool:
    """Whether the cheap parser accepts the input (False: it refused with a BadInputError)."""
    try:
        fn(*args)
    except BadInputError:
        return False
    return True


# ---------------------------------------------------------------------------------------------- surfaces


def fuzz_kinematic_tables(folder: Path, tally: Tally, num: int, seed: int, cli_runs: int = 1000) -> None:
    """Mutated kinematics tables (dh, mdh, poe) in a cell spec: ``jcalib plan --kind kinematics`` must refuse
    the ones the cell parser refuses (exit 2, before any planning); accepted ones must give a finite forward
    kinematics and round-trip through their table."""
    from jcalib.geometry import kinematic_models
    from jcalib.geometry.kinematic_tables import from_spec, to_spec
    from jcalib.io.cell import parse_cell

    rng = random.Random(seed)
    for i in range(num):
        convention = ("dh", "mdh", "poe")[i % 3]
        base = kinematic_cell(convention)
        doc, op = mutate(base, rng, ("robot", "kinematics"))
        try:
            cell = parse_cell(doc, "cell.yaml")
        except BadInputError:
            cell = None
        if cell is None and cli_runs <= 0:
            tally.add("kinematic table", f"{op} (refused by the parser; parser only)", 2)
            continue
        if cell is None:
            cli_runs -= 1
            path = write(folder / f"kcell{i}.yaml", doc, "yaml")
            out = folder / f"kplan{i}.json"
            code = run_checked(["plan", "--cell", path, "--kind", "kinematics", "-o", out], [path], out)
            assert code == 2, (op, doc["robot"] if isinstance(doc, dict) else doc)
            tally.add("kinematic table", f"{op} (refused by the parser)", code)
            continue
        model = cell.robot.kinematics
        q = np.zeros((1, model.num_joints))
        T = np.asarray(kinematic_models.forward(model, model.nominal, q))
        assert np.all(np.isfinite(T)), (op, doc["robot"])
        again = from_spec(to_spec(model, model.nominal), "robot")
        assert np.allclose(np.asarray(kinematic_models.forward(again, again.nominal, q)), T, atol=1e-9)
        tally.add("kinematic table", f"{op} (accepted: finite FK, round trip)", 0)


def run_mutants(label: str, tally: Tally, mutants, accepts, run, real_runs: int, cli_runs: int) -> None:
    """Each ``(i, doc, op)`` of ``mutants`` through the CLI (``run(i, doc) -> exit status``): a document the
    parser refuses (``accepts(doc)`` false) must exit 2; only ``real_runs`` accepted ones and ``cli_runs``
    refused ones run the CLI, the other refused ones are tallied as "parser only"."""
    ran = 0
    for i, doc, op in mutants:
        ok = accepts(doc)
        if ok and ran >= real_runs:
            continue
        if not ok and cli_runs <= 0:
            tally.add(label, f"{op} (refused by the parser; parser only)", 2)
            continue
        cli_runs -= not ok
        code = run(i, doc)
        if not ok:
            assert code == 2, (op, doc)
        ran += ok
        tally.add(label, f"{op} ({'accepted' if ok else 'refused by the parser'})", code)


def fuzz_plan_files(folder: Path, tally: Tally, num: int, seed: int, golden: Path, result: Path,
                    real_runs: int = 2, cli_runs: int = 1000) -> None:
    """Mutated plan files: ``jcalib report RESULT --plan PLAN`` refuses what :func:`plan_goals` /
    :func:`plan_from_json` refuse; ``real_runs`` accepted ones write the report."""
    from jcalib.io.plan import plan_from_json, plan_goals

    rng = random.Random(seed)
    base = optimal_plan(golden)

    def run(i, doc):
        path, out = write(folder / f"plan{i}.json", doc), folder / f"report{i}.html"
        return run_checked(["report", result, "-o", out, "--plan", path], [path, result], out)

    mutants = ((i, *mutate(base, rng, ("planner",) if i % 2 else ())) for i in range(num))
    run_mutants("plan file (report --plan)", tally, mutants,
                lambda doc: parses(plan_goals, doc) and parses(plan_from_json, doc, "plan.json"), run, real_runs,
                cli_runs)


#: ``jcalib plan`` options and hostile values; every one must be refused at parse time (exit 2).
PLAN_OPTION_VALUES = {
    "--seed": ["-1", "-2147483648", "4294967296", "1.5", "x"],
    "--stations": ["0", "-3", "x", "1e3"],
    "--candidates": ["0", "-1", "1000000000"],
    "--max-stations": ["0", "-1", "100000"],
    "--sigma-px": ["0", "-0.2", "nan", "inf", "1e308"],
    "--amplitude-deg": ["0", "-5", "nan", "inf", "1e9"],
    "--image-size": ["0x0", "x", "-5x5", "100000x100000"],
    "--kind": ["", "optimal ", "nope"],
}


def fuzz_plan_options(folder: Path, tally: Tally, cell: Path, every_kind: bool = True) -> None:
    """Every hostile value of every ``jcalib plan`` option: exit 2 naming it, nothing written. With
    ``every_kind`` each value is tried with every kind (handeye, kinematics, optimal), else with one of them
    in turn."""
    kinds = ("handeye", "kinematics", "optimal")
    pairs = [(option, value) for option, values in PLAN_OPTION_VALUES.items() for value in values]
    for j, (option, value) in enumerate(pairs):
        for kind in kinds if every_kind and option != "--kind" else (kinds[j % 3],):
            out = folder / "plan_out.json"
            args = ["plan", "--cell", cell, "--kind", kind, "-o", out, option, value]
            if option == "--kind":
                args = ["plan", "--cell", cell, "-o", out, "--kind", value]
            code, text = run_cli(*args)
            assert code == 2, (args, text[-1500:])
            assert option in text, (args, text[-1500:])
            assert not out.exists()
            tally.add("plan options", f"{option} {value!r}", code)


#: ``cross-validate`` / ``compare`` options and hostile values (refused at parse time).
CROSSVAL_OPTION_VALUES = {
    "--seed": ["-1", "4294967296"],
    "--grid": ["0x0", "1x1", "100000x100000", "24x", "x18", "-3x4"],
    "--distance": ["0", "-1", "nan"],
    "--sigma-px": ["0", "-1", "nan", "inf"],
    "--outlier-threshold": ["-1", "nan", "inf"],
}


def fuzz_crossval_options(tally: Tally, cell: Path, observations: Path) -> None:
    for option, values in CROSSVAL_OPTION_VALUES.items():
        for value in values:
            args = ["cross-validate", cell, observations, option, value, "--split", "random"]
            code, text = run_cli(*args)
            assert code == 2 and option in text, (args, text[-1500:])
            tally.add("cross-validate options", f"{option} {value!r}", code)


def fuzz_convert(folder: Path, tally: Tally, num: int, seed: int, real_runs: int = 2, cli_runs: int = 1000) -> None:
    """Mutated result files and options for ``jcalib convert``: refused ones exit 2 before the fit."""
    from jcalib.io.result import ResultFile

    rng = random.Random(seed)
    base = estimated_result()

    def run(i, doc):
        path, out = write(folder / f"conv_in{i}.json", doc), folder / f"conv_out{i}.json"
        return run_checked(["convert", path, "--to", "opencv5", "-o", out, "--camera", "cam_hand"], [path], out)

    mutants = ((i, *mutate(base, rng, ("cameras", "cam_hand") if i % 2 else ())) for i in range(num))
    run_mutants("convert (result file)", tally, mutants, lambda doc: parses(ResultFile.from_dict, doc, "result.json"),
                run, real_runs, cli_runs)
    good = write(folder / "conv_good.json", base)
    out = folder / "conv_opt.json"
    for option, value in [("--to", "opencv99"), ("--to", ""), ("--region", "nan,0,10,10"), ("--region", "1,2,3"),
                          ("--region", "0,0,1e308,1e308"), ("--region", "50,50,10,10"), ("--fix", "zz"),
                          ("--fix", ",,,k9"), ("--camera", "nope"), ("--camera", "")]:
        opts = {"--to": "opencv5", "--camera": "cam_hand", option: value}
        code = run_checked(["convert", good, "-o", out, *[x for kv in opts.items() for x in kv]], [good], out)
        assert code == 2, (option, value)
        tally.add("convert options", f"{option} {value!r}", code)


def fuzz_compare(folder: Path, tally: Tally, num: int, seed: int, real_runs: int = 2, cli_runs: int = 1000) -> None:
    """Mutated result files for ``jcalib compare A B`` (either side), unrelated pairs and hostile options."""
    from jcalib.io.result import ResultFile

    rng = random.Random(seed)
    a_doc, b_doc = estimated_result(), estimated_result(1.0005)
    a = write(folder / "cmp_a.json", a_doc)
    b = write(folder / "cmp_b.json", b_doc)

    def run(i, doc):
        path = write(folder / f"cmp_m{i}.json", doc)
        pair = [a, path] if i % 2 else [path, b]
        return run_checked(["compare", *pair, "--json", folder / f"cmp{i}.json"], pair, folder / f"cmp{i}.json",
                           verdict=True)

    mutants = ((i, *mutate(b_doc if i % 2 else a_doc, rng, ("cameras",) if i % 3 else ())) for i in range(num))
    run_mutants("compare (result files)", tally, mutants, lambda doc: parses(ResultFile.from_dict, doc, "result.json"),
                run, real_runs, cli_runs)
    # another lens model of the same camera is compared (a verdict: consistent or "differ"); results that
    # do not describe one camera (another image size, no camera in common) are refused
    other = estimated_result()
    other["cameras"]["cam_hand"]["model"] = "opencv5"
    other["cameras"]["cam_hand"]["dist"] = [-0.1, 0.02, 0.0, 0.0, 0.0]
    other["cameras"]["cam_hand"]["covariance"] = np.diag([0.25] * 4 + [1e-6] * 5).tolist()
    sized = estimated_result()
    sized["cameras"]["cam_hand"]["image_size"] = [1280, 960]
    renamed = estimated_result()
    renamed["cameras"] = {"other_cam": renamed["cameras"].pop("cam_hand")}
    renamed["transforms"] = {}
    path = write(folder / "cmp_other_model.json", other)
    code = run_checked(["compare", a, path], [a, path], None, verdict=True)
    assert code in (0, 1), "another lens model"
    tally.add("compare (another lens model)", "opencv5 against the source's model", code)
    for name, doc in (("another image size", sized), ("no camera in common", renamed)):
        path = write(folder / f"cmp_unrelated_{name.replace(' ', '_')}.json", doc)
        code = run_checked(["compare", a, path], [a, path], None)
        assert code == 2, name
        tally.add("compare (two unrelated results)", name, code)
    for option, value in [("--grid", "0x0"), ("--grid", "100000x100000"), ("--distance", "nan"), ("--distance", "-1"),
                          ("--camera", "nope")]:
        code = run_checked(["compare", a, b, option, value], [a, b], None)
        assert code == 2, (option, value)
        tally.add("compare options", f"{option} {value!r}", code)
