"""Strategy studies: thousands of simulated calibrations of one scenario, every estimator on each,
as a tidy table; on this machine (batched) or on a ``dask.distributed`` cluster."""

from jcalib.study.estimators import columns
from jcalib.study.run import run_study, write_table
from jcalib.study.scenario import (
    ESTIMATORS,
    STRATEGIES,
    Noise,
    Scenario,
    Stations,
    load_scenario,
)
from jcalib.study.simulate import simulate_trial, trial_rng

__all__ = [
    "ESTIMATORS",
    "STRATEGIES",
    "Noise",
    "Scenario",
    "Stations",
    "columns",
    "load_scenario",
    "run_study",
    "simulate_trial",
    "trial_rng",
    "write_table",
]
