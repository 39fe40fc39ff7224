"""End-to-end worker: ``jcalib plan`` → ``jcalib simulate`` → ``jcalib capture`` → ``jcalib detect --session``.

``python _e2e_worker.py OUT CELL RUNS_JSON``: RUNS_JSON is a list of runs ``{"name", "protocol",
"robot", "kind", "stations", "cameras": {id: address}}``. For each run it plans (in this process,
through the CLI entry point), starts ``jcalib simulate`` as a child process (waits for its READY line),
captures and detects through the CLI entry point, stops the simulator, and records every command's
exit status and stderr in ``OUT/<name>/report.json``. Run it inside ``unshare -n`` with 127.0.0.2 on
``lo`` for a second camera address (the test does).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path

JCALIB = [sys.executable, "-c", "from jcalib.app.cli import main; main()"]


def cli(*args: str) -> tuple[int, str]:
    """Run ``jcalib ARGS`` in this process; (exit status, stderr + stdout)."""
    from jcalib.app.cli import main

    err, out = io.StringIO(), io.StringIO()
    old = sys.argv
    sys.argv = ["jcalib", *args]
    code = 0
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            main()
    except SystemExit as e:
        code = int(e.code or 0)
    finally:
        sys.argv = old
    return code, err.getvalue() + out.getvalue()


def start_simulator(cell: Path, run: dict, out: Path) -> tuple[subprocess.Popen, str]:
    cmd = [*JCALIB, "simulate", "--cell", str(cell), "--robot-protocol", run["protocol"], "--robot-port", "0",
           "--time-scale", "0", "--truth", str(out / "truth.json"), "--robot", run["robot"],
           "--image-size", run.get("image_size", "320x240")]  # fmt: skip
    for name, addr in run["cameras"].items():
        cmd += ["--camera", f"{name}={addr}"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=open(out / "simulate.err", "w"), text=True)
    line = proc.stdout.readline()
    if not line.startswith("READY"):
        proc.kill()
        proc.wait()
        raise RuntimeError(f"simulate did not start: {line!r}: {(out / 'simulate.err').read_text()}")
    return proc, line.split()[2]  # READY --robot URL ...


def main() -> None:
    out_root, cell, runs = Path(sys.argv[1]), Path(sys.argv[2]), json.loads(sys.argv[3])
    for run in runs:
        out = out_root / run["name"]
        out.mkdir(parents=True, exist_ok=True)
        report: dict = {}
        t0 = time.monotonic()
        report["plan"] = cli("plan", "--cell", str(cell), "--kind", run["kind"], "--stations", str(run["stations"]),
                             "--robot", run["robot"], "--image-size", run.get("image_size", "320x240"),
                             "-o", str(out / "plan.json"))  # fmt: skip
        proc, robot_url = start_simulator(cell, run, out)
        cams = [a for name in run["cameras"] for a in ("--camera", f"{name}=gige://{run['cameras'][name]}")]
        capture = ["capture", "--cell", str(cell), "--robot", robot_url, *cams, "--plan", str(out / "plan.json"),
                   "--out", str(out / "session"), "--packet-size", "1400"]  # fmt: skip
        try:
            report["capture"] = cli(*capture)
        finally:
            proc.terminate()
            proc.wait(30)
        report["simulate_status"] = proc.returncode
        report["detect"] = cli("detect", "--session", str(out / "session"))
        if run.get("resume_after_stop"):  # the simulator is gone: a clean device error saying how to resume
            report["resume_dead"] = cli(*capture, "--resume")
        report["elapsed_s"] = time.monotonic() - t0
        (out / "report.json").write_text(json.dumps(report))
    print("E2E-WORKER-DONE", flush=True)


if __name__ == "__main__":
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    main()
