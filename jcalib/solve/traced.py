"""A cache of traced solves across processes: the one compiled solve of a problem structure and shape
bucket, traced once and loaded by every later process without tracing again.

JAX's persistent compilation cache (:mod:`jcalib.solve.cache`) saves the XLA compile, but every new
process still traces the Python solve (seconds for a whole cell: the LM loop, every residual's
linearisation) to find the cache entry. Here the traced program itself is kept: the first solve of a
structure exports it (:mod:`jax.export`, StableHLO) next to the compilation cache, keyed by everything
that determines the program — jcalib's source, JAX's version and backend, the solver options, and the
problem's static structure (variable kinds, residual functions by their recipe, losses, chunking) and
array shapes. A later process deserialises it (milliseconds) and its XLA compile hits the persistent
cache.

A residual function takes part when it says what it is: the residual factories of
:mod:`jcalib.residuals` set ``fn.__jcalib_key__`` (their recipe: model class, image size, chain...);
module-level functions are named by module and qualified name. A problem with any other function
(a closure without a key, e.g. in a test) is solved by the plain jitted path.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

from jcalib.solve.problem import Problem

#: Sub-folder of the compilation cache that holds the exported solves.
SUBDIR = "jcalib-traced"


def function_key(f) -> str | None:
    """A process-independent name of a residual function (or its linearisation), or None."""
    if f is None:
        return "none"
    key = getattr(f, "__jcalib_key__", None)
    if key is not None:
        return str(key)
    qual = getattr(f, "__qualname__", "")
    if qual and "<locals>" not in qual and getattr(f, "__module__", None):
        return f"{f.__module__}.{qual}"
    return None


@functools.cache
def _source_hash() -> str:
    """Hash of jcalib's Python sources: an edit invalidates every exported solve."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        h.update(str(p.relative_to(root)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def structure_key(problem: Problem, options, traces: bool) -> str | None:
    """The cache key of a padded problem's compiled solve, or None when some function has no name."""
    parts = [_source_hash(), jax.__version__, jax.default_backend(), str(jax.config.jax_enable_x64), repr(options),
             str(bool(traces))]
    for v in problem.variables:
        parts.append(f"V|{v.name}|{type(v.manifold).__name__}|{v.manifold.param_dim}|{v.eliminate}|{v.constant}|"
                     f"{v.coord_names}|{v.entry_label}")
    for f in problem.factors:
        fk, jk = function_key(f.fn), function_key(f.jacobian)
        if fk is None or jk is None:
            return None
        parts.append(f"F|{f.name}|{fk}|{jk}|{f.args}|{f.chunk}|{f.loss!r}")
    dyn, _ = eqx.partition(problem, eqx.is_array)
    # leaf paths and shapes (the treedef's repr would carry the functions' addresses)
    parts += [f"{jax.tree_util.keystr(path)}|{np.shape(x)}|{np.asarray(x).dtype}"
              for path, x in jax.tree_util.tree_flatten_with_path(dyn)[0]]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:40]


def cache_dir() -> Path | None:
    """The folder of exported solves (inside JAX's compilation cache folder), or None when the
    compilation cache is off."""
    base = jax.config.jax_compilation_cache_dir
    return None if not base else Path(base) / SUBDIR


_LOADED: dict[str, object] = {}


def run(core, problem: Problem, options, traces: bool, out_treedef):
    """``core(problem, options, traces)`` through the cache of traced solves (see the module docstring).

    Returns the host copy of the output pytree (structure ``out_treedef``), or None when the problem
    cannot be cached (the caller then uses its plain jitted function).
    """
    folder = cache_dir()
    if folder is None:
        return None
    key = structure_key(problem, options, traces)
    if key is None:
        return None
    dyn, static = eqx.partition(problem, eqx.is_array)
    leaves, in_tree = jax.tree.flatten(dyn)
    fn = _LOADED.get(key)
    if fn is None:
        path = folder / f"{key}.jax"
        exported = None
        if path.is_file():
            try:
                exported = jax.export.deserialize(bytearray(path.read_bytes()))
            except Exception:  # noqa: BLE001 - a damaged or foreign file: trace again
                exported = None
        if exported is None:
            def flat(*xs):
                return tuple(jax.tree.leaves(core(eqx.combine(jax.tree.unflatten(in_tree, xs), static), options, traces)))

            avals = [jax.ShapeDtypeStruct(np.shape(x), np.asarray(x).dtype) for x in leaves]
            exported = jax.export.export(jax.jit(flat))(*avals)
            try:
                folder.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(f".{os.getpid()}.tmp")
                tmp.write_bytes(exported.serialize())
                os.replace(tmp, path)
            except OSError:
                pass  # a read-only cache: solve anyway
        fn = jax.jit(exported.call)
        _LOADED[key] = fn
    outs = jax.device_get(fn(*leaves))
    return jax.tree.unflatten(out_treedef, list(outs))
