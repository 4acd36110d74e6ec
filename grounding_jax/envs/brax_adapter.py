"""A registered env as a ``brax.envs.base.Env``, for Brax's trainers and wrappers.

Needs the ``brax`` extra (``pip install -e '.[brax]'``). The adapter keeps the project's
`State` as Brax's ``pipeline_state`` and runs the same physics, on the C MuJoCo backend (the
CPU path, through JAX's FFI) or on MJX::

    from brax.training.agents.ppo import train as ppo
    env = envs.to_brax(envs.load("paper"))
    make_policy, params, metrics = ppo.train(env, num_timesteps=100_000,
                                             episode_length=env.episode_length, ...)

``done`` is 1.0 only when the episode *terminates* (a wrong object moved); the time limit is
Brax's ``episode_length`` (pass ``env.episode_length``, 75 steps as in the paper), which
marks its end as a truncation, so that PPO and SAC bootstrap through it.
"""

from __future__ import annotations

import importlib
from typing import Any

import jax
import jax.numpy as jnp

from grounding_jax.envs.registry import TaskEnv

try:
    from brax.envs import base as _brax_base
except ImportError as err:  # pragma: no cover - exercised without the extra
    raise ImportError("grounding_jax.envs.to_brax needs Brax: pip install -e '.[brax]' "
                      "(or pip install 'grounding-jax[brax]')") from err


def _restore_for_brax() -> None:
    """Brax 0.14 calls ``jax.device_put_replicated`` and ``device_put_sharded``, which JAX
    0.10 turned into errors while still shipping them; put them back for Brax's trainers."""
    api = importlib.import_module("jax._src.api")
    for name in ("device_put_replicated", "device_put_sharded"):
        try:
            getattr(jax, name)
        except AttributeError:
            if hasattr(api, name):
                setattr(jax, name, getattr(api, name))


_restore_for_brax()


def _terminated(inner: Any) -> jax.Array:
    return (inner.done & (inner.wrong_since >= 0)).astype(jnp.float32)


class BraxEnv(_brax_base.Env):
    """A `TaskEnv` behind Brax's ``Env`` interface (``reset(rng)``, ``step(state, action)``).

    Attributes:
        env: the `TaskEnv` it runs.
        episode_length: the env's episode length, to pass to Brax's trainers.
    """

    def __init__(self, env: TaskEnv) -> None:
        if not isinstance(env, TaskEnv):
            raise ValueError(f"env: expected a registered env (grounding_jax.envs.load(name)), "
                             f"got {type(env).__name__}")
        self.env = env
        self.episode_length = env.episode_length

    def reset(self, rng: jax.Array) -> _brax_base.State:
        s = self.env.reset(rng)
        return _brax_base.State(pipeline_state=s.pipeline_state, obs=s.obs, reward=s.reward,
                                done=_terminated(s.pipeline_state), metrics=dict(s.metrics),
                                info=dict(s.info))

    def step(self, state: _brax_base.State, action: jax.Array) -> _brax_base.State:
        inner = self.env.unwrapped.step(state.pipeline_state, action, self.env.config.params)
        info = {**state.info, **inner.info}
        return state.replace(pipeline_state=inner, obs=inner.obs, reward=inner.reward,
                             done=_terminated(inner), metrics={**state.metrics, **inner.metrics},
                             info=info)

    @property
    def observation_size(self) -> int:
        return self.env.observation_size

    @property
    def action_size(self) -> int:
        return self.env.action_size

    @property
    def backend(self) -> str:
        return self.env.backend

    @property
    def dt(self) -> float:
        """Seconds of simulated time per step."""
        return self.env.dt


def to_brax(env: TaskEnv) -> BraxEnv:
    """``env`` (from `grounding_jax.envs.load`) as a ``brax.envs.base.Env``.

    Raises:
        ValueError: ``env`` is not a registered env.
    """
    return BraxEnv(env)
