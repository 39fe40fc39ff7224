"""Every example in ``examples/`` runs as its README says and matches the values stored beside it.

Each ``examples/<name>/README.md`` has one ```` ```bash ```` block of ``jcalib`` commands, run here in order in
a copy of the example's folder (in this process, as the CLI's ``main``; each must exit 0). Its
``expected.json`` holds the simulation's truth (``examples/make_examples.py``, never jcalib's output) and
``max_sigma``: every calibrated component of the result must lie within that many of its own σ of the truth
(transforms per tangent component rx..tz as the result's covariance states them, intrinsics per name,
points per coordinate, kinematic parameters per calibrated name). So the docs' commands cannot rot.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import shlex
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from jcalib.geometry.se3 import invert, log_so3
from jcalib.io.result import ResultFile

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
NAMES = sorted(p.name for p in EXAMPLES.iterdir() if (p / "README.md").is_file())
#: Examples run under ``slow`` only: each new problem shape costs seconds of compilation, and these repeat
#: what the default ones and their own tests cover (the kinematic solve with a pose sensor:
#: tests/problems/test_pose_sensors.py, which also solves the point sensor's cell; eye-to-hand mirrors eye-in-hand; stereo and camera TCP:
#: tests/problems). The default ones: a camera, eye-in-hand, a tracked pivot and a pose sensor's hand-eye.
SLOW = {"kinematics-tracker", "stereo", "eye-to-hand", "camera-tcp", "two-robots", "tracker-reflector"}
_TANGENT = ("rx", "ry", "rz", "tx", "ty", "tz")


def commands(name: str) -> list[list[str]]:
    """The ``jcalib`` command lines of an example's README (its one bash block; ``\\`` continues a line)."""
    text = (EXAMPLES / name / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```bash\n(.*?)```", text, flags=re.S)
    assert len(blocks) == 1, f"{name}/README.md: expected one ```bash block of commands, got {len(blocks)}"
    lines = blocks[0].replace("\\\n", " ").splitlines()
    out = [shlex.split(line, comments=True) for line in lines]
    out = [c for c in out if c]
    assert out and all(c[0] == "jcalib" for c in out), f"{name}/README.md: every command is a jcalib command"
    return out


def run(argv: list[str], cwd: Path) -> tuple[int, str]:
    from jcalib.app.cli import main

    buf = io.StringIO()
    old_argv = sys.argv
    sys.argv = argv
    try:
        with contextlib.chdir(cwd), contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            main()
        return 0, buf.getvalue()
    except SystemExit as e:
        return int(e.code or 0), buf.getvalue()
    finally:
        sys.argv = old_argv


def within(err: np.ndarray, sigma: np.ndarray, k: float, names, what: str) -> None:
    bad = [f"{n}: {e:.3g} vs σ {s:.3g}" for n, e, s in zip(names, err, sigma) if not abs(e) <= k * s]
    assert not bad, f"{what}: beyond {k} σ of the truth: {'; '.join(bad)}"


def check(result: ResultFile, expected: dict) -> int:
    """Compare a result with an example's expected values; the number of components compared."""
    k, n = float(expected["max_sigma"]), 0
    for name, T_true in expected.get("transforms", {}).items():
        tr = result.transforms[name]
        D = invert(np.asarray(tr.matrix)) @ np.asarray(T_true)
        err = np.concatenate([log_so3(D[:3, :3]), D[:3, 3]])
        sigma = np.sqrt(np.diag(np.asarray(tr.covariance)))
        keep = [i for i, c in enumerate(_TANGENT) if c in tr.extra.get("calibrated", _TANGENT)]
        within(err[keep], sigma[keep], k, [_TANGENT[i] for i in keep], name)
        n += len(keep)
    for cam, values in expected.get("cameras", {}).items():
        c = result.cameras[cam]
        names = list(c.param_names)
        assert set(values) == set(names), (cam, names)
        est = dict(zip(names, c.params))
        sigma = np.sqrt(np.diag(np.asarray(c.covariance)))
        within(np.array([est[x] - values[x] for x in names]), sigma, k, names, cam)
        n += len(names)
    for p, pos in expected.get("points", {}).items():
        pt = result.points[p]
        within(np.asarray(pt.position) - pos, np.sqrt(np.diag(np.asarray(pt.covariance))), k, "xyz", p)
        n += 3
    for robot, values in expected.get("kinematics", {}).items():
        kin = result.kinematics[robot]
        est = dict(zip(kin.names, kin.values))
        cal = list(kin.calibrated)
        assert cal, f"{robot}: no kinematic parameter calibrated"
        within(np.array([est[x] - values[x] for x in cal]), np.sqrt(np.diag(np.asarray(kin.covariance))), k, cal,
               f"kinematics.{robot}")
        n += len(cal)
    return n


def test_every_cell_kind_has_an_example():
    assert {"camera", "stereo", "eye-in-hand", "eye-to-hand", "camera-tcp", "pivot-tracker", "two-robots",
            "kinematics-tracker", "tracker-handeye", "tracker-reflector"} <= set(NAMES)
    for name in NAMES:
        d = EXAMPLES / name
        assert (d / "cell.yaml").is_file() and (d / "expected.json").is_file(), name
        commands(name)


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in NAMES])
def test_example_runs_and_matches_its_expected_values(name, tmp_path):
    work = tmp_path / name
    shutil.copytree(EXAMPLES / name, work)
    for argv in commands(name):
        code, text = run(argv, work)
        assert code == 0, f"{name}: {shlex.join(argv)} exited {code}:\n{text[-3000:]}"
    expected = json.loads((work / "expected.json").read_text())
    assert check(ResultFile.load(work / expected["result"]), expected) > 0


@pytest.mark.parametrize("name", NAMES)
def test_example_files_validate_against_the_published_schemas(name):
    """An editor that follows ``cell.yaml``'s ``yaml-language-server`` line validates it, and the observations,
    with the shipped JSON Schemas (jcalib/io/schema/json)."""
    import jsonschema
    import yaml

    d = EXAMPLES / name
    head = (d / "cell.yaml").read_text(encoding="utf-8").splitlines()[0]
    schema_path = (d / head.split("$schema=", 1)[1]).resolve()
    assert schema_path == (EXAMPLES.parent / "jcalib/io/schema/json/cell.schema.json").resolve()
    for file, schema in (("cell.yaml", schema_path), ("observations.json", schema_path.with_name(
            "observations.schema.json"))):
        text = (d / file).read_text(encoding="utf-8")
        doc = json.loads(text) if file.endswith(".json") else yaml.safe_load(text)
        validator = jsonschema.Draft202012Validator(json.loads(schema.read_text(encoding="utf-8")))
        errors = list(validator.iter_errors(doc))
        assert not errors, f"{name}/{file}: {errors[0].message[:300]}"


def test_the_check_can_fail():
    """A truth moved by 10 σ of a component is reported (the comparison is not vacuous)."""
    cov = np.diag([1e-6] * 3 + [1e-8] * 3)
    result = ResultFile.from_dict({"schema": "jcalib.result/1", "cameras": {}, "transforms": {
        "T_base_x": {"matrix": np.eye(4).tolist(), "covariance": cov.tolist()}}, "stats": {}})
    T = np.eye(4)
    T[0, 3] = 1e-3  # 10 σ of tx
    with pytest.raises(AssertionError, match="tx"):
        check(result, {"max_sigma": 5.0, "transforms": {"T_base_x": T.tolist()}})
    assert check(result, {"max_sigma": 5.0, "transforms": {"T_base_x": np.eye(4).tolist()}}) == 6
