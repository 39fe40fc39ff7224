"""Cost of the input layer: reading + schema + plausibility checks of observations files of growing size,
against plain ``json.loads`` of the same text; and the time to refuse hostile files (alias bomb, deep
nesting, a 20000x20000 PNG header).

Run: ``.venv/bin/python benchmarks/bench_input_validation.py [--quick]``. Prints two tables. Timings on
shared machines move by tens of percent between runs: compare rows of one run.
"""

from __future__ import annotations

import argparse
import json
import struct
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np

from jcalib.errors import BadInputError, DetectionError
from jcalib.io.observations import load_observations
from jcalib.io.schema.reading import read_document


def _observations(num_stations: int, num_points: int = 100, cameras: int = 2) -> dict:
    rng = np.random.default_rng(0)
    board = np.c_[rng.uniform(0, 0.3, (num_points, 2)), np.zeros(num_points)]
    T = np.eye(4)
    T[:3, 3] = [0.5, 0.0, 0.6]
    stations = [{"id": f"s{i:05d}", "T_base_flange": T.tolist(),
                 "detections": [{"camera": f"cam{c}", "target": "board", "point_index": list(range(num_points)),
                                 "pixels": rng.uniform(0, 1000, (num_points, 2)).tolist()} for c in range(cameras)]}
                for i in range(num_stations)]
    return {"schema": "jcalib.observations/1",
            "cameras": {f"cam{c}": {"image_size": [1280, 1024]} for c in range(cameras)},
            "targets": {"board": {"points": board.tolist()}}, "stations": stations}


def _best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def _refusal(fn) -> tuple[float, str]:
    t0 = time.perf_counter()
    try:
        fn()
        outcome = "accepted (!)"
    except (BadInputError, DetectionError) as e:
        outcome = str(e).split(": ", 1)[-1][:60]
    return time.perf_counter() - t0, outcome


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small files only")
    args = parser.parse_args()
    sizes = [10, 100, 1000] if args.quick else [10, 100, 1000, 5000]
    repeat = 2 if args.quick else 3
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        print("observations files: json.loads vs jcalib's reading + schema + plausibility + data classes")
        print(f"{'stations':>9} {'pixels':>9} {'MB':>7} {'json.loads s':>13} {'read_document s':>16} "
              f"{'load_observations s':>20} {'overhead':>9}")
        for n in sizes:
            path = tmp / f"obs{n}.json"
            path.write_text(json.dumps(_observations(n)))
            text = path.read_text()
            t_json = _best(lambda: json.loads(text), repeat)
            t_read = _best(lambda: read_document(path, "observations file", fmt="json"), repeat)
            t_load = _best(lambda: load_observations(path), repeat)
            print(f"{n:>9} {n * 200:>9} {path.stat().st_size / 1e6:>7.1f} {t_json:>13.3f} {t_read:>16.3f} "
                  f"{t_load:>20.3f} {t_load / t_json:>8.1f}x")

        print("\nhostile inputs: time to refuse")
        bomb = tmp / "bomb.yaml"
        bomb.write_text("a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
            f"{k}: &{k} [{', '.join(['*' + p] * 10)}]\n" for p, k in zip("abcdefgh", "bcdefghi")))
        deep = tmp / "deep.json"
        deep.write_text("[" * 100_000 + "]" * 100_000)
        png = tmp / "big.png"

        def chunk(kind: bytes, data: bytes) -> bytes:
            return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

        png.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 20000, 20000, 8, 0, 0, 0, 0))
                        + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))
        from jcalib.vision.image import load_image

        print(f"{'input':<32} {'s':>8}  message")
        for name, fn in [("YAML alias bomb (10^9 values)", lambda: read_document(bomb, "cell spec")),
                         ("JSON nested 100000 deep", lambda: read_document(deep, "observations file")),
                         ("PNG header 20000x20000", lambda: load_image(png))]:
            dt, outcome = _refusal(fn)
            print(f"{name:<32} {dt:>8.3f}  {outcome}")


if __name__ == "__main__":
    main()
