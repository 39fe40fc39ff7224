"""JAX's persistent compilation cache: where the command line, the demos, the notebooks and Dask workers keep
compiled solves, so a new process loads what another one compiled."""

from __future__ import annotations

import os
from pathlib import Path


def enable_compilation_cache() -> None:
    """Turn on JAX's persistent compilation cache (``$JCALIB_CACHE_DIR`` or ~/.cache/jcalib/jax)."""
    import jax

    cache_dir = os.environ.get("JCALIB_CACHE_DIR") or str(Path.home() / ".cache" / "jcalib" / "jax")
    if jax.config.jax_compilation_cache_dir != cache_dir:
        jax.config.update("jax_compilation_cache_dir", cache_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
