"""Pytree bookkeeping as one compiled program per tree shape.

Slicing every leaf of a pytree on the host runs one eager operation (one small XLA program)
per leaf and index form; these helpers do the same in a single jitted call, shared by every
caller whose trees have the same structure and shapes.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp


@jax.jit
def _take(tree: Any, i: jax.Array) -> Any:
    return jax.tree.map(lambda x: x[i], tree)


def take(tree: Any, i: int) -> Any:
    """Row ``i`` of every leaf (``tree[i]`` leaf by leaf); IndexError when out of range."""
    n = len(jax.tree.leaves(tree)[0])
    if not -n <= int(i) < n:
        raise IndexError(f"index {i} is out of range for a batch of {n}")
    return _take(tree, jnp.int32(int(i) % n))


@jax.jit
def add_axis(tree: Any) -> Any:
    """Every leaf with a new leading axis of size 1 (a batch of one)."""
    return jax.tree.map(lambda x: x[None], tree)


@jax.jit
def put_columns(into: Any, values: Any, start: jax.Array) -> Any:
    """``into`` with columns ``start:start + width`` of every leaf replaced by ``values``'s
    (leaves ``[rows, columns, ...]``)."""
    return jax.tree.map(lambda a, b: jax.lax.dynamic_update_slice_in_dim(
        a, b.astype(a.dtype), start, axis=1), into, values)


def zeros_columns(like: Any, columns: int) -> Any:
    """Zeros ``[rows, columns, ...]`` per leaf of ``like`` (leaves ``[rows, any, ...]``),
    of its dtypes, made on the host."""
    import numpy as np

    return jax.tree.map(lambda x: np.zeros(x.shape[:1] + (columns,) + x.shape[2:], x.dtype),
                        like)
