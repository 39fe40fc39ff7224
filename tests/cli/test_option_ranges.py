"""Issue 32: numeric options are checked when the command line is parsed. A negative seed, a zero count
(which once silently meant "the default"), NaN or an absurd limit is a usage error (exit 2) naming the
option, before any file is read or any work is done."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fuzz"))
from fuzz_helpers import run_cli  # noqa: E402


def _refused(args, option: str) -> str:
    """Run ``jcalib ARGS``: exit 2 naming ``option``; returns the message as one line (rich's box undone)."""
    code, text = run_cli(*args)
    text = " ".join(text.replace("│", " ").split())
    assert code == 2, (args, text)
    assert f"'{option}'" in text or f"{option}:" in text, (args, text)
    return text


@pytest.fixture
def files(tmp_path):
    """Paths that the parse-time refusal must never read (they do not exist)."""
    return {"cell": tmp_path / "cell.yaml", "obs": tmp_path / "obs.json", "out": tmp_path / "out.json",
            "a": tmp_path / "a.json", "b": tmp_path / "b.json"}


@pytest.mark.parametrize("kind", ["handeye", "tcp", "kinematics", "optimal"])
def test_plan_refuses_a_negative_seed(files, kind):
    _refused(["plan", "--cell", files["cell"], "--kind", kind, "-o", files["out"], "--seed", "-1"], "--seed")
    assert not files["out"].exists()


@pytest.mark.parametrize(("option", "value"), [
    ("--max-stations", "0"), ("--candidates", "0"), ("--stations", "0"), ("--max-stations", "-2"),
    ("--candidates", "1000000000"), ("--sigma-px", "0"), ("--sigma-px", "nan"), ("--amplitude-deg", "inf"),
    ("--amplitude-deg", "-5"), ("--seed", "4294967296"),
])
def test_plan_refuses_zero_counts_and_absurd_values(files, option, value):
    text = _refused(["plan", "--cell", files["cell"], "--kind", "optimal", "-o", files["out"], option, value], option)
    if value == "0" and option != "--sigma-px":
        assert "0 does not mean the default" in text


@pytest.mark.parametrize(("option", "value"), [
    ("--seed", "-1"), ("--grid", "0x0"), ("--grid", "100000x100000"), ("--distance", "nan"), ("--distance", "0"),
    ("--sigma-px", "-0.5"), ("--outlier-threshold", "-1"), ("--outlier-threshold", "nan"),
])
def test_cross_validate_refuses_bad_options(files, option, value):
    _refused(["cross-validate", files["cell"], files["obs"], "--split", "random", option, value], option)


@pytest.mark.parametrize(("option", "value"), [("--grid", "1x1"), ("--grid", "24x"), ("--distance", "-3")])
def test_compare_refuses_bad_options(files, option, value):
    _refused(["compare", files["a"], files["b"], option, value], option)


@pytest.mark.parametrize(("args", "option"), [
    (["demo", "--seed", "-1"], "--seed"),
    (["demo", "--camera-only", "--views", "0"], "--views"),
    (["demo", "--stations", "0"], "--stations"),
    (["simulate", "--cell", "c.yaml", "--robot-protocol", "kuka", "--camera", "cam0=127.0.0.2", "--seed", "-1"],
     "--seed"),
    (["simulate", "--cell", "c.yaml", "--robot-protocol", "kuka", "--camera", "cam0=127.0.0.2",
      "--kinematic-errors", "-3"], "--kinematic-errors"),
    (["simulate", "--cell", "c.yaml", "--robot-protocol", "kuka", "--camera", "cam0=127.0.0.2", "--time-scale",
      "nan"], "--time-scale"),
    (["capture", "--robot", "kuka://127.0.0.1:1", "--camera", "cam0=gige://127.0.0.2", "-o", "s", "--goal",
      "T_flange_cam0:translation_mm<=0.05", "--max-stations", "0"], "--max-stations"),
    (["capture", "--robot", "kuka://127.0.0.1:1", "--camera", "cam0=gige://127.0.0.2", "-o", "s", "--goal",
      "T_flange_cam0:translation_mm<=0.05", "--seed", "-1"], "--seed"),
    (["capture", "--robot", "kuka://127.0.0.1:1", "--camera", "cam0=gige://127.0.0.2", "-o", "s", "--goal",
      "T_flange_cam0:translation_mm<=0.05", "--candidates", "0"], "--candidates"),
    (["frame", "points.json", "-o", "f.json", "--sigma-mm", "-1"], "--sigma-mm"),
])
def test_other_commands_refuse_negative_seeds_and_zero_counts(tmp_path, monkeypatch, args, option):
    monkeypatch.chdir(tmp_path)
    _refused(args, option)
    assert list(tmp_path.iterdir()) == []  # nothing written, nothing started
