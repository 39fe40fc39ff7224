"""Monte-Carlo check of the reported hand-eye covariance: normalised errors follow χ²(6).

A fast version of ``benchmarks/bench_handeye_consistency.py``: 0.2 px corners, robot 0.1 mm /
0.01 deg, 15 stations, pose model on, free intrinsics, fixed seeds. With NEES_k = δ_kᵀ Σ_k⁻¹ δ_k
(``T_true = T_est · Exp(δ)``) and Σ_k the reported covariance, Σ_k NEES_k ~ χ²(6N) if Σ is right;
the bounds are that distribution's 0.1 % / 99.9 % quantiles (a 0.2 % false alarm rate for a
correct covariance, while a covariance off by 1.3x in σ fails).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binom, chi2

from jcalib.geometry import lie

_path = Path(__file__).resolve().parent / "test_handeye_joint.py"
_spec = importlib.util.spec_from_file_location("_handeye_joint_helpers_consistency", _path)
J = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(J)


@pytest.mark.parametrize(("mount", "trials"), [pytest.param("flange", 40, marks=pytest.mark.slow(
    reason="40 trials (8 s): ./scripts/test -m slow; the base mount runs the same check")), ("base", 20)])
def test_reported_covariance_matches_monte_carlo_spread(mount, trials):
    nees = []
    for trial in range(trials):
        cell, obs, truth = J.make_data(5000 + trial, mount, sigma_px=0.2, robot_m=1e-4, robot_deg=0.01)
        cal = J.calibrate(cell, obs, sigma_px=0.2)
        assert cal.pose_model
        X = J.names(mount)[0]
        delta = np.asarray(lie.local(lie.se3_from_matrix(cal.transforms[X]), lie.se3_from_matrix(truth["T_hand_eye"])))
        nees.append(float(delta @ np.linalg.solve(cal.transform_covariance[X], delta)))
    nees = np.array(nees)
    lo, hi = chi2.ppf([0.001, 0.999], 6 * trials)
    assert lo <= nees.sum() <= hi, (nees.mean(), lo / trials, hi / trials)
    # no heavy tail: trials above χ²_6(0.99) are Binomial(trials, 0.01); bound at its 99.9 % quantile
    assert np.sum(nees > chi2.ppf(0.99, 6)) <= binom.ppf(0.999, trials, 0.01), np.sort(nees)[-5:]
