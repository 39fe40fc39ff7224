"""The inputs the `jcalib import` fuzzer tries, per importer, and what became of them (issue 32).

Runs the generator of ``tests/fuzz/import_fuzz.py`` (the same fixed seeds as
``tests/fuzz/test_import_fuzz.py``) and prints two markdown tables: per importer, the cases and their
exit statuses, with the count of violations (an internal error, a file that existed and changed, a
partial session left behind, the canary outside the source opened without ``allow_outside``), which
must all be 0; and per mutation family, the exit statuses over all importers.

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/bench_import_fuzz.py [--seed 0] [--draws 1]``
(``--draws``: cases per random mutation and seed variant). Output of the default run:
``benchmarks/data/bench_import_fuzz.txt``.
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "fuzz"))

from import_fuzz import FORMATS, VARIANTS, cases, run_case


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--draws", type=int, default=1)
    args = parser.parse_args()
    per_fmt: dict[str, collections.Counter] = {}
    per_family: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    with tempfile.TemporaryDirectory() as tmp:
        for fmt in FORMATS:
            c = collections.Counter()
            t0 = time.perf_counter()
            root = Path(tmp) / fmt
            root.mkdir()
            for case in cases(fmt, root, seed=args.seed, per_variant=args.draws):
                o = run_case(case)
                c["cases"] += 1
                c[o.code if o.code in (0, 2, 3) else "other"] += 1
                c["internal"] += o.internal_error
                c["changed"] += bool(o.changed)
                c["left"] += bool(o.left_behind)
                c["canary"] += o.canary_opened and not case.allow_outside
                per_family[case.mutation.split(":")[0].split("+")[0]][o.code if o.code in (0, 2, 3) else "other"] += 1
            c["seconds"] = time.perf_counter() - t0
            per_fmt[fmt] = c
    print(f"`jcalib import` fuzz cases (seed {args.seed}, {args.draws} draw(s) per random mutation)\n")
    print("| importer | seed variants | cases | exit 0 | exit 2 | exit 3 | other exit | internal error | "
          "existing file changed | left behind | read outside source | time (s) |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for fmt, c in per_fmt.items():
        print(f"| {fmt} | {', '.join(VARIANTS[fmt])} | {c['cases']} | {c[0]} | {c[2]} | {c[3]} | {c['other']} | "
              f"{c['internal']} | {c['changed']} | {c['left']} | {c['canary']} | {c['seconds']:.1f} |")
    total = sum((c for c in per_fmt.values()), collections.Counter())
    print(f"| all | | {total['cases']} | {total[0]} | {total[2]} | {total[3]} | {total['other']} | "
          f"{total['internal']} | {total['changed']} | {total['left']} | {total['canary']} | {total['seconds']:.1f} |")
    print("\n| mutation family | cases | exit 0 | exit 2 | exit 3 | other exit |")
    print("|---|---:|---:|---:|---:|---:|")
    for fam, c in sorted(per_family.items()):
        print(f"| {fam} | {sum(c.values())} | {c[0]} | {c[2]} | {c[3]} | {c['other']} |")
    print("\nexit 0 under a mutation: the change was harmless (a note names it: a repeated pose pair, an unused "
          "field or reference file, an empty --out folder, image bytes that PNG headers do not cover).")


if __name__ == "__main__":
    main()
