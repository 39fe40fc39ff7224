"""The benchmark scripts still load against today's package: every ``benchmarks/*.py`` imports (its names from
jcalib exist) and a script's ``--help`` works. A benchmark is run by hand, rarely; an API change that breaks
one is otherwise found by the next person who needs its table (``bench_ur`` lost an import that way)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Loads each script as a module (``__name__`` is not ``"__main__"``: nothing runs), then calls its ``main``
#: with ``--help`` where it parses arguments; prints ``{script: problem}`` as JSON.
CHECK = r"""
import contextlib, importlib.util, io, json, os, sys, traceback
from pathlib import Path
os.environ.setdefault("JAX_PLATFORMS", "cpu")
folder = Path(sys.argv[1])
sys.path.insert(0, str(folder))
problems = {}
for path in sorted(folder.glob("*.py")):
    name = f"_bench_{path.stem}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        problems[path.name] = "import: " + traceback.format_exc(limit=3)[-600:]
        continue
    main = getattr(module, "main", None)
    if main is None or "argparse" not in path.read_text():
        continue
    sys.argv = [path.name, "--help"]
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            main()
        problems[path.name] = "--help returned instead of exiting"
    except SystemExit as stop:
        if stop.code not in (0, None):
            problems[path.name] = f"--help exited {stop.code}"
    except BaseException:
        problems[path.name] = "--help: " + traceback.format_exc(limit=3)[-600:]
print(json.dumps(problems))
"""


def test_every_benchmark_script_loads_and_parses_its_arguments():
    scripts = sorted((ROOT / "benchmarks").glob("*.py"))
    assert len(scripts) > 20, "the benchmarks folder moved?"
    proc = subprocess.run([sys.executable, "-c", CHECK, str(ROOT / "benchmarks")], capture_output=True,
                          text=True, timeout=300, check=False, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    problems = json.loads(proc.stdout.strip().splitlines()[-1])
    assert problems == {}, "\n".join(f"{k}: {v}" for k, v in problems.items())
