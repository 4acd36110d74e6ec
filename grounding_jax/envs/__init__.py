"""Registered envs in the Brax / MuJoCo Playground shape, and adapters to Brax and gymnasium.

```python
from grounding_jax import envs
env = envs.load("paper")                 # or "free", "paper_touch", ... (envs.names())
state = env.reset(jax.random.key(0))     # a task drawn by the env's TaskSampler
state = env.step(state, jnp.zeros(env.action_size))
brax_env = envs.to_brax(env)             # pip install -e '.[brax]'
vec = envs.to_gymnasium(env, num_envs=8) # pip install -e '.[gym]'
```
"""

from __future__ import annotations

from typing import Any

from grounding_jax.envs.registry import (
    EnvState,
    TaskEnv,
    TaskEnvConfig,
    describe,
    get_default_config,
    load,
    names,
    register,
)
from grounding_jax.sim.sampler import TaskSampler


def to_brax(env: TaskEnv) -> Any:
    """``env`` as a ``brax.envs.base.Env`` (needs the ``brax`` extra); see
    `grounding_jax.envs.brax_adapter.to_brax`."""
    from grounding_jax.envs import brax_adapter as adapter

    return adapter.to_brax(env)


def to_gymnasium(env: TaskEnv, num_envs: int = 1, seed: int = 0) -> Any:
    """``env`` as a ``gymnasium.vector.VectorEnv`` of ``num_envs`` copies (needs the ``gym``
    extra); see `grounding_jax.envs.gym_adapter.to_gymnasium`."""
    from grounding_jax.envs import gym_adapter as adapter

    return adapter.to_gymnasium(env, num_envs, seed)


__all__ = ["EnvState", "TaskEnv", "TaskEnvConfig", "TaskSampler", "describe",
           "get_default_config", "load", "names", "register", "to_brax", "to_gymnasium"]
