"""Image inputs of ``jcalib detect``: the fuzz cases and what each got, and large blank images.

1. Every case of ``tests/fuzz/image_cases.py`` (generated and mutated files, header bombs, multi-page and
   EXIF files, duplicates, session symlinks, ``-o`` over other files; seed 0), run through the CLI in this
   process: exit status, what the output says about the file (skipped and why, warned, refused), wall time.
2. Large blank (and noise) images, each ``jcalib detect`` in a subprocess on one core: wall time, the
   process's peak memory (VmHWM), and the estimate the memory budget checks (``detection_memory_bytes``:
   the image's share, without the interpreter's ~75 MiB).

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_image_fuzz.py [--no-large]``; the output
is kept in ``benchmarks/data/bench_image_fuzz.txt``.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "fuzz")]
os.environ["COLUMNS"] = "100000"


def outcome(text: str) -> str:
    """The output's words about the inputs, short: skip reasons, warnings, refusals, what was written."""
    text = re.sub(r"/tmp/\S+/", "", " ".join(text.split())).replace("images skipped", "images not used")
    parts = re.split(r"(?=\b(?:skipped|excluded|warning|wrote|jcalib error)\b)", text)
    said = []
    for part in parts:
        part = part.strip()
        if part.startswith("skipped"):
            m = re.match(r"skipped \S+: (\w+) — \S+: (.*)", part) or re.match(r"skipped .+?: (\w+): (.*)", part)
            said.append(f"skipped ({m.group(1)}: {_cut(m.group(2))})" if m else _cut(part))
        elif part.startswith(("warning", "jcalib error")):
            said.append(_cut(part))
        elif part.startswith("wrote"):
            said.append(_cut(part, 60))
    return "; ".join(dict.fromkeys(said)) or _cut(text)


def _cut(s: str, n: int = 130) -> str:
    s = s.replace("|", "/")
    return s if len(s) <= n else s[: n - 1] + "…"


def fuzz_table() -> list[str]:
    from fuzz_helpers import run_cli
    from image_cases import cases

    rows = ["| case | kind | exit | outcome | s |", "|---|---|---|---|---|"]
    for case in cases(seed=0):
        with tempfile.TemporaryDirectory() as d:
            old = {k: os.environ.get(k) for k in case.env}
            os.environ.update(case.env)
            try:
                args = case.make(Path(d))
                t = time.perf_counter()
                code, text = run_cli("detect", *args)
                dt = time.perf_counter() - t
            finally:
                for k, v in old.items():
                    os.environ.pop(k) if v is None else os.environ.__setitem__(k, v)
        ok = "" if code in case.exits else " (UNEXPECTED)"
        rows.append(f"| {case.name} | {case.kind} | {code}{ok} | {outcome(text)} | {dt:.2f} |")
    return rows


LARGE = [  # (name, width, height, pixel kind, extension)
    ("grey 8-bit blank", 6000, 4000, "g8", "png"), ("BGR 8-bit blank", 6000, 4000, "c8", "png"),
    ("BGR 16-bit blank", 6000, 4000, "c16", "png"), ("RGB float blank", 6000, 4000, "cf", "hdr"),
    ("grey 8-bit noise", 6000, 4000, "n8", "png"), ("grey 8-bit blank", 14000, 14000, "g8", "png"),
]


def large_table() -> list[str]:
    import cv2
    import numpy as np

    from jcalib.vision.image import check_image_header, detection_memory_bytes

    rows = ["| image | px | file | exit | wall s | peak MiB | estimate MiB |", "|---|---|---|---|---|---|---|"]
    cell = "schema: jcalib.cell/1\ncameras:\n  c: {model: opencv5}\ntargets:\n  b: {type: checkerboard, cols: 9, rows: 6, square: 0.03}\n"
    code = ("import re, sys\nfrom jcalib.app.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n"
            "    hwm = re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read()).group(1)\n"
            "    print('exit', e.code, hwm, file=sys.stderr)\n")  # VmHWM: ru_maxrss keeps the forking parent's peak
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "cell.yaml").write_text(cell)
        for name, w, h, kind, ext in LARGE:
            shape = (h, w) if kind in ("g8", "n8") else (h, w, 3)
            img = {"g8": lambda s: np.full(s, 128, np.uint8), "c8": lambda s: np.full(s, 128, np.uint8),
                   "c16": lambda s: np.full(s, 30000, np.uint16), "cf": lambda s: np.full(s, 0.5, np.float32),
                   "n8": lambda s: np.random.default_rng(0).normal(128, 30, s).clip(0, 255).astype(np.uint8)}[kind](shape)
            path = Path(d) / f"{kind}_{w}x{h}.{ext}"
            cv2.imwrite(str(path), img)
            del img
            estimate = detection_memory_bytes(check_image_header(path)) / 2**20
            t = time.perf_counter()
            proc = subprocess.run([sys.executable, "-c", code, "detect", "--cell", str(Path(d) / "cell.yaml"), "--camera",
                                   "c", str(path), "-o", str(Path(d) / "obs.json"), "-j", "1"], capture_output=True,
                                  text=True, check=False, env={**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)})
            dt = time.perf_counter() - t
            last = proc.stderr.split()[-3:]
            rows.append(f"| {name} | {w}x{h} | {ext.upper()} {path.stat().st_size / 2**20:.1f} MiB | {last[1]} | {dt:.1f} "
                        f"| {int(last[2]) / 1024:.0f} | {estimate:.0f} |")
            path.unlink()
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-large", action="store_true", help="Skip the large-image table.")
    args = parser.parse_args()
    print("## Image inputs of `jcalib detect` (tests/fuzz/image_cases.py, seed 0)\n")
    print("\n".join(fuzz_table()))
    if not args.no_large:
        print("\n## Large images, one `jcalib detect` process each (checkerboard 9x6; peak = VmHWM of the process, "
              "the interpreter's ~100 MiB included)\n")
        print("\n".join(large_table()))


if __name__ == "__main__":
    main()
