"""Programs jcalib did not write, against jcalib's simulators, in a private network namespace only.

Aravis' own command-line tools read and write the fake GigE camera's features (``arv-tool-0.8 -a
127.0.0.1``) and grab from it (``arv-camera-test-0.8``); the PyPI KUKAVARPROXY client ``py_openshowvar``
reads, writes and moves the simulated KUKA controller of ``jcalib simulate``; the PyPI client ``ur_rtde``
(``rtde_receive.RTDEReceiveInterface``, Universal Robots' RTDE protocol) reads the pose and joints of the
simulated UR5e. The same run lists the simulator's sockets (``ss -lunpt``: all on 127.0.0.1) and sends 10,000
random packets to each of its ports, after which jcalib's clients, Aravis' tool and ur_rtde are still served
(KUKA, ABB and UR simulators).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).parent


@pytest.fixture(scope="module")
def report(aravis, tmp_path_factory):
    missing = [t for t in ("unshare", "ip", "ss", "arv-tool-0.8", "arv-camera-test-0.8") if shutil.which(t) is None]
    problem = f"needs {', '.join(missing)} (scripts/apt-packages.txt)" if missing else None
    if problem is None and subprocess.run(["unshare", "-n", "true"], capture_output=True).returncode != 0:
        problem = "cannot create a network namespace here (needs CAP_SYS_ADMIN)"
    pytest.importorskip("py_openshowvar", reason="pip install py-openshowvar (the dev extra)")
    pytest.importorskip("rtde_receive", reason="pip install ur-rtde (the dev extra)")
    if problem:
        if os.environ.get("CI") or os.geteuid() == 0:
            pytest.fail(f"{problem}; CI runs as root with scripts/setup's packages, so this is a setup failure",
                        pytrace=False)  # fmt: skip
        pytest.skip(problem)
    out = tmp_path_factory.mktemp("interop")
    env = {**os.environ, "PYTHONPATH": str(HERE.parents[1]), "JCALIB_CACHE_DIR": str(out / "jax")}
    cmd = f'ip link set lo up && exec {sys.executable} {HERE / "_interop_worker.py"} {out}'
    proc = subprocess.run(["unshare", "-n", "sh", "-c", cmd], capture_output=True, text=True, timeout=400, env=env)
    assert "INTEROP-DONE" in proc.stdout, proc.stdout[-3000:] + proc.stderr[-3000:]
    return json.loads((out / "report.json").read_text())


def test_every_socket_of_the_simulator_is_on_loopback(report):
    for key in ("kuka_sockets", "abb_sockets", "ur_sockets"):
        sockets = report[key]
        assert {p for p, _, _ in sockets} == {"udp", "tcp"}
        assert all(addr == "127.0.0.1" for _, addr, _ in sockets), sockets
        assert ["udp", "127.0.0.1", 3956] in sockets
    # UR's ports are fixed: RTDE and the secondary interface (URScript), as on a controller
    assert ["tcp", "127.0.0.1", 30004] in report["ur_sockets"] and ["tcp", "127.0.0.1", 30002] in report["ur_sockets"]
    assert report["ur_url"] == "ur://127.0.0.1"


def test_aravis_tools_read_write_and_grab_from_the_fake_camera(report):
    code, text = report["arv_read"]
    assert code == 0 and "Width = 320" in text and "Height = 240" in text and "PixelFormat = Mono8" in text
    code, text = report["arv_write"]
    assert code == 0 and "ExposureTimeAbs = 2500" in text and "GainRaw = 2" in text
    assert report["kuka_before"]["exposure_us"] == 2500.0  # what arv-tool wrote, read back by jcalib's client
    assert report["arv_features"] == 0
    code, text = report["arv_grab"]
    completed = int(re.search(r"n_completed_buffers\s*=\s*(\d+)", text).group(1))
    failures = int(re.search(r"n_failures\s*=\s*(\d+)", text).group(1))
    assert code == 0 and completed >= 10 and failures == 0, text[-1500:]


def test_pypi_kukavarproxy_client_reads_writes_and_moves(report):
    r = report["openshowvar"]
    assert r["pos_act"].startswith("{E6POS: X ") and r["unknown"] is None
    assert r["vel_write"] == "30" and r["vel_read"] == "30"
    assert r["nan_write"] is None  # a failed write, as KUKAVARPROXY reports it
    assert r["pos_write"] and r["err"] == "0"
    dx, dy, dz = r["moved_mm"]
    assert abs(dx - 10.0) < 0.1 and abs(dy) < 0.1 and abs(dz) < 0.1  # repeatability noise: 13 um


def _ur5e_flange(q) -> np.ndarray:
    """Flange pose of a UR5e at joints ``q`` (rad) from UR's published DH table, written out here (not jcalib's)."""
    a, d = [0.0, -0.425, -0.3922, 0.0, 0.0, 0.0], [0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996]
    alpha = [np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0]
    T = np.eye(4)
    for i in range(6):
        ct, st, ca, sa = np.cos(q[i]), np.sin(q[i]), np.cos(alpha[i]), np.sin(alpha[i])
        T = T @ np.array([[ct, -st * ca, st * sa, a[i] * ct], [st, ct * ca, -ct * sa, a[i] * st], [0, sa, ca, d[i]],
                          [0, 0, 0, 1.0]])
    return T


def _rotvec_matrix(r) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(r, dtype=np.float64))[0]


@pytest.mark.parametrize("key", ["ur_rtde_before", "ur_rtde_moved", "ur_rtde_after"])
def test_pypi_ur_rtde_reads_the_simulators_pose_and_joints(report, key):
    r = report[key]
    assert r["connected"] and not r["protective_stop"]
    assert (r["robot_mode"], r["safety_mode"], r["runtime_state"]) == (7, 1, 1)  # RUNNING, NORMAL, STOPPED
    pose, q = np.array(r["pose"]), np.array(r["q"])
    # the same pose and joints as jcalib's driver reads (the arm stands; the TCP is the flange)
    T = np.array(r["jcalib_T_base_flange"])
    assert np.linalg.norm(pose[:3] - T[:3, 3]) < 1e-9 and np.abs(_rotvec_matrix(pose[3:]) - T[:3, :3]).max() < 1e-9
    assert np.abs(np.degrees(q) - np.array(r["jcalib_joints_deg"])).max() < 1e-7
    # and the pose is the UR5e's at those joints (UR's DH table: actual_TCP_pose is the forward kinematics)
    F = _ur5e_flange(q)
    assert np.linalg.norm(F[:3, 3] - pose[:3]) < 1e-9 and np.abs(F[:3, :3] - _rotvec_matrix(pose[3:])).max() < 1e-9


def test_ur_rtde_sees_the_move_jcalib_commanded(report):
    before, moved = np.array(report["ur_rtde_before"]["pose"]), np.array(report["ur_rtde_moved"]["pose"])
    assert abs(moved[0] - before[0] - 0.010) < 1e-4 and np.abs(moved[1:3] - before[1:3]).max() < 1e-4
    assert report["ur_before"]["move_error_mm"] < 0.1


@pytest.mark.parametrize("protocol", ["kuka", "abb", "ur"])
def test_10000_random_packets_per_port_and_the_simulator_keeps_serving(report, protocol):
    assert report[f"{protocol}_alive"] and report[f"{protocol}_exit"] == 0
    flood = report[f"{protocol}_flood"]
    assert len(flood) == len(report[f"{protocol}_sockets"]) and min(flood.values()) >= 10_000
    after = report[f"{protocol}_after"]
    assert after["move_error_mm"] < 0.1 and after["image_shape"] == [240, 320]
    if protocol == "kuka":
        assert report["arv_after"][0] == 0 and "Width = 320" in report["arv_after"][1]
