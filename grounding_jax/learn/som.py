"""Self-organizing map on a torus (wrap-around neighbourhood), batch training in JAX.

Used to show that the actor's hidden activations cluster by action and by position (the
paper's Fig 12).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core.checks import Rule, check_config, integer_at_least

#: What each count of `SOMConfig` accepts (its ``__post_init__`` reads it).
CONFIG_RULES: dict[str, Rule] = {name: integer_at_least(1) for name in ("rows", "cols", "epochs")}


@dataclasses.dataclass(frozen=True)
class SOMConfig:
    """Static configuration: grid ``rows x cols`` on a torus, ``epochs`` of batch updates,
    Gaussian neighbourhood radius decaying geometrically from ``sigma_start`` to ``sigma_end``
    (grid cells)."""

    rows: int = 12
    cols: int = 12
    epochs: int = 30
    sigma_start: float = 4.0
    sigma_end: float = 0.7

    def __post_init__(self) -> None:
        check_config(self, CONFIG_RULES)
        if not 0 < self.sigma_end <= self.sigma_start:
            raise ValueError(f"sigma_start/sigma_end: need 0 < sigma_end <= sigma_start, got "
                             f"{self.sigma_start!r}, {self.sigma_end!r}")


def grid(config: SOMConfig) -> jax.Array:
    """Cell coordinates ``[rows * cols, 2]`` (row, col), row-major."""
    r, c = jnp.meshgrid(jnp.arange(config.rows), jnp.arange(config.cols), indexing="ij")
    return jnp.stack([r.ravel(), c.ravel()], axis=1).astype(jnp.float32)


def torus_distance(a: jax.Array, b: jax.Array, rows: int, cols: int) -> jax.Array:
    """Euclidean distance between cells ``a`` and ``b`` ([..., 2]) on a rows x cols torus."""
    d = jnp.abs(a - b)
    d = jnp.minimum(d, jnp.array([rows, cols], d.dtype) - d)
    return jnp.sqrt(jnp.sum(d * d, axis=-1))


@jax.jit
def bmu(weights: jax.Array, x: jax.Array) -> jax.Array:
    """Best-matching unit of each sample: ``[N]`` indices into the cells."""
    d = (jnp.sum(x * x, 1)[:, None] - 2 * x @ weights.T + jnp.sum(weights * weights, 1)[None])
    return jnp.argmin(d, axis=1)


@functools.partial(jax.jit, static_argnames='config')
def train(key: jax.Array, data: jax.Array, config: SOMConfig = SOMConfig()) -> jax.Array:
    """Batch SOM: each epoch, every cell moves to the neighbourhood-weighted mean of the data.

    Args:
        key: PRNG key (initial weights: random samples of the data).
        data: ``[N, D]``.
        config: grid and schedule.

    Returns:
        Weights ``[rows * cols, D]``.
    """
    if data.ndim != 2 or data.shape[0] < 1:
        raise ValueError(f"data: expected a non-empty [N, D] array, got shape {data.shape}")
    cells = grid(config)
    n_cells = cells.shape[0]
    w0 = data[jax.random.randint(key, (n_cells,), 0, data.shape[0])]
    dist = torus_distance(cells[:, None], cells[None], config.rows, config.cols)
    sigmas = config.sigma_start * (config.sigma_end / config.sigma_start) ** (
        jnp.arange(config.epochs) / max(config.epochs - 1, 1))

    def epoch(w, sigma):
        h = jnp.exp(-dist[bmu(w, data)] ** 2 / (2 * sigma**2))  # [N, cells]
        num = h.T @ data
        den = jnp.sum(h, axis=0)[:, None]
        return jnp.where(den > 1e-8, num / jnp.maximum(den, 1e-8), w), None

    return jax.lax.scan(epoch, w0, sigmas)[0]


def purity(units: np.ndarray, labels: np.ndarray) -> float:
    """Share of samples whose label is their unit's majority label (1 = pure clusters)."""
    units, labels = np.asarray(units), np.asarray(labels)
    total = 0
    for u in np.unique(units):
        total += np.bincount(labels[units == u]).max()
    return float(total / len(labels))
