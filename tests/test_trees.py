"""The pytree helpers: the same answers as leaf-by-leaf indexing, in one program per shape."""

import jax.numpy as jnp
import numpy as np
import pytest

from grounding_jax.core import compiles, trees

TREE = {"a": jnp.arange(6.0).reshape(3, 2), "b": jnp.arange(3)}


def test_take_matches_indexing_and_refuses_out_of_range():
    for i in (0, 2, -1):
        got = trees.take(TREE, i)
        np.testing.assert_array_equal(got["a"], np.asarray(TREE["a"])[i])
        assert int(got["b"]) == int(np.asarray(TREE["b"])[i])
    with pytest.raises(IndexError, match="out of range"):
        trees.take(TREE, 3)


def test_take_builds_one_program_for_every_index():
    compiles.install()
    trees.take(TREE, 0)
    before = compiles.tally()
    for i in (1, 2, -2):
        trees.take(TREE, i)
    assert (compiles.tally() - before).programs == 0


def test_add_axis_and_put_columns():
    one = trees.add_axis(TREE)
    assert one["a"].shape == (1, 3, 2) and one["b"].shape == (1, 3)
    into = trees.zeros_columns({"m": np.ones((2, 1), np.float32)}, 5)
    assert into["m"].shape == (2, 5) and into["m"].dtype == np.float32
    out = trees.put_columns(into, {"m": jnp.full((2, 2), 7.0)}, 3)
    np.testing.assert_array_equal(out["m"], [[0, 0, 0, 7, 7], [0, 0, 0, 7, 7]])
