"""A cache of traced solves across processes: the one compiled solve of a problem structure and shape
bucket, traced once and loaded by every later process without tracing again.

JAX's persistent compilation cache (:mod:`jcalib.solve.cache`) saves the XLA compile, but every new
process still traces the Python solve (seconds for a whole cell: the LM loop, every residual's
linearisation) to find the cache entry. Here the traced program itself is kept: the first solve of a
structure exports it (:mod:`jax.export`, StableHLO) next to the compilation cache, keyed by everything
that determines the program — jcalib's source, JAX's version and backend, the solver's static options
(its tolerances and iteration limit are inputs of the program), and the
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
import json
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


_STATIC: dict = {}


def _static_description(problem: Problem, treedef) -> str | None:
    """The static part of a problem's key (cached per pytree structure), or None when uncacheable."""
    if treedef in _STATIC:
        return _STATIC[treedef]
    parts = []
    for v in problem.variables:
        parts.append(f"V|{v.name}|{type(v.manifold).__name__}|{v.manifold.param_dim}|{v.eliminate}|{v.constant}|"
                     f"{v.coord_names}|{v.entry_label}")
    for f in problem.factors:
        fk, jk = function_key(f.fn), function_key(f.jacobian)
        if fk is None or jk is None:
            _STATIC[treedef] = None
            return None
        parts.append(f"F|{f.name}|{fk}|{jk}|{f.args}|{f.chunk}|{f.loss!r}|{jax.tree.structure(f.observations)}")
    _STATIC[treedef] = "\n".join(parts)
    return _STATIC[treedef]


def structure_key(problem: Problem, options, traces: bool, leaves=None, treedef=None) -> str | None:
    """The cache key of a padded problem's compiled solve, or None when some function has no name."""
    if leaves is None:
        dyn, _ = eqx.partition(problem, eqx.is_array)
        leaves, treedef = jax.tree.flatten(dyn)
    desc = _static_description(problem, treedef)
    if desc is None:
        return None
    parts = [_source_hash(), jax.__version__, jax.default_backend(), str(jax.config.jax_enable_x64), repr(options),
             str(bool(traces)), desc, ";".join(f"{np.shape(x)}{np.asarray(x).dtype}" for x in leaves)]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:40]


def cache_dir() -> Path | None:
    """The folder of exported solves (inside JAX's compilation cache folder), or None when the
    compilation cache is off."""
    base = jax.config.jax_compilation_cache_dir
    return None if not base else Path(base) / SUBDIR


_KINDS = ("f", "i")  # packed buffers: float64, and int64 (integers and booleans)


def _kind(dtype) -> str:
    return "f" if np.issubdtype(np.dtype(dtype), np.floating) else "i"


def pack(arrays, xp=np) -> tuple:
    """``(float64 buffer, int64 buffer)``: every array ravelled into one of two buffers (one transfer each)."""
    out = []
    for k in _KINDS:
        parts = [xp.ravel(a).astype(xp.float64 if k == "f" else xp.int64) for a in arrays if _kind(a.dtype) == k]
        out.append(xp.concatenate(parts) if parts else xp.zeros((0,), xp.float64 if k == "f" else xp.int64))
    return tuple(out)


def unpack(buffers, layout, xp=np) -> list:
    """The arrays of :func:`pack` back: ``layout`` is ``[(shape, dtype), ...]`` in their order."""
    offsets = dict.fromkeys(_KINDS, 0)
    out = []
    for shape, dtype in layout:
        k = _kind(dtype)
        n = int(np.prod(shape, dtype=np.int64))
        buf = buffers[_KINDS.index(k)]
        out.append(buf[offsets[k]:offsets[k] + n].reshape(shape).astype(dtype))
        offsets[k] += n
    return out


_LOADED: dict[str, tuple] = {}


def _export(core, static, in_tree, in_layout, options, traces, path: Path):
    """Trace ``core`` once into a serialised program whose inputs are the problem's arrays and then the
    options' numeric settings (``options = (static part, treedef, count)``)."""
    out_layout = []
    o_static, o_tree, o_count = options

    def flat(f, i):
        xs = unpack((f, i), in_layout, jax.numpy)
        split = len(xs) - o_count
        problem = eqx.combine(jax.tree.unflatten(in_tree, xs[:split]), static)
        opts = eqx.combine(jax.tree.unflatten(o_tree, xs[split:]), o_static)
        outs = jax.tree.leaves(core(problem, opts, traces))
        out_layout[:] = [(tuple(o.shape), str(o.dtype)) for o in outs]
        return pack(outs, jax.numpy)

    bufs = pack([np.zeros(s, d) for s, d in in_layout])
    exported = jax.export.export(jax.jit(flat))(*[jax.ShapeDtypeStruct(b.shape, b.dtype) for b in bufs])
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_bytes(json.dumps([[list(s), d] for s, d in out_layout]).encode() + b"\n" + exported.serialize())
        os.replace(tmp, path)
    except OSError:
        pass  # a read-only cache: solve anyway
    return exported, out_layout


def _load(path: Path):
    try:
        head, _, body = path.read_bytes().partition(b"\n")
        layout = [(tuple(s), d) for s, d in json.loads(head)]
        return jax.export.deserialize(bytearray(body)), layout
    except Exception:  # noqa: BLE001 - a damaged or foreign file: trace again
        return None


def run(core, problem: Problem, options, traces: bool, out_treedef):
    """``core(problem, options, traces)`` through the cache of traced solves (see the module docstring).

    Inputs and outputs travel packed in two buffers each. Returns the host copy of the output pytree
    (structure ``out_treedef``), or None when the problem cannot be cached (the caller then uses its plain
    jitted function).
    """
    folder = cache_dir()
    if folder is None:
        return None
    dyn, static = eqx.partition(problem, eqx.is_array)
    leaves, in_tree = jax.tree.flatten(dyn)
    # the options' tolerances and iteration limit are inputs of the program, not part of its key
    o_dyn, o_static = eqx.partition(options.traced(), eqx.is_array)
    o_leaves, o_tree = jax.tree.flatten(o_dyn)
    key = structure_key(problem, o_static, traces, leaves, in_tree)
    if key is None:
        return None
    entry = _LOADED.get(key)
    if entry is None:
        path = folder / f"{key}.jax"
        loaded = _load(path) if path.is_file() else None
        if loaded is None:
            in_layout = [(tuple(np.shape(x)), str(np.asarray(x).dtype)) for x in [*leaves, *o_leaves]]
            loaded = _export(core, static, in_tree, in_layout, (o_static, o_tree, len(o_leaves)), traces, path)
        exported, out_layout = loaded
        entry = (jax.jit(exported.call), out_layout)
        _LOADED[key] = entry
    fn, out_layout = entry
    bufs = jax.device_get(fn(*pack([np.asarray(x) for x in [*leaves, *o_leaves]])))
    return jax.tree.unflatten(out_treedef, unpack(bufs, out_layout))
