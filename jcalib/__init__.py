"""jcalib: calibrate industrial robot cells as one joint least-squares problem in JAX.

Importing jcalib turns on JAX's float64 mode (``jax_enable_x64``): calibration needs double
precision; it also adds an XLA:CPU compile-time flag to ``XLA_FLAGS`` where the installed jaxlib knows it
(below; ``JCALIB_XLA_DEFAULTS=0`` turns that off). The import itself stays light (JAX is imported on first
use), so ``jcalib --help`` is instant.
"""

from __future__ import annotations

import os
import sys

__version__ = "0.1.0"

# XLA:CPU compile flags, set before JAX starts its backend (XLA reads XLA_FLAGS once, at the first
# computation; a JAX that has already computed something before `import jcalib` keeps its flags).
# XLA:CPU's older loop emitters instead of its MLIR fusion emitters compile our solves in about 0.6-0.75x
# the CPU time (`jcalib calibrate` of the demo cell, empty cache: ~31 -> ~22 s) with the same run time
# and the same results (to ~1e-9 relative). Appended to the user's XLA_FLAGS, never overriding a flag
# they name; CPU-only (GPU backends ignore it); JCALIB_XLA_DEFAULTS=0 turns it off. Not
# --xla_backend_optimization_level=0 (scripts/test uses it): it compiles faster but solves 2-2.4x slower.
# Only for the jaxlib versions where each flag was checked: XLA aborts the whole process on a flag it does
# not know (jaxlib 0.11.2 no longer has this one: "Unknown flag in XLA_FLAGS", then SIGABRT at the first
# computation), so a newer or older jaxlib runs with XLA's own defaults.
_XLA_DEFAULTS = (("--xla_cpu_use_fusion_emitters=false", ((0, 10),)),)


def _jaxlib_version() -> tuple[int, int] | None:
    """``(major, minor)`` of the installed jaxlib, without importing it (None when unknown): read from its
    ``version.py`` (0.2 ms; ``importlib.metadata`` takes 20-50 ms, and ``jcalib --help`` stays instant)."""
    try:
        import importlib.util
        import re

        spec = importlib.util.find_spec("jaxlib")
        path = os.path.join(list(spec.submodule_search_locations)[0], "version.py")
        with open(path, encoding="utf-8") as f:
            match = re.search(r"^_version\s*=\s*[\"']([0-9]+)\.([0-9]+)", f.read(), re.M)
        return (int(match.group(1)), int(match.group(2))) if match else None
    except Exception:  # noqa: BLE001 - not installed, or laid out differently: XLA's defaults
        return None


def _default_xla_flags(user_flags: str, jaxlib: tuple[int, int] | None) -> list[str]:
    """The default flags to append: those this jaxlib knows and the user's ``XLA_FLAGS`` does not name."""
    return [f for f, versions in _XLA_DEFAULTS
            if jaxlib in versions and f.split("=")[0].lstrip("-") not in user_flags]


if os.environ.get("JCALIB_XLA_DEFAULTS", "1").strip().lower() not in ("0", "false", "no", "off"):
    _user_flags = os.environ.get("XLA_FLAGS", "")
    _added = _default_xla_flags(_user_flags, _jaxlib_version())
    if _added:
        os.environ["XLA_FLAGS"] = " ".join([_user_flags.strip(), *_added]).strip()
    del _user_flags, _added

# float64 everywhere. The environment variable covers a JAX imported after us (and our
# subprocesses); the config update covers a JAX that was imported before us.
os.environ["JAX_ENABLE_X64"] = "1"
if "jax" in sys.modules:
    sys.modules["jax"].config.update("jax_enable_x64", True)

from jcalib.errors import (  # noqa: E402
    BadInputError,
    DetectionError,
    DeviceError,
    JcalibError,
    NotObservableError,
)

#: Public names imported on first use (keeps ``import jcalib`` and ``jcalib --help`` fast).
_LAZY = {
    "calibrate": "jcalib.problems.api",
    "Result": "jcalib.problems.calibrate",
    "Calibration": "jcalib.problems.assemble",
    "CalibrationOptions": "jcalib.problems.options",
    "calibrate_cell": "jcalib.problems.calibrate",
    "calibrate_batch": "jcalib.problems.batch",
    "calibrate_tcp": "jcalib.problems.tcp",
    "refine_pivot": "jcalib.problems.pivot",
    "calibrate_hand_eye_pairs": "jcalib.problems.handeye_pairs",
    "reoptimise": "jcalib.problems.reoptimise",
    "load_cell": "jcalib.io.cell",
    "load_observations": "jcalib.io.observations",
    "load_result": "jcalib.io.result",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'jcalib' has no attribute {name!r}")


__all__ = [
    *_LAZY,
    "BadInputError",
    "DetectionError",
    "DeviceError",
    "JcalibError",
    "NotObservableError",
    "__version__",
]
