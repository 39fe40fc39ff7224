"""Test configuration: float64 and strict JAX promotion, so a silent float32 or a broadcast bug fails."""

import os

os.environ["JAX_ENABLE_X64"] = "1"

import jax  # noqa: E402

import jcalib  # noqa: E402,F401  (enables float64 on import)

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")

from hypothesis import HealthCheck, settings  # noqa: E402

# JAX compiles on first call, so the first example of a property test is slow: no deadline.
settings.register_profile(
    "jcalib",
    deadline=None,
    max_examples=60,
    suppress_health_check=[HealthCheck.too_slow],
    derandomize=True,
)
settings.load_profile("jcalib")

from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

REAL_DATA = Path(__file__).resolve().parent / "data" / "real"


@pytest.fixture(scope="session")
def real_data() -> Path:
    """``tests/data/real``: the public real calibration data bundled with the repository (README.md there)."""
    assert REAL_DATA.is_dir(), f"real calibration data not found at {REAL_DATA}"
    return REAL_DATA


def _shared_compilation_cache() -> None:
    """JAX's persistent compilation cache (and jcalib's traced solves) shared by the test workers of a run.

    ``$JCALIB_CACHE_DIR`` when set (CI starts it empty), else one folder per run (the xdist workers of
    a run share ``PYTEST_XDIST_TESTRUNUID``): a problem structure that several modules or workers solve is
    traced and compiled once per run, starting from an empty cache every run.
    """
    import tempfile

    if not os.environ.get("JCALIB_CACHE_DIR"):
        run = os.environ.get("PYTEST_XDIST_TESTRUNUID") or f"pid{os.getpid()}"
        os.environ["JCALIB_CACHE_DIR"] = os.path.join(tempfile.gettempdir(), f"jcalib-tests-{run}")
    from jcalib.solve.cache import enable_compilation_cache

    enable_compilation_cache()


_shared_compilation_cache()


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_code():
    """Drop JAX's compiled functions after every test module.

    Every XLA:CPU executable keeps memory mappings for its code (thousands per big solve); a test
    process that keeps every executable of the suite reaches the kernel's ``vm.max_map_count``
    (65530) and then crashes inside a later compilation. Clearing the caches frees them.
    """
    yield
    jax.clear_caches()


#: A test still running after this many seconds is taken as hung (``$JCALIB_TEST_HANG_S``): the slowest
#: test (the TCP row of the option matrix) takes about two minutes on 2 busy cores with an empty cache.
HANG_S = float(os.environ.get("JCALIB_TEST_HANG_S", "600"))


def _dump_and_stop(nodeid: str, capman) -> None:
    """Write every thread's stack, native frames included (``py-spy``, with the notebook kernels and
    other child processes), then end this worker: xdist reports the test as failed and goes on."""
    import faulthandler
    import shutil
    import subprocess
    import sys

    if capman is not None:  # the stacks go to the terminal (with xdist: the worker's stderr), not to
        capman.suspend_global_capture()  # a capture file that ends with the worker
    sys.stderr.write(f"\n=== {nodeid}: still running after {HANG_S:.0f} s; stacks follow ===\n")
    spy = shutil.which("py-spy") or shutil.which("py-spy", path=os.path.dirname(sys.executable))
    if spy:
        try:
            out = subprocess.run([spy, "dump", "--native", "--subprocesses", "--pid", str(os.getpid())],
                                 capture_output=True, text=True, timeout=120)
            sys.stderr.write(out.stdout + out.stderr)
        except (OSError, subprocess.SubprocessError) as e:
            sys.stderr.write(f"py-spy failed: {e}\n")
    faulthandler.dump_traceback(all_threads=True)
    sys.stderr.flush()
    os._exit(70)


@pytest.fixture(autouse=True)
def _hang_watchdog(request):
    """Turns a hung test (a deadlock waits forever without using the CPU) into a failed one, with stacks."""
    import threading

    capman = request.config.pluginmanager.getplugin("capturemanager")
    timer = threading.Timer(HANG_S, _dump_and_stop, args=(request.node.nodeid, capman))
    timer.daemon = True
    timer.start()
    yield
    timer.cancel()


@pytest.fixture(scope="session")
def run_cli():
    """``run_cli(*args) -> (exit status, stdout and stderr)``: the ``jcalib`` command, run in this process."""
    import contextlib
    import io

    from jcalib.app.cli import main

    def run(*args) -> tuple[int, str]:
        out = io.StringIO()
        with contextlib.redirect_stderr(out), contextlib.redirect_stdout(out):
            try:
                main([str(a) for a in args])
                code = 0
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else 1
        return code, out.getvalue()

    return run
