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


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_code():
    """Drop JAX's compiled functions after every test module.

    Every XLA:CPU executable keeps memory mappings for its code (thousands per big solve); a test
    process that keeps every executable of the suite reaches the kernel's ``vm.max_map_count``
    (65530) and then crashes inside a later compilation. Clearing the caches frees them.
    """
    yield
    jax.clear_caches()
