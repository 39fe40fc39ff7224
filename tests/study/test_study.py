"""Strategy studies (``jcalib.study``): scenario validation (both forms), estimators against independent
references (ground truth, OpenCV), and the same table on the local and the Dask backend."""

from __future__ import annotations

import csv
import math

import cv2
import numpy as np
import pytest

from jcalib.errors import BadInputError
from jcalib.study import columns, load_scenario, run_study, simulate_trial, trial_rng

CLOSED = ["tsai_lenz", "park_martin", "horaud", "andreff", "daniilidis"]
X = "T_flange_cam0"
#: Hand-eye scenario of the backend test (first form): 6 stations, every corner visible (one solver shape).
HANDEYE = {
    "schema": "jcalib.study/1",
    "cell": "handeye",
    "noise": {"pixel_sigma_px": 0.2, "robot_translation_m": 1e-4, "robot_rotation_deg": 0.01, "dropout_rate": 0.0},
    "stations": {"strategy": "random", "count": 6},
    "estimators": ["park_martin", "tsai_lenz", "joint_pose_model"],
}
BOARD = {"type": "checkerboard", "cols": 9, "rows": 6, "square": 0.025}
KNOWN = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]
#: The same study in the cell-spec form.
HANDEYE_CELL = {
    "schema": "jcalib.study/1",
    "cell": {"cameras": {"cam0": {"model": "opencv5", "mount": "flange", "fix": KNOWN}},
             "targets": {"board": {**BOARD, "mount": "base"}},
             "robot": {"pose_noise": {"translation_m": 1e-4, "rotation_deg": 0.01}}},
    "stations": {"strategy": "random", "camera": "cam0", "target": "board", "count": 6},
    "estimators": ["park_martin"],
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
def test_first_form_validation_names_the_bad_key(patch, key):
    with pytest.raises(BadInputError) as err:
        load_scenario({**HANDEYE, **patch})
    assert str(err.value).startswith(key + ":"), str(err.value)


@pytest.mark.parametrize(
    "patch, key",
    [
        ({"stations": [{"strategy": "random", "count": 5}, {"strategy": "random", "count": 2}]},
         "scenario.stations[1].count"),
        ({"stations": {"strategy": "random", "target": "plate"}}, "scenario.stations.target"),
        ({"stations": {"strategy": "tcp_spread"}}, "scenario.stations.tool"),
        ({"stations": {"strategy": "random", "measure": "depth"}}, "scenario.stations.measure"),
        ({"estimators": [{"name": "j", "options": {"sigma_pix": 1.0}}]}, "scenario.estimators[0].options"),
        ({"estimators": [{"name": "j", "closed_form": "zhang"}]}, "scenario.estimators[0].closed_form"),
        ({"estimators": ["park_martin", {"name": "park_martin", "options": {}}]}, "scenario.estimators"),
        ({"truth": {"poses": {"cam9": np.eye(4).tolist()}}}, "scenario.truth.poses.cam9"),
        ({"truth": {"poses": {"board": {"rotation_deg": 200.0}}}}, "scenario.truth.poses.board.rotation_deg"),
        ({"truth": {"cameras": {"cam0": {"params": [1.0, 2.0]}}}}, "scenario.truth.cameras.cam0.params"),
        ({"given": ["cam7"]}, "scenario.given[0]"),
        ({"intrinsics": "known"}, "scenario.intrinsics"),
    ],
)
def test_cell_form_validation_names_the_bad_key(patch, key):
    with pytest.raises(BadInputError) as err:
        load_scenario({**HANDEYE_CELL, **patch})
    assert str(err.value).startswith(key + ":"), str(err.value)


def test_first_form_key_with_a_cell_says_how_to_write_it():
    with pytest.raises(BadInputError, match=r"^scenario\.camera: .*truth\.cameras"):
        load_scenario({**HANDEYE_CELL, "camera": {"model": "opencv5"}})


def test_validation_from_yaml_file(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("cell: tcp\nstations: {strategy: tcp_three_pose, alpha_deg: 0}\n")
    with pytest.raises(BadInputError, match=r"^scenario\.stations\.alpha_deg: got 0"):
        load_scenario(path)


def test_cell_spec_errors_name_the_cell_file(tmp_path):
    (tmp_path / "cell.yaml").write_text("schema: jcalib.cell/1\ncameras: {cam0: {model: opencv99}}\n")
    (tmp_path / "s.yaml").write_text("cell: cell.yaml\n")
    with pytest.raises(BadInputError, match=r"cell\.yaml: cameras\.cam0"):
        load_scenario(tmp_path / "s.yaml")


def test_three_pose_needs_its_strategy():
    with pytest.raises(BadInputError, match="three_pose"):
        load_scenario({"cell": "tcp", "stations": {"strategy": "random", "count": 5}, "estimators": ["three_pose"]})


def test_first_form_is_the_cell_form_it_converts_to():
    """The first form is read as a cell spec + truth + blocks; its plain data reloads to the same
    scenario and the same trial (the truth draws, stations and noise do not depend on the form)."""
    old = load_scenario(HANDEYE)
    new = load_scenario(old.to_dict())
    assert old.to_dict() == new.to_dict()
    assert old.cell_spec.cameras["cam0"].mount == "flange" and old.cell_spec.targets["board"].mount == "base"
    assert [e.name for e in old.estimators] == HANDEYE["estimators"]
    a, b = simulate_trial(old, 4, 1), simulate_trial(new, 4, 1)
    assert a.observations.to_dict() == b.observations.to_dict()
    np.testing.assert_array_equal(a.truth.poses["cam0"], b.truth.poses["cam0"])


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
        assert r[f"err_{X}_rot_deg"] < 1e-6 and r[f"err_{X}_trans_mm"] < 1e-6, r
        assert r["err_T_base_board_trans_mm"] < 1e-6, r
        assert math.isnan(r[f"sigma_{X}_tx_mm"])  # closed forms report no σ


@pytest.mark.parametrize("strategy", ["robocalib_handeye", "robocalib_viewsets"])
def test_park_martin_matches_opencv_on_the_simulated_trial(strategy):
    """The study's closed-form row equals cv2.calibrateHandEye (PARK) on the same simulated data,
    computed here independently (cv2.solvePnP with the true intrinsics, cv2.calibrateHandEye):
    jcalib's closed forms agree with OpenCV to ~1e-13, so 1e-9 mm / deg."""
    sc = load_scenario({**HANDEYE, "stations": {"strategy": strategy}, "estimators": ["park_martin"]})
    (row,) = _rows(run_study(sc, 1, seed=11, progress=False))
    d = simulate_trial(sc, 11, 0)
    K, dist = (np.asarray(a) for a in d.truth.cameras["cam0"].to_opencv())
    points = d.observations.targets["board"]
    Rs, ts, T_bf = [], [], []
    for s in d.observations.stations:
        (det,) = s.detections
        ok, r, t = cv2.solvePnP(points[det.point_index], det.pixels, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
        assert ok
        Rs.append(cv2.Rodrigues(r)[0])
        ts.append(t.ravel())
        T_bf.append(s.T_base_flange)
    T_bf = np.array(T_bf)
    R, t = cv2.calibrateHandEye(list(T_bf[:, :3, :3]), list(T_bf[:, :3, 3]), Rs, ts, method=cv2.CALIB_HAND_EYE_PARK)
    T = d.truth.poses["cam0"]
    err_t = 1e3 * np.linalg.norm(t.ravel() - T[:3, 3])
    err_r = np.degrees(np.linalg.norm(cv2.Rodrigues(R.T @ T[:3, :3])[0]))
    assert row["status"] == "ok" and row["num_stations"] == len(T_bf) >= 5
    assert abs(row[f"err_{X}_trans_mm"] - err_t) < 1e-9
    assert abs(row[f"err_{X}_rot_deg"] - err_r) < 1e-9


@pytest.mark.parametrize("strategy, estimators", [("tcp_three_pose", ["three_pose", "ray_lsq"]),
                                                  ("random", ["ray_lsq"])])
def test_tcp_noise_free_recovers_the_tip(strategy, estimators):
    """Noise-free TCP trials: the analytic methods recover the simulated tip (1e-9 mm: float64 closed forms)."""
    stations = {"strategy": strategy} if strategy == "tcp_three_pose" else {"strategy": strategy, "count": 5}
    sc = {"cell": "tcp", "stations": stations, "estimators": estimators,
          "noise": {"pixel_sigma_px": 0.0, "robot_translation_m": 0.0, "robot_rotation_deg": 0.0}}
    for r in _rows(run_study(sc, 3, seed=5, progress=False)):
        assert r["status"] == "ok", r
        assert r["err_T_flange_tool_trans_mm"] < 1e-9, r
        assert math.isnan(r["err_T_flange_tool_rot_deg"])  # the closed forms do not estimate a rotation


def test_tcp_reported_sigma_covers_the_errors():
    """With noise, the TCP errors are of the order of the reported σ (NEES is χ²(3): mean 3; the
    servo residual is taken isotropic, so the σ is conservative: mean NEES in [0.5, 6] over 40 trials)."""
    sc = {"cell": "tcp", "stations": {"strategy": "tcp_three_pose"}, "estimators": ["three_pose"]}
    nees = [r["nees_T_flange_tool"] for r in _rows(run_study(sc, 40, seed=2, progress=False))]
    assert 0.5 < np.mean(nees) < 6.0, np.mean(nees)


def test_opencv_estimator_equals_cv2_on_the_same_corners():
    """The ``opencv`` camera estimator is cv2.calibrateCameraExtended on the trial's corners (run here
    independently: the same numbers to 1e-9 relative). OpenCV runs on one thread in both: its threaded
    reductions are not reproducible from call to call, and 6 views leave k3 weak enough that the
    difference reached 2e-6 relative."""
    sc = load_scenario({"cell": "camera", "stations": {"strategy": "random", "count": 6}, "estimators": ["opencv"]})
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        _opencv_estimator_equals_cv2(sc)
    finally:
        cv2.setNumThreads(threads)


def _opencv_estimator_equals_cv2(sc):
    (row,) = _rows(run_study(sc, 1, seed=8, progress=False))
    d = simulate_trial(sc, 8, 0)
    P = d.observations.targets["board"]
    obj = [P[det.point_index].astype(np.float32) for s in d.observations.stations for det in s.detections]
    img = [det.pixels.astype(np.float32) for s in d.observations.stations for det in s.detections]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, *_ = cv2.calibrateCameraExtended(obj, img, (1600, 1200), None, None, criteria=crit)
    truth = np.asarray(d.truth.cameras["cam0"].params)
    assert row["status"] == "ok" and row["rms_px"] == pytest.approx(rms, rel=1e-9)
    assert row["err_cam0_fx_px"] + truth[0] == pytest.approx(K[0, 0], rel=1e-9)
    assert row["err_cam0_k3"] + truth[8] == pytest.approx(dist.ravel()[4], rel=1e-9, abs=1e-12)


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
        assert float(s[f"err_{X}_trans_mm"]) == r[f"err_{X}_trans_mm"]  # repr round-trips float64 exactly
        assert s[f"sigma_{X}_tx_mm"] == ""  # NaN written as an empty cell


@pytest.fixture(scope="module")
def worker_env(tmp_path_factory):
    """Workers see the test process's JAX settings and share a persistent compilation cache with it
    (so each worker loads the solve the local run compiled instead of compiling it again)."""
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
    """As above with the joint solve (robot pose model, through calibrate_batch): the compiled solve gives
    bit-identical results in the workers. Slow: each worker loads or traces the solve once."""
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
    np.testing.assert_array_equal(sc.stations[0].T_target_cam, np.array(poses))
    np.testing.assert_array_equal(load_scenario(sc.to_dict()).stations[0].T_target_cam, sc.stations[0].T_target_cam)
    (row,) = _rows(run_study(tmp_path / "study.yaml", 1, seed=1, progress=False))
    assert row["status"] == "ok" and row["num_stations"] == 6
    assert row[f"err_{X}_trans_mm"] < 5.0  # 0.2 px, 0.1 mm robot noise: millimetre level, not a wrong solution
    d = simulate_trial(sc, 1, 0)  # the camera poses relative to the board are exactly the file's
    T_bt, X_true = d.truth.poses["board"], d.truth.poses["cam0"]
    for s, T_tc in zip(d.stations, poses):
        np.testing.assert_allclose(np.linalg.inv(T_bt) @ s.flange["robot"] @ X_true, T_tc, atol=1e-12)


def test_study_command_writes_the_table(tmp_path, monkeypatch):
    """The CLI body, registered on a typer app as the CLI does: exit 0, a CSV with one row per
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


def test_jcalib_study_bad_scenario_exits_2_naming_the_key(tmp_path, monkeypatch, capsys):
    """``jcalib study`` on a scenario with a mistyped key: exit 2, the key in the message, no traceback."""
    import sys

    from jcalib.app import cli

    (tmp_path / "s.yaml").write_text("cell: handeye\nnoise: {pixl_sigma_px: 0.2}\n")
    monkeypatch.setattr(sys, "argv", ["jcalib", "study", str(tmp_path / "s.yaml"), "-n", "1", "-o",
                                      str(tmp_path / "t.csv")])
    import jcalib.solve.cache

    monkeypatch.setattr(jcalib.solve.cache, "enable_compilation_cache", lambda: None)
    with pytest.raises(SystemExit) as exit_:
        cli.main()
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "scenario.noise.pixl_sigma_px" in err and "Traceback" not in err
