"""Programs jcalib did not write, against jcalib's simulators, in a private network namespace only.

Aravis' own command-line tools read and write the fake GigE camera's features (``arv-tool-0.8 -a
127.0.0.1``) and grab from it (``arv-camera-test-0.8``); the PyPI KUKAVARPROXY client ``py_openshowvar``
reads, writes and moves the simulated KUKA controller of ``jcalib simulate``. The same run lists the
simulator's sockets (``ss -lunpt``: all on 127.0.0.1) and sends 10,000 random packets to each of its
ports, after which jcalib's clients and Aravis' tool are still served (KUKA and ABB simulators).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).parent


@pytest.fixture(scope="module")
def report(aravis, tmp_path_factory):
    missing = [t for t in ("unshare", "ip", "ss", "arv-tool-0.8", "arv-camera-test-0.8") if shutil.which(t) is None]
    problem = f"needs {', '.join(missing)} (scripts/apt-packages.txt)" if missing else None
    if problem is None and subprocess.run(["unshare", "-n", "true"], capture_output=True).returncode != 0:
        problem = "cannot create a network namespace here (needs CAP_SYS_ADMIN)"
    pytest.importorskip("py_openshowvar", reason="pip install py-openshowvar (the dev extra)")
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
    for key in ("kuka_sockets", "abb_sockets"):
        sockets = report[key]
        assert {p for p, _, _ in sockets} == {"udp", "tcp"}
        assert all(addr == "127.0.0.1" for _, addr, _ in sockets), sockets
        assert ["udp", "127.0.0.1", 3956] in sockets


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


@pytest.mark.parametrize("protocol", ["kuka", "abb"])
def test_10000_random_packets_per_port_and_the_simulator_keeps_serving(report, protocol):
    assert report[f"{protocol}_alive"] and report[f"{protocol}_exit"] == 0
    flood = report[f"{protocol}_flood"]
    assert len(flood) == len(report[f"{protocol}_sockets"]) and min(flood.values()) >= 10_000
    after = report[f"{protocol}_after"]
    assert after["move_error_mm"] < 0.1 and after["image_shape"] == [240, 320]
    if protocol == "kuka":
        assert report["arv_after"][0] == 0 and "Width = 320" in report["arv_after"][1]
