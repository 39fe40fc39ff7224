"""TCP in the report: the result file of a TCP calibration, σ per flange axis and of a gripped point
in the base frame, checked against finite differences, the solver's own tip covariance and a Monte
Carlo of the thesis-like cell (benchmarks/bench_tcp_thesis.py)."""

import importlib.util
import re
import types
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

import jcalib  # noqa: F401  (float64)
from jcalib.io.result import ResultFile, TransformResult
from jcalib.problems.tcp import calibrate_tcp
from jcalib.report import render_report
from jcalib.report import tcp as T

_path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_tcp_thesis.py"
_spec = importlib.util.spec_from_file_location("_bench_tcp_thesis_report", _path)
B = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(B)

ARGS = types.SimpleNamespace(mm_per_px=0.021, repeatability_mm=0.03, repeatability_sigmas=2.0,
                             rotation_noise_deg=0.001, sigma_px=0.25, cad_error_mm=2.0)
CELL = B.Cell(ARGS)


def _trial(rng):
    """One thesis-like joint TCP calibration (12 poses, camera position free, orientation known to
    0.05°, robot pose model): the calibration and its tip error (m, flange frame)."""
    x_nom = CELL.x + rng.normal(0.0, CELL.cad_error, 3)
    T_cmd = B.joint_poses(CELL, 12, x_nom)
    px = []
    for Tc in T_cmd:
        w = rng.normal(0.0, CELL.sigma_r, 3)
        tip = Tc[:3, :3] @ B._rotvec(w) @ CELL.x + Tc[:3, 3] + rng.normal(0.0, CELL.sigma_t, 3)
        px.append(CELL.project(tip) + rng.normal(0.0, CELL.sigma_px, 2))
    s = np.deg2rad(0.05)
    T_cam0 = CELL.T_base_cam.copy()
    T_cam0[:3, 3] += np.array([0.012, -0.01, 0.012])
    T_cam0[:3, :3] = T_cam0[:3, :3] @ B._rotvec(rng.normal(0.0, s, 3))
    cal = calibrate_tcp(CELL.camera, T_cam0, T_cmd, np.stack(px), free_camera_pose=True,
                        T_base_cam_covariance=np.diag([s**2] * 3 + [np.inf] * 3)[None],
                        pose_noise_translation_m=CELL.sigma_t,
                        pose_noise_rotation_deg=float(np.rad2deg(CELL.sigma_r)), sigma_px=CELL.sigma_px)
    return cal, cal.p_flange_tip - CELL.x


@pytest.fixture(scope="module")
def cal():
    return _trial(np.random.default_rng(3))[0]


@pytest.fixture(scope="module")
def file(cal):
    return T.tcp_result_file(cal, "needle", sigma_px=CELL.sigma_px, pose_noise_translation_m=CELL.sigma_t,
                             pose_noise_rotation_deg=float(np.rad2deg(CELL.sigma_r)))


