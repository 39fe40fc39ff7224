"""Chunked factor groups and constant variables: same system and solution as the plain path."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from solve_problems import INTRINSIC_NAMES, calibration_data, perturbed_start, project

import jcalib  # noqa: F401  (float64)
from jcalib.errors import BadInputError
from jcalib.solve import SE3, Euclidean, FactorGroup, Problem, SolveOptions, Variable, linear, solve
from jcalib.solve.manifolds import quat_rotate
from jcalib.solve import pad_problem

NUM_VIEWS = 5
POINTS_PER_VIEW = 54  # 9 x 6 board of solve_problems


def _data():
    data = calibration_data(num_views=NUM_VIEWS, noise_px=0.2, seed=4)
    K0, P0 = perturbed_start(data, np.random.default_rng(5))
    return data, K0, P0


def _problem(data, K0, P0, chunk, weights=None):
    K = Variable("intrinsics", Euclidean(6), K0, coord_names=INTRINSIC_NAMES)
    poses = Variable("T_cam_target", SE3(), P0, eliminate=True)
    f = FactorGroup(
        "reprojection", project, ("intrinsics", "T_cam_target"),
        (np.zeros(len(data["view_index"]), np.int32), data["view_index"]),
        (data["points"], data["uv"]), sigma=0.2, sqrt_weight=weights, chunk=chunk,
    )
    return Problem([K, poses], [f])


def _system(problem):
    layout = linear.make_layout(problem)
    cost, system, m_eff, _groups = linear.linearize(problem, layout, problem.initial_values(),
                                                    linear.free_masks(problem))
    return cost, system, m_eff


def test_chunked_group_assembles_the_same_normal_equations():
    data, K0, P0 = _data()
    # some zero weights so that a run's sum is not just a sum of equal parts
    w = np.ones(NUM_VIEWS * POINTS_PER_VIEW)
    w[::7] = 0.0
    cost_a, sys_a, m_a = _system(_problem(data, K0, P0, None, w))
    cost_b, sys_b, m_b = _system(_problem(data, K0, P0, POINTS_PER_VIEW, w))
    # same sums in a different order: float64 rounding only
    np.testing.assert_allclose(float(cost_b), float(cost_a), rtol=1e-12)
    assert int(m_a) == int(m_b)
    for a, b in ((sys_a.H_ss, sys_b.H_ss), (sys_a.g_s, sys_b.g_s), (sys_a.V[0], sys_b.V[0]),
                 (sys_a.W[0], sys_b.W[0]), (sys_a.g_e[0], sys_b.g_e[0])):
        scale = float(jnp.max(jnp.abs(a)))
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=0, atol=1e-11 * scale)


def test_chunked_group_solves_to_the_same_optimum_and_pads_whole_runs():
    data, K0, P0 = _data()
    plain = solve(_problem(data, K0, P0, None))
    chunked = solve(_problem(data, K0, P0, POINTS_PER_VIEW))
    # one optimum up to where each solve stops inside the float64 resolution of the cost (~1e-7 of a
    # standard deviation; the two sum in different orders): compared in units of σ
    sigma = np.sqrt(np.diag(plain.covariance("intrinsics")))
    assert np.all(np.abs(np.asarray(chunked.values["intrinsics"][0]) - np.asarray(plain.values["intrinsics"][0]))
                  < 1e-5 * sigma)
    np.testing.assert_allclose(chunked.covariance("intrinsics"), plain.covariance("intrinsics"), rtol=1e-7)
    padded = pad_problem(_problem(data, K0, P0, POINTS_PER_VIEW), size_fn=lambda n: n + 3)
    assert padded.factors[0].num_obs == (NUM_VIEWS + 3) * POINTS_PER_VIEW  # whole runs added
    idx = np.asarray(padded.factors[0].indices[1]).reshape(-1, POINTS_PER_VIEW)
    assert np.all(idx == idx[:, :1])  # every run still shares one index


def test_chunk_that_splits_a_view_is_refused_by_name():
    data, K0, P0 = _data()
    with pytest.raises(BadInputError, match="indices differ inside run"):
        _problem(data, K0, P0, 45)  # runs of 45 straddle views of 54 corners
    with pytest.raises(BadInputError, match="positive divisor"):
        _problem(data, K0, P0, 7)


def _rig_problem(data, K0, P0, constant):
    """The board seen through a fixed extra transform T_cam_rig (constant or merely all-fixed)."""
    T_rig = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])

    def fn(K, T_cam_rig, T_rig_target, obs):
        p_target, uv = obs
        p_rig = quat_rotate(T_rig_target[:4], p_target) + T_rig_target[4:]
        p = quat_rotate(T_cam_rig[:4], p_rig) + T_cam_rig[4:]
        return project(K, jnp.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]), (p, uv))

    K = Variable("intrinsics", Euclidean(6), K0, coord_names=INTRINSIC_NAMES)
    rig = Variable("T_cam_rig", SE3(), T_rig, fixed=True, constant=constant)
    poses = Variable("T_rig_target", SE3(), P0, eliminate=True)
    n = len(data["view_index"])
    f = FactorGroup("reprojection", fn, ("intrinsics", "T_cam_rig", "T_rig_target"),
                    (np.zeros(n, np.int32), np.zeros(n, np.int32), data["view_index"]),
                    (data["points"], data["uv"]), sigma=0.2)
    return Problem([K, rig, poses], [f])


def test_constant_variable_equals_a_fully_fixed_one():
    data, K0, P0 = _data()
    fixed = solve(_rig_problem(data, K0, P0, False))
    const = solve(_rig_problem(data, K0, P0, True))
    np.testing.assert_array_equal(const.values["T_cam_rig"], fixed.values["T_cam_rig"])
    # A constant variable is laid out as an eliminated kind (never in the dense system), a fully fixed
    # one as a shared kind: the same optimum, summed in a different order, so the two solves stop at
    # iterates that differ inside the float64 resolution of the cost (~4e-8 relative on k2, a few 1e-6 σ):
    # compared in units of σ as the chunked layout is.
    sigma = np.sqrt(np.diag(fixed.covariance("intrinsics")))
    assert np.all(np.abs(const.values["intrinsics"][0] - fixed.values["intrinsics"][0]) < 1e-5 * sigma)
    np.testing.assert_allclose(const.covariance("intrinsics"), fixed.covariance("intrinsics"), rtol=1e-7)
    # and it is the right optimum: the rig is the identity, so the plain problem gives the same answer
    # (a different residual function: the two solves stop at different iterates, so compare in σ units)
    plain = solve(_problem(data, K0, P0, None))
    sigma = np.sqrt(np.diag(plain.covariance("intrinsics")))
    assert np.all(np.abs(const.values["intrinsics"][0] - plain.values["intrinsics"][0]) < 1e-4 * sigma)


def test_constant_variable_with_a_prior_is_refused():
    with pytest.raises(BadInputError, match="constant variable cannot have a prior"):
        Variable("T", SE3(), np.array([1.0, 0, 0, 0, 0, 0, 0]), constant=True,
                 prior_mean=np.array([1.0, 0, 0, 0, 0, 0, 0]), prior_sqrt_info=np.eye(6))


def test_solve_options_unchanged_by_chunking():
    # the chunked path is a layout choice: it must not change what the solver reports
    data, K0, P0 = _data()
    a = solve(_problem(data, K0, P0, None), options=SolveOptions(max_iterations=3))
    b = solve(_problem(data, K0, P0, POINTS_PER_VIEW), options=SolveOptions(max_iterations=3))
    assert a.iterations == b.iterations
    np.testing.assert_allclose(b.cost, a.cost, rtol=1e-10)
