"""Size of the compiled solves and the time of the solve alone (issue 16).

Compile time, the persistent cache's load time and the re-lowering of a cached solve all grow with the
size of the program XLA compiles. This prints, for three cells built by the one builder:

- StableHLO operations of the whole solve (``_core``: LM loop, covariance, observability) and of each
  factor group's linearisation, counted in the lowered text of the padded problem;
- for the camera-only cell at 25 and 400 views, the wall time of ``jcalib.solve.solve`` on the prepared
  problem (no parsing, start or result file), with 1, 2 and all LM iterations: the floor under any
  public ``jcalib.calibrate`` time.

Cells: the demo cell (``benchmarks/data/demo_cell``: two cameras, board, torch with its axis, pose model),
a camera-only calibration (``bench_budgets.camera_inputs``), a 6-axis arm whose kinematics are calibrated
(``sim.kinematic_cells.synthetic_arm_cell``, 30 stations).

Run: ``.venv/bin/python benchmarks/bench_program_size.py`` (the solve timings use a warm in-process jit).
"""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path

import jax

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_budgets import camera_inputs  # noqa: E402

import jcalib  # noqa: E402, F401  (float64)
from jcalib.io.cell import load_cell  # noqa: E402
from jcalib.io.observations import load_observations  # noqa: E402
from jcalib.problems.calibrate import prepare  # noqa: E402
from jcalib.solve import SolveOptions, linear, solve  # noqa: E402
from jcalib.solve.batch import pad_problem  # noqa: E402
from jcalib.solve.core import _core  # noqa: E402


def ops(fn, *args) -> int:
    """StableHLO / CHLO operations in the lowered text of ``jit(fn)(*args)``."""
    return len(re.findall(r"= (?:stablehlo|chlo|mhlo)\.", jax.jit(fn).lower(*args).as_text()))


def problem_of(cell, obs):
    return prepare(load_cell(cell), load_observations(obs))[2].problem


def sizes(name: str, problem) -> None:
    padded = pad_problem(problem)
    free, x = linear.free_masks(padded), padded.initial_values()
    total = ops(lambda q: _core(q, SolveOptions(), True), padded)
    print(f"\n{name}: whole solve {total:,} ops")
    for f in padded.factors:
        n = ops(lambda v, f=f: linear.factor_linearization(padded, v, f, free)[:3], x)
        print(f"  {f.name:40s} {f.num_obs:6d} observations  linearisation {n:6,} ops")


def solve_times(num_views: int, repeats: int = 10) -> None:
    problem = problem_of(*camera_inputs(num_views))
    print(f"\ncamera-only, {num_views} views: jcalib.solve.solve on the prepared problem (median of {repeats})")
    for label, opts in (("1 iteration", SolveOptions(mu0=1e-6, max_iterations=1)),
                        ("2 iterations", SolveOptions(mu0=1e-6, max_iterations=2)),
                        ("to convergence", SolveOptions(mu0=1e-6))):
        sol = solve(problem, options=opts, raise_on_unobservable=False)
        runs = []
        for _ in range(repeats):
            t = time.perf_counter()
            sol = solve(problem, options=opts, raise_on_unobservable=False)
            runs.append(time.perf_counter() - t)
        runs.sort()
        print(f"  {label:15s} {1e3 * runs[len(runs) // 2]:8.2f} ms  (LM iterations {int(sol.raw.iterations)})")


def main() -> None:
    from jcalib.sim.kinematic_cells import synthetic_arm_cell

    demo = HERE / "data" / "demo_cell"
    sizes("demo cell (22 stations)", problem_of(demo / "cell.yaml", demo / "observations.json"))
    sizes("camera-only (25 views)", problem_of(*camera_inputs(25)))
    cell, obs, _ = synthetic_arm_cell(5, num_stations=30, num_heldout=10)
    sizes("kinematic arm cell (30 stations)", problem_of(cell, obs))
    for n in (25, 400):
        solve_times(n)


if __name__ == "__main__":
    main()