def _se3_exp(delta):
    """Exp of a right-perturbation tangent (ω, v) via the 4x4 matrix exponential (scipy)."""
    w, v = delta[:3], delta[3:]
    M = np.zeros((4, 4))
    M[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    M[:3, 3] = v
    return expm(M)


def _fd_jacobian(f, n, h=1e-6):
    """Central differences of ``f: (n,) -> (3,)`` at 0."""
    cols = []
    for k in range(n):
        e = np.zeros(n)
        e[k] = h
        cols.append((f(e) - f(-e)) / (2 * h))
    return np.stack(cols, axis=1)


@given(st.integers(0, 2**31 - 1))
def test_gripped_point_covariance_matches_finite_differences(seed):
    """First-order propagation through p_base = T_base_flange Exp(ε) T_flange_tcp Exp(δ) p, with the
    Jacobians from central differences of the exact matrix exponential (independent of the code's
    closed form); TCP and robot covariances random SPD."""
    rng = np.random.default_rng(seed)

    def pose():
        P = np.eye(4)
        P[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        P[:3, 3] = rng.uniform(-0.5, 0.5, 3)
        return P

    Tft, Tbf = pose(), pose()
    p = rng.uniform(-0.2, 0.2, 3)
    A = rng.normal(size=(6, 6)) * 1e-3
    Ct, Cr = A @ A.T + 1e-8 * np.eye(6), np.diag(rng.uniform(1e-9, 1e-7, 6))
    ph = np.append(p, 1.0)
    Jt = _fd_jacobian(lambda d: (Tbf @ Tft @ _se3_exp(d) @ ph)[:3], 6)
    Jr = _fd_jacobian(lambda d: (Tbf @ _se3_exp(d) @ Tft @ ph)[:3], 6)
    ref = Jt @ Ct @ Jt.T + Jr @ Cr @ Jr.T
    got = T.gripped_point_covariance(TransformResult(Tft, Ct), Tbf, p, Cr)
    # central differences with h = 1e-6 on O(1) functions: truncation ~1e-12, rounding ~1e-10 relative
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())


def test_result_file_carries_the_solvers_tip_covariance(cal, file, tmp_path):
    """T_flange_needle's covariance, rotated into the flange frame, is the solver's tip covariance
    (propagated by the engine through another path, sol.propagate of the tip); the file survives a
    JSON round trip; the tool tip's total σ in the base frame equals sqrt(trace) at any flange pose."""
    tr = file.transforms["T_flange_needle"]
    # two float64 computations of one covariance (engine propagate vs covariance block): 1e-9
    np.testing.assert_allclose(T.tcp_position_covariance(tr), cal.tip_covariance, rtol=1e-9,
                               atol=1e-9 * np.abs(cal.tip_covariance).max())
    np.testing.assert_allclose(T.tcp_std_mm(tr), cal.tip_std_mm, rtol=1e-9)
    # no tool axis observed: the orientation was held, its rows are zero
    assert np.all(np.asarray(tr.covariance)[:3, :] == 0.0)
    back = ResultFile.load(file.save(tmp_path / "tcp.json"))
    np.testing.assert_array_equal(back.transforms["T_flange_needle"].covariance, tr.covariance)
    assert T.is_tcp("T_flange_needle", back) and not T.is_tcp("T_base_cam0", back)
    Bf = np.asarray(back.extra[T.GRIP_REFERENCE_KEY])
    C = T.gripped_point_covariance(tr, Bf)
    np.testing.assert_allclose(np.trace(C), np.trace(cal.tip_covariance), rtol=1e-9)


def test_report_shows_tcp_sigma_in_mm(cal, file):
    """The page's TCP table shows the per-axis σ of the tip (mm, flange frame) and of the tip in the
    base frame at the reference pose, with and without the robot's repeatability."""
    html = render_report(file)
    assert "<h3>TCP</h3>" in html
    sec = html[html.index("<h3>TCP</h3>"):]
    row = re.search(r"<code>T_flange_needle</code></td>(.*?)</tr>", sec).group(1)
    cells = re.findall(r"<td[^>]*>(.*?)</td>", row)
    shown = np.array([float(x) for x in re.findall(r"[-+]?\d+\.\d+", cells[1])])
    np.testing.assert_allclose(shown, cal.tip_std_mm, atol=6e-5)  # printed to 4 decimals
    assert "not estimated" in cells[3]
    Bf = np.asarray(file.extra[T.GRIP_REFERENCE_KEY])
    base = 1e3 * np.sqrt(np.diag(Bf[:3, :3] @ cal.tip_covariance @ Bf[:3, :3].T))
    tip_row = re.search(r"<td>tool tip</td>(.*?)</tr>", sec).group(1)
    shown = np.array([float(x) for x in re.findall(r"[-+]?\d+\.\d+", re.findall(r"<td[^>]*>(.*?)</td>", tip_row)[0])])
    np.testing.assert_allclose(shown, base, atol=6e-5)
    assert "tool tip + robot repeatability" in sec
    assert "gripped point 100 mm along the tool z" in sec


def test_tcp_sigma_matches_monte_carlo():
    """Errors of 120 independent trials, normalised by the covariance the report shows, follow
    χ²(3): mean NEES within its 99.9 % band (mean of 120 χ²(3): s.d. sqrt(6/120) = 0.224, band
    3 ± 3.3 s.d.), and each axis' RMS σ over the empirical σ within the χ²(120) 99.9 % band."""
    from scipy import stats

    rng = np.random.default_rng(20261122)
    n = 120
    err, cov = [], []
    for _ in range(n):
        c, e = _trial(rng)
        f = T.tcp_result_file(c, "needle")
        err.append(e)
        cov.append(T.tcp_position_covariance(f.transforms["T_flange_needle"]))
    err, cov = np.array(err), np.array(cov)
    nees = np.einsum("ni,nij,nj->n", err, np.linalg.inv(cov), err)
    assert abs(nees.mean() - 3.0) < 3.3 * np.sqrt(6.0 / n), nees.mean()
    band = np.sqrt(stats.chi2(n).ppf([0.0005, 0.9995]) / n)
    ratio = np.sqrt(np.mean(np.diagonal(cov, axis1=1, axis2=2), axis=0)) / np.sqrt(np.mean(err**2, axis=0))
    assert np.all((ratio > 1 / band[1]) & (ratio < 1 / band[0])), ratio
