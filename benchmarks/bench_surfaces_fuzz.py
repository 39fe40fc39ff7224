"""Mutation fuzzing of the newer surfaces (issue 32), at a larger scale than the test suite: the table of
inputs tried per surface and how the CLI answered them (markdown).

Surfaces: kinematic tables in a cell spec (dh, mdh, poe; ``jcalib plan --kind kinematics``), plan files
(``jcalib report --plan``), every hostile value of the ``plan`` options, ``cross-validate``'s options,
``convert`` and ``compare`` (mutated result files, unrelated pairs, hostile options). The cases and the
checks are those of ``tests/fuzz/test_surfaces_fuzz.py`` (:mod:`surfaces_fuzz`): exit status 0, 2 or 3
(compare's verdict "differ", 1), no internal error or traceback, no input file changed, no output left by
a refused command; a failed check stops the run with its case.

Run: ``.venv/bin/python benchmarks/bench_surfaces_fuzz.py [--quick] [--seed N]``; the committed table is
``benchmarks/data/bench_surfaces_fuzz.txt``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "fuzz"))

import fuzz_files  # noqa: E402
import surfaces_fuzz as sf  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the test suite's sizes")
    parser.add_argument("--seed", type=int, default=100, help="seed of the mutations")
    args = parser.parse_args()
    num, cli, real = (40, 8, 1) if args.quick else (300, 60, 6)
    warnings.simplefilter("ignore")
    tally = sf.Tally()
    times = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        inputs = fuzz_files.write_all(tmp / "in")
        golden = ROOT / "tests" / "golden" / "planning" / "plan_optimal.json"
        result = sf.write(tmp / "goal_result.json", sf.goal_result())
        steps = {
            "kinematic tables": lambda d: sf.fuzz_kinematic_tables(d, tally, num, args.seed, cli_runs=cli),
            "plan files": lambda d: sf.fuzz_plan_files(d, tally, num, args.seed + 1, golden, result, real_runs=real,
                                                       cli_runs=cli),
            "plan options": lambda d: sf.fuzz_plan_options(d, tally, inputs["cell"], every_kind=not args.quick),
            "cross-validate options": lambda d: sf.fuzz_crossval_options(tally, inputs["cell"], inputs["observations"]),
            "convert": lambda d: sf.fuzz_convert(d, tally, num, args.seed + 2, real_runs=real, cli_runs=cli),
            "compare": lambda d: sf.fuzz_compare(d, tally, num, args.seed + 3, real_runs=real, cli_runs=cli),
        }
        for name, step in steps.items():
            folder = tmp / name.replace(" ", "_")
            folder.mkdir()
            t0 = time.perf_counter()
            step(folder)
            times[name] = time.perf_counter() - t0
    print(f"Mutation fuzzing of the newer surfaces (seed {args.seed}; {num} mutants per document surface, the first "
          f"{cli} refused by the parser and {real} accepted run through the CLI; the rest of the refused ones are "
          "\"parser only\"). Every row passed the checks: exit status in {0, 1 (compare: differ), 2, 3}, no internal "
          "error, no input changed, nothing written by a refused command.\n")
    print(tally.markdown())
    print("\n| step | seconds |\n|---|---:|")
    for name, t in times.items():
        print(f"| {name} | {t:.1f} |")


if __name__ == "__main__":
    main()
