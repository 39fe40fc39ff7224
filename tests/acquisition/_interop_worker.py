"""Interoperability worker, run inside a private network namespace (``unshare -n``, only ``lo`` up).

``python _interop_worker.py OUT``: starts ``jcalib simulate`` (KUKA, one fake GigE camera on 127.0.0.1)
and talks to it with programs jcalib did not write: Aravis' ``arv-tool-0.8`` (features read and written,
always ``-a 127.0.0.1``) and ``arv-camera-test-0.8`` (software-triggered grabbing), and the PyPI
KUKAVARPROXY client ``py_openshowvar`` (reads, writes, a motion through the ``JCALIB_MOVE`` variables);
records ``ss -lunpt``; sends 10,000 random packets to every port of the simulator; checks that jcalib's own
clients and Aravis' tool are still served. Then the same listing, flood and check for the ABB simulator, and
for the UR simulator (on UR's fixed ports, free in this namespace), whose RTDE interface the PyPI client
``ur_rtde`` (``rtde_receive.RTDEReceiveInterface``) reads before and after the flood.
Writes ``OUT/report.json``.
"""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

JCALIB = [sys.executable, "-c", "from jcalib.app.cli import main; main()"]
CELL = """schema: jcalib.cell/1
cameras:
  cam0: {model: opencv5, mount: flange}
targets:
  board: {type: checkerboard, cols: 8, rows: 5, square: 0.02, mount: base}
"""
NUM_PACKETS = 10_000


def sh(*cmd: str, timeout: float = 60) -> tuple[int, str]:
    p = subprocess.run(list(cmd), capture_output=True, text=True, timeout=timeout)
    return p.returncode, p.stdout + p.stderr


def listening(pid: int) -> list[tuple[str, str, int]]:
    """(protocol, local address, port) of the sockets ``ss -lunpt`` shows for process ``pid``."""
    out = []
    for line in sh("ss", "-H", "-lunpt")[1].splitlines():
        if f"pid={pid}," not in line:
            continue
        parts = line.split()
        addr, _, port = parts[4].rpartition(":")
        out.append((parts[0], addr, int(port)))
    return out


