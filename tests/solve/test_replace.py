"""``jcalib.solve.replace``: a field copy of an equinox module, as ``eqx.tree_at`` makes it."""

import equinox as eqx
import jax
import numpy as np
import pytest

from jcalib.solve import SE3, Variable, replace


def test_replace_equals_tree_at_and_leaves_the_original():
    v = Variable("pose", SE3(), np.tile([1.0, 0, 0, 0, 0.1, 0.2, 0.3], (3, 1)))
    value = np.tile([1.0, 0, 0, 0, 0.4, 0.5, 0.6], (3, 1))
    fixed = np.zeros((3, 6), bool)
    fixed[1] = True
    a = replace(v, value=value, fixed=fixed)
    b = eqx.tree_at(lambda w: (w.value, w.fixed), v, (value, fixed))
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(x, y)
    assert a.name == "pose" and not np.any(v.fixed) and v.value[0, 4] == 0.1  # the original is unchanged


def test_replace_refuses_a_field_the_module_lacks():
    v = Variable("pose", SE3(), np.tile([1.0, 0, 0, 0, 0, 0, 0], (2, 1)))
    with pytest.raises(TypeError, match="no field"):
        replace(v, valeu=np.zeros((2, 7)))
