"""Echo-state network (ESN) of the action namer, as pure functions.

A linear reservoir, ``x_{t+1} = W_in u_t + W x_t``, with ``W_in ~ U[-1, 1]`` and a sparse
``W`` (a fixed share of non-zero entries) scaled to a given spectral radius; a linear readout
``y_t = W_out x_t`` fitted in one shot by the pseudo-inverse over all time steps,
``W_out = (X^+ D)^T`` (paper, section 2.3), with an optional ridge term.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from grounding_jax.core.checks import Rule, check_config, integer_at_least
from grounding_jax.sim import tasks

N_ACTIONS, N_WORDS = tasks.N_ACTIONS, tasks.N_WORDS  # the paper's task set


#: What each size of `ESNConfig` accepts (its ``__post_init__`` reads it).
CONFIG_RULES: dict[str, Rule] = {name: integer_at_least(1) for name in ("n_in", "n_res", "n_out")}


@dataclasses.dataclass(frozen=True)
class ESNConfig:
    """Static configuration.

    Attributes:
        n_in: input units (paper: 40 actor hidden + 50 TL hidden = 90).
        n_res: reservoir units (paper: 50).
        n_out: output units: one per action word of the task set and one per target word
            (paper: 3 + 6 = 9); None (the default) takes it from ``task_set``.
        spectral_radius: of the reservoir matrix (paper: 0.9).
        connectivity: share of non-zero reservoir weights, in (0, 1] (paper: 0.2).
        task_set: name of the `tasks.TaskSet` whose actions the namer names.
    """

    n_in: int = 90
    n_res: int = 50
    n_out: int | None = None
    spectral_radius: float = 0.9
    connectivity: float = 0.2
    task_set: str = tasks.PAPER.name

    def __post_init__(self) -> None:
        size = tasks.get(self.task_set).sentence_size
        if self.n_out is None:
            object.__setattr__(self, "n_out", size)
        elif self.n_out != size:
            raise ValueError(f"n_out: must be {size} (the action and target words of task set "
                             f"{self.task_set!r}) or None, got {self.n_out!r}")
        check_config(self, CONFIG_RULES)
        if not np.isfinite(self.spectral_radius) or self.spectral_radius <= 0:
            raise ValueError(f"spectral_radius: must be > 0, got {self.spectral_radius!r}")
        if not 0 < self.connectivity <= 1:
            raise ValueError(f"connectivity: must be in (0, 1], got {self.connectivity!r}")


@struct.dataclass
class ESN:
    """Input and reservoir weights, and the readout (zeros until fitted)."""

    w_in: jax.Array  # [n_in, n_res]
    w_res: jax.Array  # [n_res, n_res]
    w_out: jax.Array  # [n_res, n_out]


@functools.partial(jax.jit, static_argnames='config')
def init(key: jax.Array, config: ESNConfig = ESNConfig()) -> ESN:
    """Draw ``W_in ~ U[-1, 1]`` and a reservoir with exactly ``round(connectivity * n_res^2)``
    non-zero ``U[-1, 1]`` entries, scaled to ``spectral_radius``.

    Args:
        key: PRNG key.
        config: sizes and reservoir shape.

    Returns:
        The ESN with a zero readout.
    """
    k_in, k_w, k_mask = jax.random.split(key, 3)
    n = config.n_res
    w_in = jax.random.uniform(k_in, (config.n_in, n), jnp.float32, -1, 1)
    n_nonzero = max(1, int(round(config.connectivity * n * n)))
    mask = (jax.random.permutation(k_mask, n * n) < n_nonzero).reshape(n, n)
    w = jax.random.uniform(k_w, (n, n), jnp.float32, -1, 1) * mask
    radius = jnp.max(jnp.abs(jnp.linalg.eigvals(w)))  # eigvals runs on the CPU
    w = w * (config.spectral_radius / radius)
    return ESN(w_in=w_in, w_res=w.astype(jnp.float32),
               w_out=jnp.zeros((n, config.n_out), jnp.float32))


def run(esn: ESN, inputs: jax.Array, x0: jax.Array | None = None) -> jax.Array:
    """Reservoir states over time, ``x_{t+1} = u_t W_in + x_t W`` under ``lax.scan``.

    Args:
        esn: the network.
        inputs: ``[T, n_in]``.
        x0: initial state ``[n_res]`` (zeros if None).

    Returns:
        States ``[T, n_res]`` (the state after each input).
    """
    if inputs.ndim != 2 or inputs.shape[1] != esn.w_in.shape[0]:
        raise ValueError(f"inputs: expected shape [T, {esn.w_in.shape[0]}], got {inputs.shape}")
    x0 = jnp.zeros(esn.w_res.shape[0], inputs.dtype) if x0 is None else x0
    return _run(esn.w_in, esn.w_res, x0, inputs)


@jax.jit
def _run(w_in: jax.Array, w_res: jax.Array, x0: jax.Array, inputs: jax.Array) -> jax.Array:
    # jitted at module level: an eager lax.scan builds (and loads) a new executable per call,
    # which a robot naming thousands of episodes ran out of memory on
    def step(x, u):
        x = u @ w_in + x @ w_res
        return x, x

    return jax.lax.scan(step, x0, inputs)[1]


def fit_readout(states: jax.Array, targets: jax.Array, ridge: float = 0.0) -> jax.Array:
    """Readout ``W_out`` [n_res, n_out] from states ``X`` [N, n_res] and targets ``D``
    [N, n_out] (all time steps stacked): ``pinv(X) D``, or ridge regression when ``ridge > 0``.
    """
    if states.ndim != 2 or targets.ndim != 2 or states.shape[0] != targets.shape[0]:
        raise ValueError(f"states/targets: expected [N, n_res] and [N, n_out] with the same N, "
                         f"got {states.shape} and {targets.shape}")
    if ridge < 0:
        raise ValueError(f"ridge: must be >= 0, got {ridge!r}")
    if ridge == 0:
        # Cut singular values only at float precision: the default cut-off scales with the
        # number of rows (all time steps: tens of thousands), which for a linear reservoir
        # drops directions the naming needs (measured: train accuracy 59-97% -> 100%).
        return jnp.linalg.pinv(states, rtol=jnp.finfo(states.dtype).eps) @ targets
    gram = states.T @ states + ridge * jnp.eye(states.shape[1], dtype=states.dtype)
    return jnp.linalg.solve(gram, states.T @ targets)


@jax.jit
def apply(esn: ESN, states: jax.Array) -> jax.Array:
    """The 9 linear outputs for states ``[..., n_res]``."""
    return states @ esn.w_out


@functools.partial(jax.jit, static_argnames='n_actions')
def decode(outputs: jax.Array, n_actions: int = N_ACTIONS) -> tuple[jax.Array, jax.Array]:
    """(action index, target-word index): the top of the first ``n_actions`` units (the
    action words) and the top of the 6 word units after them."""
    return (jnp.argmax(outputs[..., :n_actions], axis=-1),
            jnp.argmax(outputs[..., n_actions:], axis=-1))


@functools.partial(jax.jit, static_argnames='n_actions')
def targets(action: jax.Array, word: jax.Array, n_actions: int = N_ACTIONS) -> jax.Array:
    """One-hot sentence targets ``[..., n_actions + 6]``: the action word and the target word."""
    return jnp.concatenate([jax.nn.one_hot(action, n_actions), jax.nn.one_hot(word, N_WORDS)],
                           axis=-1)
