"""jcalib: calibrate industrial robot cells as one joint least-squares problem in JAX.

Importing jcalib turns on JAX's float64 mode (``jax_enable_x64``): calibration needs double
precision. The import itself stays light (JAX is imported on first use), so ``jcalib --help`` is
instant.
"""

from __future__ import annotations

import os
import sys

__version__ = "0.1.0"

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
