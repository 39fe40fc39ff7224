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

__all__ = [
    "BadInputError",
    "DetectionError",
    "DeviceError",
    "JcalibError",
    "NotObservableError",
    "__version__",
]
