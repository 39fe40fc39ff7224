"""Information of chosen shared variables with everything else marginalised (Solution.information and
jcalib.solve.information at given values) against a dense reference."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from solve_problems import calibration_data, calibration_problem, perturbed_start, project

import jcalib  # noqa: F401
from jcalib.errors import BadInputError
from jcalib.solve import SE3, Status, information, solve

NV = 4
SIGMA = 0.3


@pytest.fixture(scope="module")
def data():
    return calibration_data(num_views=NV, noise_px=SIGMA, seed=7, cols=5, rows=4)


def _dense_marginal(data, K, P, keep_fixed=()):
    """Stated-noise information of the intrinsics with the view poses marginalised, from one dense JᵀJ."""
    m = SE3()
    vi = jnp.asarray(data["view_index"])
    obs = (jnp.asarray(data["points"]), jnp.asarray(data["uv"]))

    def r(delta):
        poses = jax.vmap(m.retract)(jnp.asarray(P), delta[6:].reshape(NV, 6))
        return jax.vmap(project, in_axes=(None, 0, 0))(jnp.asarray(K) + delta[:6], poses[vi], obs).reshape(-1) / SIGMA

    J = np.array(jax.jacfwd(r)(jnp.zeros(6 + 6 * NV)))
    J[:, list(keep_fixed)] = 0.0
    H = J.T @ J
    A, B, D = H[:6, :6], H[:6, 6:], H[6:, 6:]
    M = A - B @ np.linalg.solve(D, B.T)
    return 0.5 * (M + M.T)


def _close(M, ref):
    d = np.sqrt(np.maximum(np.diag(ref), 1e-300))
    assert np.max(np.abs(M - ref) / np.outer(d, d)) < 1e-9


@pytest.mark.parametrize("eliminate", [True, False])
def test_marginal_information_matches_dense_schur_complement(data, eliminate):
    """Poses eliminated (the solve's Schur complement) or shared (marginalised on the host): the intrinsics'
    information equals the dense Schur complement, linearised by the solve or at given values; its inverse
    is the solve's covariance."""
    K0, P0 = perturbed_start(data, np.random.default_rng(8))
    problem = calibration_problem(data, K0, P0, noise_px=SIGMA, eliminate=eliminate)
    sol = solve(problem)
    assert sol.status == Status.CONVERGED
    ref = _dense_marginal(data, sol.values["intrinsics"][0], sol.values["T_cam_target"])
    _close(sol.information(["intrinsics"], noise="stated"), ref)
    _close(sol.information(["intrinsics"]) * sol.sigma2, ref)
    _close(information(problem, ["intrinsics"], x0=sol.values), ref)
    C = sol.joint_covariance(["intrinsics"], noise="stated")
    _close(np.linalg.inv(C), ref)
    # at other values: the linearisation there, not the solve's
    K1 = sol.values["intrinsics"] * np.array([1.01, 0.99, 1.0, 1.0, 1.0, 1.0])
    _close(information(problem, ["intrinsics"], x0={"intrinsics": K1, "T_cam_target": sol.values["T_cam_target"]}),
           _dense_marginal(data, K1[0], sol.values["T_cam_target"]))


def test_fixed_coordinates_have_no_information_and_names_are_checked(data):
    K0, P0 = perturbed_start(data, np.random.default_rng(9))
    fixed = np.array([False, False, False, False, True, True])  # k1, k2 held
    sol = solve(calibration_problem(data, K0, P0, noise_px=SIGMA, K_fixed=fixed))
    M = sol.information(["intrinsics"], noise="stated")
    assert np.all(M[4:, :] == 0.0) and np.all(M[:, 4:] == 0.0)
    ref = _dense_marginal(data, sol.values["intrinsics"][0], sol.values["T_cam_target"], keep_fixed=(4, 5))
    _close(M[:4, :4], ref[:4, :4])
    with pytest.raises(BadInputError, match="T_cam_target"):
        sol.information(["T_cam_target"])  # eliminated: not a shared variable
