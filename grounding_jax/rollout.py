"""Run whole episodes under ``lax.scan`` (jit- and vmap-friendly)."""

from __future__ import annotations

from collections.abc import Callable

import jax

from grounding_jax.env import DEFAULT_PARAMS, Env, EnvParams, State, Task

Policy = Callable[[State], jax.Array]


def run_episode(env: Env, key: jax.Array, task: Task, policy: Policy,
                params: EnvParams = DEFAULT_PARAMS, steps: int | None = None
                ) -> tuple[State, State]:
    """Reset, then step ``steps`` times (default: the episode length) with ``policy(state)``.

    Args:
        env: the environment.
        key: PRNG key for the reset.
        task: the task.
        policy: a pure function of the current state returning the action.
        params: env parameters (traced).
        steps: number of steps (static).

    Returns:
        (initial state, states after each step stacked along a leading time axis).
    """
    n = env.config.episode_length if steps is None else steps

    def body(state: State, _):
        state = env.step(state, policy(state), params)
        return state, state

    first = env.reset(key, task, params)
    _, traj = jax.lax.scan(body, first, None, length=n)
    return first, traj
