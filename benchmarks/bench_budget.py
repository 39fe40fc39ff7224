"""Error budgets by Monte Carlo (issue 35): combined σ against the scatter, and the stated-σ checks' power.

1. **Combined σ.** A hand-eye cell (:func:`jcalib.sim.cells.synthetic_cell`: flange camera ``cam0``, fixed
   camera ``cam1`` with held intrinsics, a board on the table, a tool tip) whose board is printed at a scale
   drawn from its stated σ and whose fixed camera's true intrinsics are drawn from their stated covariance;
   the cell states the nominal values. Each trial is calibrated; the errors of ``T_flange_cam0``,
   ``T_base_cam1`` and ``T_base_board`` against the truth are normalised by the sampling-only covariance and
   by ``covariance_combined``. The mean χ² per transform must be within its 95 % band (6 dof) for the
   combined σ; the sampling-only σ is shown too small.
2. **Stated-σ checks.** The true robot pose noise, corner pixel noise, or the error of the flange camera's
   held intrinsics (held at a lab calibration stated with σ fx, fy 3 px, cx, cy 2 px; the true error is
   that factor times each σ, with random signs) is 5x the
   stated value (then the check must name it in >= 95 % of seeds), or equal to it (then no check may call the
   stated σ "worse than stated" in >= 90 % of seeds).

Run: ``.venv/bin/python benchmarks/bench_budget.py [--trials 100] [--seeds 20] [--out benchmarks/data/bench_budget.txt]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parent / "data"

#: Stated σ of the Monte-Carlo cell: the board's printed scale (relative) and the held intrinsics of cam1.
SCALE_SIGMA_REL = 0.002
INTRINSICS_SIGMA = {"fx": 3.0, "fy": 3.0, "cx": 2.0, "cy": 2.0}
TRANSFORMS = ("T_flange_cam0", "T_base_cam1", "T_base_board")


def _held_camera(params) -> dict:
    from jcalib.geometry.cameras import camera_model_from_name
    from jcalib.sim.cells import SYNTH_IMAGE_SIZE

    K, d = camera_model_from_name("opencv5", SYNTH_IMAGE_SIZE, np.asarray(params, np.float64)).to_opencv()
    return {"K": np.asarray(K).tolist(), "dist": np.asarray(d).tolist()}


def budget_trial(seed: int, *, stations: tuple[int, int] = (8, 10), scale_sigma: float = SCALE_SIGMA_REL,
                 intrinsics_sigma: dict | None = None) -> dict:
    """One Monte-Carlo trial of the combined σ: the assumptions drawn from their stated distribution.

    Returns ``{transform: (chi2 sampling, chi2 combined)}`` (6 dof each)."""
    from jcalib.geometry.se3 import log_se3
    from jcalib.io.cell import parse_cell
    from jcalib.io.observations import parse_observations
    from jcalib.problems import CalibrationOptions, calibrate_cell
    from jcalib.sim.cells import SYNTH_FIXED_PARAMS, synthetic_cell

    sig = INTRINSICS_SIGMA if intrinsics_sigma is None else intrinsics_sigma
    rng = np.random.default_rng(10_000 + seed)
    true_cam1 = SYNTH_FIXED_PARAMS.copy()
    for i, n in enumerate(("fx", "fy", "cx", "cy")):
        true_cam1[i] += sig.get(n, 0.0) * rng.normal()
    scale = 1.0 + scale_sigma * rng.normal()  # the true board is this much larger than stated
    cell, obs, truth = synthetic_cell(seed, num_board_stations=stations[0], num_tool_stations=stations[1],
                                      truth={"cam1": true_cam1})
    obs["targets"]["board"]["points"] = (np.asarray(obs["targets"]["board"]["points"]) / scale).tolist()
    cell["cameras"]["cam1"]["intrinsics"] = _held_camera(SYNTH_FIXED_PARAMS)
    cell["assumptions"] = {"board.square": {"sigma_rel": scale_sigma}, "cam1.intrinsics": {"sigma": dict(sig)}}
    cal = calibrate_cell(parse_cell(cell), parse_observations(obs), CalibrationOptions(prediction=False))
    out = {}
    for name in TRANSFORMS:
        T_true = np.asarray(truth[name], np.float64)
        if name == "T_base_board":  # the true board is scaled about its origin: its pose is unchanged
            pass
        e = log_se3(np.linalg.inv(cal.transforms[name]) @ T_true)
        C = cal.transform_covariance[name]
        Cc = cal.budget["unknowns"][name]["covariance_combined"]
        out[name] = (float(e @ np.linalg.solve(C, e)), float(e @ np.linalg.solve(Cc, e)))
    return out


def check_trial(seed: int, what: str, factor: float) -> dict:
    """One seed of the stated-σ checks: ``what`` (``pose_noise``, ``pixel_noise``, ``intrinsics``) is truly
    ``factor`` x the stated σ. Returns ``{"named": the check of that input says worse than stated,
    "any_worse": some check says worse than stated}``."""
    from jcalib.io.cell import parse_cell
    from jcalib.io.observations import parse_observations
    from jcalib.problems import CalibrationOptions, calibrate_cell
    from jcalib.problems.calibrate import result_file
    from jcalib.sim.cells import SYNTH_FLANGE_PARAMS, synthetic_cell

    robot_m, robot_deg, sigma_px = 1e-4, 0.01, 0.2
    kw = {}
    true_cam0 = SYNTH_FLANGE_PARAMS.copy()
    rng = np.random.default_rng(20_000 + seed)
    if what == "pose_noise":
        kw.update(robot_m=factor * robot_m, robot_deg=factor * robot_deg)
    elif what == "pixel_noise":
        kw.update(sigma_px=factor * sigma_px, tip_sigma_px=sigma_px)
    elif what == "intrinsics":  # the flange camera's intrinsics held at a lab calibration that is off
        for i, n in enumerate(("fx", "fy", "cx", "cy")):  # factor x the stated σ, each with a random sign
            true_cam0[i] += factor * INTRINSICS_SIGMA[n] * rng.choice([-1.0, 1.0])
    else:
        raise ValueError(what)
    cell, obs, _ = synthetic_cell(seed, num_board_stations=10, num_tool_stations=12, truth={"cam0": true_cam0}, **kw)
    cell["robot"]["pose_noise"] = {"translation_m": robot_m, "rotation_deg": robot_deg}
    cell["cameras"]["cam0"].update(fix=["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"],
                                   intrinsics=_held_camera(SYNTH_FLANGE_PARAMS))
    cell["assumptions"] = {"cam0.intrinsics": {"sigma": dict(INTRINSICS_SIGMA)}}
    options = CalibrationOptions(prediction=False, sigma_px=sigma_px, tip_sigma_px=sigma_px)
    cal = calibrate_cell(parse_cell(cell), parse_observations(obs), options)
    checks = result_file(cal, options, "0" * 16).stats["assumption_checks"]
    target = {"pose_noise": lambda c: c["kind"] == "robot", "pixel_noise": lambda c: c["what"] == "corner noise",
              "intrinsics": lambda c: c["what"] == "cam0.intrinsics"}[what]
    worse = [c for c in checks if c["verdict"] == "worse than stated"]
    return {"named": any(target(c) for c in worse), "any_worse": bool(worse),
            "factor": next((c["factor"] for c in checks if target(c)), None)}


def chi2_band(dof: int, trials: int) -> tuple[float, float]:
    """95 % band of the mean of ``trials`` χ²(dof) values."""
    from scipy import stats

    lo, hi = stats.chi2.ppf([0.025, 0.975], dof * trials)
    return lo / trials, hi / trials


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=100, help="Monte-Carlo trials of the combined σ (default 100)")
    p.add_argument("--seeds", type=int, default=20, help="seeds per stated-σ check case (default 20)")
    p.add_argument("--out", type=Path, default=DATA / "bench_budget.txt", help="where the table is written")
    args = p.parse_args(argv)
    if args.trials < 2 or args.seeds < 1:
        p.error("--trials must be >= 2 and --seeds >= 1")
    from jcalib.solve import enable_compilation_cache

    enable_compilation_cache()
    t0 = time.perf_counter()
    lines = [f"# python benchmarks/bench_budget.py --trials {args.trials} --seeds {args.seeds}", ""]
    rows = [budget_trial(s) for s in range(args.trials)]
    lo, hi = chi2_band(6, args.trials)
    lines.append(f"1. combined σ: hand-eye cell, board scale drawn with σ {SCALE_SIGMA_REL:.1%}, held cam1 intrinsics "
                 f"drawn with σ {INTRINSICS_SIGMA} ({args.trials} trials)")
    lines.append(f"   mean χ² per transform (6 dof), 95 % band [{lo:.2f}, {hi:.2f}]")
    lines.append(f"   {'transform':<16}{'sampling only':>15}{'combined':>12}  combined in band  sampling too small")
    for name in TRANSFORMS:
        s = float(np.mean([r[name][0] for r in rows]))
        c = float(np.mean([r[name][1] for r in rows]))
        lines.append(f"   {name:<16}{s:>15.2f}{c:>12.2f}  {'yes' if lo <= c <= hi else 'NO':<16}  "
                     f"{'yes' if s > hi else 'no'}")
    lines.append("")
    lines.append(f"2. stated-σ checks ({args.seeds} seeds each; named: the check of that input says 'worse than "
                 "stated'; silent: no check says so)")
    lines.append(f"   {'true / stated':<26}{'5x: named':>12}{'1x: silent':>12}  {'median factor 5x':>17}  met (>=95 %, >=90 %)")
    for what in ("pose_noise", "pixel_noise", "intrinsics"):
        five = [check_trial(s, what, 5.0) for s in range(args.seeds)]
        one = [check_trial(s, what, 1.0) for s in range(args.seeds)]
        named = np.mean([t["named"] for t in five])
        silent = np.mean([not t["any_worse"] for t in one])
        fac = np.median([t["factor"] for t in five if t["factor"] is not None] or [np.nan])
        lines.append(f"   {what:<26}{named:>12.0%}{silent:>12.0%}  {fac:>17.2f}  "
                     f"{'yes' if named >= 0.95 and silent >= 0.90 else 'NO'}")
    lines.append("")
    lines.append(f"({time.perf_counter() - t0:.0f} s)")
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(text)
    tmp.replace(args.out)


if __name__ == "__main__":
    sys.exit(main())
