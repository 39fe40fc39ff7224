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
        # every compile is kept: with XLA:CPU's loop emitters (jcalib/__init__.py) small functions compile in
        # under 0.2 s, and a warm demo recompiled them on every run (measured: 3.39 -> 3.14 s warm with 0)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
