"""Run whole episodes under ``lax.scan`` (jit- and vmap-friendly): the one rollout loop that
evaluation, the success tables, the figures, ``Robot.perform``, the goal switch and the
exploration-knock measurement share."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from grounding_jax.sim.env import DEFAULT_PARAMS, Env, EnvParams, State, Task

Policy = Callable[[State], jax.Array]
#: ``(state, x) -> (action, aux)``: ``x`` is this step's slice of ``xs``; ``aux`` is stacked
StepPolicy = Callable[[State, Any], tuple[jax.Array, Any]]


def rollout(env: Env, first: State, policy: StepPolicy, steps: int,
            params: EnvParams = DEFAULT_PARAMS, xs: Any = None,
            switch: tuple[int, Task] | None = None) -> tuple[State, Any]:
    """Step ``steps`` times from ``first``.

    Args:
        env: the environment.
        first: the state to start from (e.g. ``env.reset(...)``).
        policy: ``(state, x) -> (action, aux)``.
        steps: number of steps (static).
        params: env parameters (traced).
        xs: per-step inputs for the policy (leading axis ``steps``), e.g. exploration keys.
        switch: ``(t, task)``: the goal becomes ``task`` (``env.set_task``) before step ``t``.

    Returns:
        (states after each step, ``aux`` of each step), stacked along a leading time axis.
    """
    def body(state: State, tx):
        t, x = tx
        if switch is not None:
            at, task = switch
            state = jax.lax.cond(t == at, lambda s: env.set_task(s, task), lambda s: s, state)
        action, aux = policy(state, x)
        state = env.step(state, action, params)
        return state, (state, aux)

    _, (traj, aux) = jax.lax.scan(body, first, (jnp.arange(steps), xs), length=steps)
    return traj, aux


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
    first = env.reset(key, task, params)
    traj, _ = rollout(env, first, lambda s, _: (policy(s), None), n, params)
    return first, traj
