"""Strategy studies (``jcalib.study``): scenario validation, estimators against independent
references (ground truth, OpenCV), and the same table on the local and the Dask backend."""

from __future__ import annotations

import csv
import math

import cv2
import numpy as np
import pytest

from jcalib.errors import BadInputError
from jcalib.study import columns, load_scenario, run_study, simulate_trial, trial_rng
from jcalib.study.simulate import camera_model

CLOSED = ["tsai_lenz", "park_martin", "horaud", "andreff", "daniilidis"]
#: Hand-eye scenario of the backend test: 6 stations, every corner visible (one solver shape).
HANDEYE = {
    "schema": "jcalib.study/1",
    "cell": "handeye",
    "noise": {"pixel_sigma_px": 0.2, "robot_translation_m": 1e-4, "robot_rotation_deg": 0.01, "dropout_rate": 0.0},
    "stations": {"strategy": "random", "count": 6},
    "estimators": ["park_martin", "tsai_lenz", "joint_pose_model"],
}


def _rows(table):
    return table.to_dict("records") if hasattr(table, "to_dict") else list(table)


def _same(a, b) -> bool:
    """Exact equality, NaN equal to NaN."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def _assert_tables_equal(t1, t2, exclude=("runtime_s",)):
    r1, r2 = _rows(t1), _rows(t2)
    assert len(r1) == len(r2)
    for x, y in zip(r1, r2):
        assert x.keys() == y.keys()
        bad = {k: (x[k], y[k]) for k in x if k not in exclude and not _same(x[k], y[k])}
        assert not bad, (x["trial"], x["estimator"], bad)


# ------------------------------------------------------------------------------------ validation


@pytest.mark.parametrize(
    "patch, key",
    [
        ({"noise": {"pixl_sigma_px": 0.2}}, "scenario.noise.pixl_sigma_px"),
        ({"noise": {"pixel_sigma_px": -1.0}}, "scenario.noise.pixel_sigma_px"),
        ({"noise": {"dropout_rate": 1.0}}, "scenario.noise.dropout_rate"),
        ({"stations": {"strategy": "spiral"}}, "scenario.stations.strategy"),
        ({"stations": {"strategy": "random", "count": 2}}, "scenario.stations.count"),
        ({"stations": {"strategy": "random", "distance_m": 0.4}}, "scenario.stations.distance_m"),
        ({"estimators": ["park_martin", "zhang"]}, "scenario.estimators[1]"),
        ({"cell": "stereo"}, "scenario.cell"),
        ({"colour": "red"}, "scenario.colour"),
        ({"camera": {"params": [1400.0, 1400.0]}}, "scenario.camera.params"),
    ],
)
def test_validation_error_names_the_bad_key(patch, key):
    bad = {**HANDEYE, **patch}
    with pytest.raises(BadInputError) as err:
        load_scenario(bad)
    assert str(err.value).startswith(key + ":"), str(err.value)


def test_validation_from_yaml_file(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("cell: tcp\nstations: {strategy: tcp_three_pose, alpha_deg: 0}\n")
    with pytest.raises(BadInputError, match=r"^scenario\.stations\.alpha_deg: got 0"):
        load_scenario(path)


def test_three_pose_needs_its_strategy():
    with pytest.raises(BadInputError, match="three_pose"):
        load_scenario({"cell": "tcp", "stations": {"strategy": "random", "count": 5}, "estimators": ["three_pose"]})


def test_bad_run_arguments():
    with pytest.raises(BadInputError, match="^trials"):
        run_study(HANDEYE, 0, progress=False)
    with pytest.raises(BadInputError, match="^backend"):
        run_study(HANDEYE, 1, backend="ray", progress=False)


# ------------------------------------------------------------------------------------ seeding


def test_trial_rng_is_the_spawned_child():
    """Trial i's generator is SeedSequence(seed).spawn(n)[i] (numpy's documented derivation)."""
    children = np.random.SeedSequence(7).spawn(5)
    for i, child in enumerate(children):
        np.testing.assert_array_equal(trial_rng(7, i).random(4), np.random.default_rng(child).random(4))


# ------------------------------------------------------------------------------------ estimators vs references


def test_noise_free_closed_forms_recover_the_truth():
    """No pixel, robot noise or dropout: every closed form recovers T_flange_cam (PnP is exact up to
    its solver tolerance: 1e-6 deg / 1e-6 mm is parameter recovery from noiseless data)."""
    sc = {**HANDEYE, "noise": {"pixel_sigma_px": 0.0, "robot_translation_m": 0.0, "robot_rotation_deg": 0.0},
          "estimators": CLOSED}
    rows = _rows(run_study(sc, 2, seed=3, progress=False))
    assert [r["estimator"] for r in rows] == CLOSED * 2
    for r in rows:
        assert r["status"] == "ok", r
        assert r["err_rot_deg"] < 1e-6 and r["err_trans_mm"] < 1e-6, r
        assert math.isnan(r["sigma_tx_mm"])  # closed forms report no σ


@pytest.mark.parametrize("strategy", ["robocalib_handeye", "robocalib_viewsets"])
def test_park_martin_matches_opencv_on_the_simulated_trial(strategy):
    """The study's closed-form row equals cv2.calibrateHandEye (PARK) on the same simulated data,
    computed here independently (cv2.solvePnP with the true intrinsics, cv2.calibrateHandEye):
    jcalib's closed forms agree with OpenCV to ~1e-13, so 1e-9 mm / deg."""
    sc = load_scenario({**HANDEYE, "stations": {"strategy": strategy}, "estimators": ["park_martin"]})
    (row,) = _rows(run_study(sc, 1, seed=11, progress=False))
    d = simulate_trial(sc, 11, 0)
    K, dist = (np.asarray(a) for a in camera_model(sc).to_opencv())
    Rs, ts = [], []
    for idx, pix in zip(d.point_index, d.pixels):
        ok, r, t = cv2.solvePnP(d.points[idx], pix, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
        assert ok
        Rs.append(cv2.Rodrigues(r)[0])
        ts.append(t.ravel())
    R, t = cv2.calibrateHandEye(list(d.T_base_flange[:, :3, :3]), list(d.T_base_flange[:, :3, 3]), Rs, ts,
                                method=cv2.CALIB_HAND_EYE_PARK)
    X = d.T_flange_cam
    err_t = 1e3 * np.linalg.norm(t.ravel() - X[:3, 3])
    err_r = np.degrees(np.linalg.norm(cv2.Rodrigues(R.T @ X[:3, :3])[0]))
    assert row["status"] == "ok" and row["num_stations"] == len(d.pixels) >= 5
    assert abs(row["err_trans_mm"] - err_t) < 1e-9
    assert abs(row["err_rot_deg"] - err_r) < 1e-9


@pytest.mark.parametrize("strategy, estimators", [("tcp_three_pose", ["three_pose", "ray_lsq"]),
                                                  ("random", ["ray_lsq"])])
def test_tcp_noise_free_recovers_the_tip(strategy, estimators):
    """Noise-free TCP trials: the analytic methods recover the simulated tip (1e-9 mm: float64 closed forms)."""
    stations = {"strategy": strategy} if strategy == "tcp_three_pose" else {"strategy": strategy, "count": 5}
    sc = {"cell": "tcp", "stations": stations, "estimators": estimators,
          "noise": {"pixel_sigma_px": 0.0, "robot_translation_m": 0.0, "robot_rotation_deg": 0.0}}
    for r in _rows(run_study(sc, 3, seed=5, progress=False)):
        assert r["status"] == "ok", r
        assert r["err_norm_mm"] < 1e-9, r


def test_tcp_reported_sigma_covers_the_errors():
    """With noise, the TCP errors are of the order of the reported σ (NEES is χ²(3): mean 3; the
    servo residual is taken isotropic, so the σ is conservative: mean NEES in [0.5, 6] over 40 trials)."""
    sc = {"cell": "tcp", "stations": {"strategy": "tcp_three_pose"}, "estimators": ["three_pose"]}
    nees = [r["nees"] for r in _rows(run_study(sc, 40, seed=2, progress=False))]
    assert 0.5 < np.mean(nees) < 6.0, np.mean(nees)


# ------------------------------------------------------------------------------------ tables and backends


def test_batching_does_not_change_the_table(tmp_path):
    """Trials draw from (seed, trial) only: batch sizes 1 and 4 give the same rows; the CSV holds them exactly."""
    sc = {**HANDEYE, "noise": {**HANDEYE["noise"], "dropout_rate": 0.3}, "estimators": CLOSED}
    a = run_study(sc, 5, seed=9, batch_size=1, progress=False)
    b = run_study(sc, 5, seed=9, batch_size=4, out=tmp_path / "t.csv", progress=False)
    _assert_tables_equal(a, b)
    rows = _rows(b)
    assert len({r["num_stations"] for r in rows}) > 1  # dropouts happened
    with open(tmp_path / "t.csv", newline="") as fh:
        back = list(csv.DictReader(fh))
    assert list(back[0]) == columns(load_scenario(sc))
    for r, s in zip(rows, back):
        assert s["estimator"] == r["estimator"] and int(s["trial"]) == r["trial"]
        assert float(s["err_trans_mm"]) == r["err_trans_mm"]  # repr round-trips float64 exactly
        assert s["sigma_tx_mm"] == ""  # NaN written as an empty cell


@pytest.fixture(scope="module")
def worker_env(tmp_path_factory):
    """Workers see the test process's JAX settings and share a persistent compilation cache with it
    (so each worker loads the hand-eye solve the local run compiled instead of compiling it again)."""
    import jax

    mp = pytest.MonkeyPatch()
    cache = tmp_path_factory.mktemp("jax_cache")
    mp.setenv("JCALIB_CACHE_DIR", str(cache))
    mp.setenv("JAX_ENABLE_X64", "1")
    mp.setenv("JAX_NUMPY_DTYPE_PROMOTION", "strict")
    mp.setenv("JAX_NUMPY_RANK_PROMOTION", "raise")
    old = jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    yield cache
    jax.config.update("jax_compilation_cache_dir", old[0])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", old[1])
    mp.undo()


def _dask_study(study, trials, seed, batch_size):
    pytest.importorskip("dask.distributed")
    local = run_study(study, trials, seed=seed, batch_size=batch_size, progress=False)
    dask = run_study(study, trials, seed=seed, backend="dask", batch_size=batch_size, progress=False)
    rows = _rows(local)
    assert [(r["trial"], r["estimator"]) for r in rows] == [(k, e) for k in range(trials) for e in study["estimators"]]
    _assert_tables_equal(local, dask)
    return rows


def test_local_and_dask_give_identical_tables(worker_env):
    """The acceptance test: the same study with the same seed gives the same table on the local
    backend and on a 2-worker Dask LocalCluster on 127.0.0.1 (exact equality, runtime excluded).
    Closed forms with dropouts (trials of different sizes, batches of 2 over 2 workers)."""
    study = {**HANDEYE, "noise": {**HANDEYE["noise"], "dropout_rate": 0.2}, "estimators": CLOSED}
    rows = _dask_study(study, 6, 42, 2)
    assert sum(r["status"] == "ok" for r in rows) >= 20


@pytest.mark.slow
def test_local_and_dask_give_identical_tables_with_the_joint_solve(worker_env):
    """As above with the joint solve (robot pose model): the compiled LM gives bit-identical results
    in the workers. Slow (~60-80 s on 2 busy cores): each worker traces the solve once."""
    rows = _dask_study(HANDEYE, 6, 42, 2)
    assert all(r["status"] == "ok" for r in rows), [r["status"] for r in rows]
    assert all(r["nees"] > 0 for r in rows if r["estimator"] == "joint_pose_model")


# ------------------------------------------------------------------------------------ file strategy and CLI


def test_file_strategy_reads_poses_relative_to_the_scenario(tmp_path):
    """``stations: {strategy: file, path: poses.yaml}`` is read from the scenario's folder; the
    stations are exactly those poses (the trial's camera poses in the target frame)."""
    import yaml

    from jcalib.geometry.views import frontal_view, recentre, rotate_camera

    centre = np.array([0.1, 0.0625, 0.0])  # the 9x6 board's centre (25 mm squares)
    T0 = frontal_view(centre, 0.5)
    poses = [T0] + [recentre(rotate_camera(T0, ax, np.radians(a)), centre, 0.5)
                    for ax, a in (("Z", 60), ("Y", 25), ("X", -25), ("Y", -20), ("X", 20))]
    (tmp_path / "poses.yaml").write_text(yaml.safe_dump({"T_target_cam": [p.tolist() for p in poses]}))
    scenario = {**HANDEYE, "stations": {"strategy": "file", "path": "poses.yaml"}, "estimators": ["daniilidis"]}
    (tmp_path / "study.yaml").write_text(yaml.safe_dump(scenario))
    sc = load_scenario(tmp_path / "study.yaml")
    np.testing.assert_array_equal(sc.stations.T_target_cam, np.array(poses))
    np.testing.assert_array_equal(load_scenario(sc.to_dict()).stations.T_target_cam, sc.stations.T_target_cam)
    (row,) = _rows(run_study(tmp_path / "study.yaml", 1, seed=1, progress=False))
    assert row["status"] == "ok" and row["num_stations"] == 6
    assert row["err_trans_mm"] < 5.0  # 0.2 px, 0.1 mm robot noise: millimetre level, not a wrong solution


def test_study_command_writes_the_table(tmp_path, monkeypatch):
    """The CLI body, registered on a typer app as the lead will: exit 0, a CSV with one row per
    trial × estimator."""
    import typer
    from typer.testing import CliRunner

    import jcalib.solve.cache
    from jcalib.app.study import study_command

    monkeypatch.setattr(jcalib.solve.cache, "enable_compilation_cache", lambda: None)
    app = typer.Typer()
    app.command("study")(study_command)
    app.command("other")(lambda: None)  # two commands: typer keeps the subcommand name
    (tmp_path / "tcp.yaml").write_text("cell: tcp\nstations: {strategy: tcp_three_pose}\n")
    out = tmp_path / "t.csv"
    res = CliRunner().invoke(app, ["study", str(tmp_path / "tcp.yaml"), "--trials", "3", "-o", str(out),
                                   "--seed", "4"])
    assert res.exit_code == 0, res.output
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["trial"], r["estimator"]) for r in rows] == [(str(k), e) for k in range(3)
                                                            for e in ("three_pose", "ray_lsq")]
