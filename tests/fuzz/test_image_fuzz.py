"""Image inputs of ``jcalib detect``, generated and mutated (fixed seeds; tests/fuzz/image_cases.py):
truncated and bit-flipped files of every format, headers claiming huge sizes, multi-page and EXIF-turned
files, duplicates, symlinks in sessions, ``-o`` over a file that is not observations.

Every input gets exit status 0, 2 or 3 with a message (never a traceback or "internal error"), the
words the case expects (the file named, the budget stated), and no file that existed before changes
(but ``-o`` with ``--force``). Header bombs are refused from the header: a subprocess that reads all of
them peaks far below what decoding one would take.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from fuzz_helpers import run_cli
from image_cases import HEADER_BOMBS, cases, snapshot

CASES = cases(seed=0)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_image_input(case, tmp_path, monkeypatch):
    monkeypatch.setenv("COLUMNS", "100000")  # rich wraps nothing: the words are found whole
    for k, v in case.env.items():
        monkeypatch.setenv(k, v)
    args = case.make(tmp_path)
    out = Path(args[args.index("-o") + 1]) if "-o" in args else None
    before = snapshot(tmp_path, skip=out if "--force" in args else None)
    code, text = run_cli("detect", *args)
    text = " ".join(text.split())
    assert code in case.exits, (code, text)
    for word in case.says:
        assert word in text, (word, text)
    after = snapshot(tmp_path, skip=out if "--force" in args else None)
    assert {k: after.get(k) for k in before} == before, "a file that existed before was changed"


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="the peak memory is read from /proc (Linux)")
def test_header_bombs_are_refused_before_decoding(tmp_path):
    """Every header bomb in one ``jcalib detect`` run, in a subprocess: refused by name, and the process peaks
    under 400 MiB, less than one decoded image (the smallest claims 268 Mpx: 0.8 GiB as 8-bit BGR)."""
    (tmp_path / "cell.yaml").write_text("schema: jcalib.cell/1\ncameras:\n  cam0: {model: opencv4}\ntargets:\n"
                                        "  board: {type: checkerboard, cols: 5, rows: 4, square: 0.03}\n")
    paths = []
    for ext, make in HEADER_BOMBS.items():
        paths.append(tmp_path / f"bomb_{ext}.{ext}")
        paths[-1].write_bytes(make())
    code = ("import re, sys\nfrom jcalib.app.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n"
            "    hwm = re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read()).group(1)\n"
            "    print('exit', e.code, 'peak_kb', hwm)\n")  # VmHWM: this process's own peak (ru_maxrss keeps the forking parent's)
    env = {**os.environ, "COLUMNS": "100000"}
    proc = subprocess.run([sys.executable, "-c", code, "detect", "--cell", str(tmp_path / "cell.yaml"), "--camera",
                           "cam0", *map(str, paths), "-o", str(tmp_path / "obs.json"), "-j", "1"],
                          capture_output=True, text=True, timeout=120, check=False, env=env, cwd=Path(__file__).resolve().parents[2])
    last = proc.stdout.split()
    assert last[:2] == ["exit", "2"], proc.stdout + proc.stderr
    for p in paths:
        assert p.name in proc.stderr, proc.stderr
    assert int(last[3]) < 400 * 1024, f"peak {int(last[3]) / 1024:.0f} MiB: a header bomb was decoded"
