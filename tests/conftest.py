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
