"""`import jcalib` adds its XLA:CPU compile flag only where the installed jaxlib knows it.

XLA aborts the whole process on a flag it does not know (jaxlib 0.11.2 dropped
``--xla_cpu_use_fusion_emitters``: "Unknown flag in XLA_FLAGS", SIGABRT at the first computation).
"""

import ast
import os
import subprocess
import sys

import jcalib

FLAG = "--xla_cpu_use_fusion_emitters=false"


def test_the_flag_is_added_only_for_the_checked_jaxlib_versions():
    assert jcalib._default_xla_flags("", (0, 10)) == [FLAG]
    for other in [(0, 11), (0, 9), (0, 4), (1, 0), None]:
        assert jcalib._default_xla_flags("", other) == [], other


def test_a_flag_the_user_names_wins():
    assert jcalib._default_xla_flags("--xla_cpu_use_fusion_emitters=true", (0, 10)) == []
    assert jcalib._default_xla_flags("--xla_backend_optimization_level=0", (0, 10)) == [FLAG]


def test_a_fresh_process_computes_with_the_flags_jcalib_chose():
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JCALIB_XLA_DEFAULTS")}
    code = ("import os, jcalib, jax.numpy as jnp; print(repr(os.environ.get('XLA_FLAGS'))); "
            "print(float(jnp.sum(jnp.arange(4.0))))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    flags, total = out.stdout.split("\n")[:2]
    assert total == "6.0"
    expected = FLAG if jcalib._jaxlib_version() == (0, 10) else None
    assert ast.literal_eval(flags) == expected


def test_the_version_read_without_importing_jaxlib_is_jaxlibs_own():
    import jaxlib

    assert jcalib._jaxlib_version() == tuple(int(x) for x in jaxlib.__version__.split(".")[:2])
