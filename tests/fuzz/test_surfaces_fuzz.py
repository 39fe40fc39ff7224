"""Mutation fuzzing of the newer surfaces (issue 32): kinematic tables, plan files and the ``plan`` command's
options, ``convert`` and ``compare`` (result files, options, unrelated pairs), ``cross-validate``'s options.

Each mutant of a valid document (a value replaced by a hostile one, a key deleted or added, a number scaled
by a unit factor, a value turned into text) goes through the cheap parser; the first refused ones go through
the CLI, which must exit 2 with a message before any solve, and a handful of accepted ones run for real.
Always: exit status 0, 2 or 3 (``compare``'s verdict "differ", 1, said so), no "internal error", no
traceback, no input file changed, no output left by a refused command. Fixed seeds; the whole file runs in
well under 90 s on one core (the cases are in :mod:`surfaces_fuzz`; ``benchmarks/bench_surfaces_fuzz.py``
runs more of them and prints the table of inputs and outcomes).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import surfaces_fuzz as sf

pytestmark = pytest.mark.filterwarnings("ignore::jcalib.errors.InputWarning")  # mutations warn, by design

GOLDEN_PLAN = Path(__file__).resolve().parents[1] / "golden" / "planning" / "plan_optimal.json"


@pytest.fixture
def tally():
    return sf.Tally()


def test_mutated_kinematic_tables_are_refused_before_planning_or_give_a_finite_model(tmp_path, tally):
    sf.fuzz_kinematic_tables(tmp_path, tally, num=60, seed=1, cli_runs=8)
    refused = sum(sum(c.values()) for k, c in tally.rows["kinematic table"].items() if "refused" in k)
    assert refused >= 20  # the mutations reach the parser's refusals, not only harmless edits


def test_mutated_plan_files_are_refused_or_reported(tmp_path, tally):
    result = sf.write(tmp_path / "result.json", sf.goal_result())
    sf.fuzz_plan_files(tmp_path, tally, num=40, seed=2, golden=GOLDEN_PLAN, result=result, real_runs=1, cli_runs=8)


def test_every_hostile_plan_option_is_a_usage_error_naming_it(inputs, tmp_path, tally):
    sf.fuzz_plan_options(tmp_path, tally, inputs["cell"], every_kind=False)


def test_every_hostile_cross_validate_option_is_a_usage_error_naming_it(inputs, tally):
    sf.fuzz_crossval_options(tally, inputs["cell"], inputs["observations"])


def test_mutated_results_and_options_of_convert(tmp_path, tally):
    sf.fuzz_convert(tmp_path, tally, num=40, seed=3, real_runs=1, cli_runs=8)
    assert tally.rows["convert options"]


def test_mutated_and_unrelated_results_of_compare(tmp_path, tally):
    sf.fuzz_compare(tmp_path, tally, num=40, seed=4, real_runs=1, cli_runs=8)
    assert len(tally.rows["compare (two unrelated results)"]) == 2
    assert len(tally.rows["compare (another lens model)"]) == 1