def start(out: Path, protocol: str) -> tuple[subprocess.Popen, str]:
    cmd = [*JCALIB, "simulate", "--cell", str(out / "cell.yaml"), "--robot-protocol", protocol,
           "--camera", "cam0=127.0.0.1", "--time-scale", "0", "--image-size", "320x240"]  # fmt: skip
    if protocol == "ur":
        cmd += ["--robot", "ur5e"]  # UR's fixed ports: free inside this namespace
    else:
        cmd += ["--robot-port", "0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=open(out / f"simulate-{protocol}.err", "w"), text=True)
    line = proc.stdout.readline() if proc.stdout else ""
    if not line.startswith("READY"):
        raise RuntimeError(f"simulate did not start: {line!r}")
    return proc, line.split()[2]


def flood(ports: list[tuple[str, str, int]], seed: int) -> dict:
    """NUM_PACKETS random datagrams to every UDP port, NUM_PACKETS random chunks to every TCP port."""
    rng = np.random.default_rng(seed)
    sent = {}
    for proto, addr, port in ports:
        if proto == "udp":
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            for i in range(NUM_PACKETS):
                n = int(rng.integers(0, 600))
                data = bytearray(rng.integers(0, 256, n, dtype=np.uint8).tobytes())
                if n >= 8 and i % 2:  # half of them look like GVCP commands
                    data[0:6] = bytes([0x42, int(rng.integers(0, 2))]) + int(rng.choice([2, 0x80, 0x82, 0x84, 0x86])).to_bytes(2, "big") + (n - 8).to_bytes(2, "big")
                s.sendto(bytes(data), (addr, port))
                if i % 500 == 0:
                    time.sleep(0.01)  # let the receiver drain (a full buffer would drop, not test)
            s.close()
        else:
            chunks = 0
            while chunks < NUM_PACKETS:
                with socket.create_connection((addr, port), timeout=5) as s:
                    for _ in range(100):
                        n = int(rng.integers(1, 120))
                        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
                        if rng.random() < 0.3:  # KUKAVARPROXY-like framing / protocol-like lines
                            data = int(rng.integers(0, 65536)).to_bytes(2, "big") + len(data).to_bytes(2, "big") + data
                        if rng.random() < 0.2:
                            data = (rng.choice(["PING", "GETP", "MOVJ", "TOOL", "SPEED"]) + " " + " ".join(
                                str(v) for v in rng.normal(0, 1e3, int(rng.integers(0, 9)))) + "\n").encode()
                        if rng.random() < 0.2:  # RTDE-like packages: a size, a command, a payload
                            body = bytes([int(rng.choice(list(b"VvOISPUM")))]) + data
                            data = int(rng.integers(0, 3 + len(body) + 2)).to_bytes(2, "big") + body
                        if rng.random() < 0.2:  # URScript-like programs and lines
                            nums = ", ".join(f"{v:.4g}" for v in rng.normal(0, 1.0, int(rng.integers(0, 8))))
                            data = str(rng.choice([f"movej(p[{nums}])\n", f"movel(p[{nums}], a=1, v=0.1)\n",
                                                   f"def f():\n  set_tcp(p[{nums}])\n", "end\n", "halt\n",
                                                   f"write_output_integer_register({nums[:3]}, 7)\n",
                                                   f"if not get_inverse_kin_has_solution(p[{nums}]):\n",
                                                   f"stopj({nums[:5]})\n"])).encode()
                        try:
                            s.sendall(data)
                        except OSError:
                            break
                        chunks += 1
            sent[f"{proto}:{port}"] = chunks
        sent.setdefault(f"{proto}:{port}", NUM_PACKETS)
    return sent


def our_clients_work(robot_url: str) -> dict:
    from jcalib.workflow.devices import open_camera, open_robot

    res: dict = {}
    robot = open_robot(robot_url, timeout_s=5.0)
    try:
        T = robot.state().T_base_flange.copy()
        T[0, 3] += 0.01
        res["move_error_mm"] = float(np.linalg.norm(robot.move(T).T_base_flange[:3, 3] - T[:3, 3]) * 1e3)
    finally:
        robot.close()
    cam = open_camera("cam0", "gige://127.0.0.1", packet_size=1400)
    try:
        img = cam.grab().image
        res["image_shape"] = list(img.shape)
        res["image_std"] = float(img.std())
        res["exposure_us"] = float(cam.get("ExposureTime"))
    finally:
        cam.close()
    return res


def ur_rtde_reads() -> dict:
    """What the PyPI client ``ur_rtde`` reads from the simulator's RTDE interface (pose, joints, modes), and what
    jcalib's driver reads right after (the arm stands still)."""
    import rtde_receive

    from jcalib.workflow.devices import open_robot

    r = rtde_receive.RTDEReceiveInterface("127.0.0.1")
    try:
        time.sleep(0.2)
        res = {"pose": list(r.getActualTCPPose()), "q": list(r.getActualQ()), "robot_mode": r.getRobotMode(),
               "safety_mode": r.getSafetyMode(), "runtime_state": r.getRuntimeState(),
               "connected": r.isConnected(), "protective_stop": r.isProtectiveStopped(),
               "timestamp": r.getTimestamp()}  # fmt: skip
    finally:
        r.disconnect()
    robot = open_robot("ur://127.0.0.1", timeout_s=5.0)
    try:
        s = robot.state()
        res["jcalib_T_base_flange"], res["jcalib_joints_deg"] = s.T_base_flange.tolist(), s.joints_deg.tolist()
    finally:
        robot.close()
    return res


def arv_tool(*args: str) -> tuple[int, str]:
    return sh("arv-tool-0.8", "-a", "127.0.0.1", *args, timeout=30)


def openshowvar_session(port: int) -> dict:
    """Reads, writes and one PTP motion through the PyPI client (its single-recv framing included)."""
    from py_openshowvar import openshowvar

    c = openshowvar("127.0.0.1", port)
    res: dict = {"pos_act": c.read("$POS_ACT", debug=False).decode()}
    res["unknown"] = c.read("$NO_SUCH_VAR", debug=False)
    res["vel_write"] = c.write("JC_VEL", "30", debug=False).decode()
    res["vel_read"] = c.read("JC_VEL", debug=False).decode()
    res["nan_write"] = c.write("JC_FLAG", "nan", debug=False)
    pos = dict(re.findall(r"([XYZABC]) ([-+0-9.eE]+)", res["pos_act"]))
    target = {k: float(pos[k]) for k in "XYZABC"}
    target["X"] += 10.0
    frame = "{FRAME: " + ", ".join(f"{k} {target[k]:.4f}" for k in "XYZABC") + "}"
    res["pos_write"] = c.write("JC_POS", frame, debug=False) is not None
    c.write("JC_FLAG", "1", debug=False)
    deadline = time.monotonic() + 20
    while c.read("JC_FLAG", debug=False) != b"0" and time.monotonic() < deadline:
        time.sleep(0.02)
    res["err"] = c.read("JC_ERR", debug=False).decode()
    after = dict(re.findall(r"([XYZABC]) ([-+0-9.eE]+)", c.read("$POS_ACT", debug=False).decode()))
    res["moved_mm"] = [float(after[k]) - float(pos[k]) for k in "XYZ"]
    c.close()
    return res


def main() -> None:
    out = Path(sys.argv[1])
    (out / "cell.yaml").write_text(CELL)
    report: dict = {}
    proc, robot_url = start(out, "kuka")
    try:
        port = int(robot_url.rsplit(":", 1)[1])
        report["kuka_sockets"] = listening(proc.pid)
        report["arv_read"] = arv_tool("control", "Width", "Height", "PixelFormat", "DeviceModelName")
        report["arv_write"] = arv_tool("control", "ExposureTimeAbs=2500", "GainRaw=2")
        report["arv_features"] = arv_tool("features")[0]
        report["arv_grab"] = sh("arv-camera-test-0.8", "-n", "127.0.0.1", "--duration=3", "-o", "10",
                                "--no-packet-socket", timeout=60)  # fmt: skip
        report["openshowvar"] = openshowvar_session(port)
        report["kuka_before"] = our_clients_work(robot_url)
        report["kuka_flood"] = flood(report["kuka_sockets"], 1)
        time.sleep(0.5)
        report["kuka_alive"] = proc.poll() is None
        report["kuka_after"] = our_clients_work(robot_url)
        report["arv_after"] = arv_tool("control", "Width")
    finally:
        proc.terminate()
        proc.wait(30)
    report["kuka_exit"] = proc.returncode
    proc, robot_url = start(out, "abb")
    try:
        report["abb_sockets"] = listening(proc.pid)
        report["abb_flood"] = flood(report["abb_sockets"], 2)
        time.sleep(0.5)
        report["abb_alive"] = proc.poll() is None
        report["abb_after"] = our_clients_work(robot_url)
    finally:
        proc.terminate()
        proc.wait(30)
    report["abb_exit"] = proc.returncode
    proc, robot_url = start(out, "ur")
    try:
        report["ur_url"] = robot_url
        report["ur_sockets"] = listening(proc.pid)
        report["ur_rtde_before"] = ur_rtde_reads()
        report["ur_before"] = our_clients_work(robot_url)  # moves the arm 10 mm
        report["ur_rtde_moved"] = ur_rtde_reads()
        report["ur_flood"] = flood(report["ur_sockets"], 3)
        time.sleep(0.5)
        report["ur_alive"] = proc.poll() is None
        report["ur_after"] = our_clients_work(robot_url)
        report["ur_rtde_after"] = ur_rtde_reads()
    finally:
        proc.terminate()
        proc.wait(30)
    report["ur_exit"] = proc.returncode
    (out / "report.json").write_text(json.dumps(report, default=str))
    print("INTEROP-DONE", flush=True)


if __name__ == "__main__":
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    main()
