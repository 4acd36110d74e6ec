"""A registered env as a gymnasium env: NumPy in and out, for CleanRL-style loops.

Needs the ``gym`` extra (``pip install -e '.[gym]'``). `to_gymnasium` gives a
``gymnasium.vector.VectorEnv`` of ``num_envs`` episodes stepped together in one compiled
call (each with its own task; an episode that ends is restarted with a fresh task at the next
step, gymnasium's ``NEXT_STEP`` autoreset), and `to_gymnasium_env` one episode at a time as
a ``gymnasium.Env``. The ids ``grounding_jax/<name>-v0`` (``gymnasium.make``) give the
latter for every registered name.

An episode is *terminated* when a wrong object moved, *truncated* at the time limit
(``episode_length`` steps).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.envs import registry
from grounding_jax.envs.registry import TaskEnv

try:
    import gymnasium
    from gymnasium import spaces
    from gymnasium.vector import AutoresetMode, VectorEnv
except ImportError as err:  # pragma: no cover - exercised without the extra
    raise ImportError("grounding_jax.envs.to_gymnasium needs gymnasium: pip install -e "
                      "'.[gym]' (or pip install 'grounding-jax[gym]')") from err


def _spaces(env: TaskEnv) -> tuple[spaces.Box, spaces.Box]:
    obs = spaces.Box(-np.inf, np.inf, (env.observation_size,), np.float32)
    act = spaces.Box(-1.0, 1.0, (env.action_size,), np.float32)
    return obs, act


class _Batch:
    """The compiled batch under both views: reset, and step-with-autoreset."""

    def __init__(self, env: TaskEnv) -> None:
        self.env = env

        def reset(keys):
            return jax.vmap(env.reset)(keys)

        def step(states, actions, restart, keys):
            stepped = jax.vmap(env.step)(states, actions)
            # the episodes that ended at the last step start again instead (a fresh task)
            new = jax.vmap(env.reset_done)(stepped.replace(done=restart.astype(jnp.float32)),
                                           keys)
            inner = new.pipeline_state
            ended = inner.done & ~restart
            terminated = ended & (inner.wrong_since >= 0)
            return new, terminated, ended & ~terminated

        self.reset = jax.jit(reset)
        self.step = jax.jit(step)


@functools.lru_cache(maxsize=8)
def _batch(env: TaskEnv) -> _Batch:
    return _Batch(env)


class GymVectorEnv(VectorEnv):
    """``num_envs`` episodes of a `TaskEnv`, stepped together (see the module doc)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, env: TaskEnv, num_envs: int, seed: int = 0) -> None:
        if not isinstance(num_envs, int) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"num_envs: expected an integer >= 1, got {num_envs!r}")
        self.env, self.num_envs = env, num_envs
        self.single_observation_space, self.single_action_space = _spaces(env)
        self.observation_space = spaces.Box(-np.inf, np.inf, (num_envs, env.observation_size),
                                            np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (num_envs, env.action_size), np.float32)
        self._batch = _batch(env)
        self._key = jax.random.key(seed)
        self._state = None
        self._restart = np.zeros(num_envs, bool)

    def _keys(self) -> jax.Array:
        self._key, k = jax.random.split(self._key)
        return jax.random.split(k, self.num_envs)

    def reset(self, *, seed: int | None = None, options: dict | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start every episode (``seed`` restarts the env's key)."""
        if seed is not None:
            self._key = jax.random.key(seed)
        self._state = self._batch.reset(self._keys())
        self._restart = np.zeros(self.num_envs, bool)
        return np.asarray(self._state.obs), {}

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                          dict[str, Any]]:
        """One step of every episode; those that ended at the last step restart."""
        if self._state is None:
            raise RuntimeError("step: call reset() first")
        actions = np.asarray(actions, np.float32).reshape(self.action_space.shape)
        restart = jnp.asarray(self._restart)
        self._state, term, trunc = self._batch.step(self._state, actions, restart,
                                                    self._keys())
        term, trunc = np.asarray(term), np.asarray(trunc)
        self._restart = term | trunc
        reward = np.where(np.asarray(restart), 0.0, np.asarray(self._state.reward))
        reward = reward.astype(np.float32)
        return np.asarray(self._state.obs), reward, term, trunc, {}


class GymEnv(gymnasium.Env):
    """One episode at a time of a `TaskEnv` (the view gymnasium's env checker tests)."""

    metadata = {"render_modes": []}

    def __init__(self, env: TaskEnv) -> None:
        self._vec = GymVectorEnv(env, 1)
        self.observation_space = self._vec.single_observation_space
        self.action_space = self._vec.single_action_space

    def reset(self, *, seed: int | None = None, options: dict | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is None and self._vec._state is None:
            seed = int(self.np_random.integers(2**31))
        obs, info = self._vec.reset(seed=seed)
        return obs[0], info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, reward, term, trunc, info = self._vec.step(np.asarray(action)[None])
        return obs[0], float(reward[0]), bool(term[0]), bool(trunc[0]), info


def to_gymnasium(env: TaskEnv, num_envs: int = 1, seed: int = 0) -> GymVectorEnv:
    """``env`` (from `grounding_jax.envs.load`) as a ``gymnasium.vector.VectorEnv``.

    Raises:
        ValueError: ``env`` is not a registered env, or ``num_envs`` is not >= 1.
    """
    if not isinstance(env, TaskEnv):
        raise ValueError(f"env: expected a registered env (grounding_jax.envs.load(name)), "
                         f"got {type(env).__name__}")
    return GymVectorEnv(env, num_envs, seed)


def to_gymnasium_env(env: TaskEnv) -> GymEnv:
    """``env`` as a single ``gymnasium.Env`` (NumPy in and out)."""
    if not isinstance(env, TaskEnv):
        raise ValueError(f"env: expected a registered env (grounding_jax.envs.load(name)), "
                         f"got {type(env).__name__}")
    return GymEnv(env)


def _make(name: str, **overrides: Any) -> GymEnv:
    return GymEnv(registry.load(name, config_overrides=overrides or None))


for _name in registry.names():
    _id = f"grounding_jax/{_name}-v0"
    if _id not in gymnasium.registry:
        gymnasium.register(_id, entry_point=functools.partial(_make, _name))
