"""Rank deficiency is reported by name, not returned as noise."""

import jax.numpy as jnp
import numpy as np
import pytest
from solve_problems import calibration_data, calibration_problem, perturbed_start

import jcalib
from jcalib.solve import Euclidean, FactorGroup, Problem, Status, Variable, solve


def _offset_pair(theta, obs):
    t, y = obs
    return jnp.atleast_1d(theta[0] * jnp.exp(theta[1] * t) + theta[2] + theta[3] - y)


def test_gauge_freedom_between_two_offsets_is_named():
    t = np.linspace(0.0, 1.0, 30)
    y = 2.0 * np.exp(-1.3 * t) + 0.5 + 0.01 * np.random.default_rng(0).standard_normal(30)
    v = Variable("theta", Euclidean(4), np.array([1.0, -1.0, 0.1, 0.1]), coord_names=("a", "b", "c", "d"))
    f = FactorGroup("fit", _offset_pair, ("theta",), (np.zeros(30, np.int32),), (t, y), sigma=0.01)
    with pytest.raises(jcalib.NotObservableError) as info:
        solve(Problem([v], [f]))
    assert len(info.value.unknowns) == 1
    assert set(info.value.unknowns[0].split(" + ")) == {"theta.c", "theta.d"}
    assert "theta.c" in str(info.value)
    sol = solve(Problem([v], [f]), raise_on_unobservable=False)
    assert sol.status == Status.NOT_OBSERVABLE
    # fixing one of the two removes the gauge freedom
    v2 = Variable("theta", Euclidean(4), np.array([1.0, -1.0, 0.1, 0.1]), fixed=[False, False, False, True],
                  coord_names=("a", "b", "c", "d"))
    assert solve(Problem([v2], [f])).status == Status.CONVERGED


@pytest.fixture(scope="module")
def calib():
    data = calibration_data(num_views=5, noise_px=0.1, seed=0, cols=5, rows=4)
    K0, P0 = perturbed_start(data, np.random.default_rng(1))
    return data, K0, P0


def test_variable_no_factor_touches_is_named(calib):
    data, K0, P0 = calib
    p = calibration_problem(data, K0, P0)
    p2 = Problem(list(p.variables) + [Variable("T_flange_cam", Euclidean(2), np.zeros(2), coord_names=("u", "v"))],
                 p.factors)
    with pytest.raises(jcalib.NotObservableError) as info:
        solve(p2)
    assert sorted(info.value.unknowns) == ["T_flange_cam.u", "T_flange_cam.v"]


def test_underdetermined_eliminated_pose_is_named(calib):
    data, K0, P0 = calib
    # view 3 keeps only 2 of its 20 corners: 4 equations for 6 pose unknowns -> 2 null directions
    keep = (data["view_index"] != 3) | (np.arange(len(data["view_index"])) % 20 < 2)
    d2 = {k: (v[keep] if k in ("points", "uv", "view_index") else v) for k, v in data.items()}
    with pytest.raises(jcalib.NotObservableError) as info:
        solve(calibration_problem(d2, K0, P0))
    assert len(info.value.unknowns) == 2
    assert all(u.startswith("view 3 pose") for n in info.value.unknowns for u in n.split(" + "))
    # the full data set is observable
    assert solve(calibration_problem(data, K0, P0)).status == Status.CONVERGED
