"""Strategy studies: thousands of simulated calibrations of any cell, every estimator on each, as a
tidy table; on this machine (batched) or on a ``dask.distributed`` cluster.

A scenario (:mod:`jcalib.study.scenario`) is a cell spec + its truth (:mod:`jcalib.study.truth`) +
noise + station strategies (:mod:`jcalib.study.stations`) + estimators (the one builder with options,
and closed forms). Trials are simulated by :func:`jcalib.sim.observe.simulate_observations` and solved
by :func:`jcalib.calibrate_batch`.
"""

from jcalib.study.metrics import columns, unknowns
from jcalib.study.run import run_study, run_trials, write_table
from jcalib.study.scenario import (
    CLOSED_FORMS,
    STRATEGIES,
    STRATEGY_OPTIONS,
    Block,
    Estimator,
    Noise,
    Scenario,
    load_scenario,
)
from jcalib.study.simulate import Trial, simulate_trial, trial_rng

__all__ = [
    "CLOSED_FORMS",
    "STRATEGIES",
    "STRATEGY_OPTIONS",
    "Block",
    "Estimator",
    "Noise",
    "Scenario",
    "Trial",
    "columns",
    "load_scenario",
    "run_study",
    "run_trials",
    "simulate_trial",
    "trial_rng",
    "unknowns",
    "write_table",
]
