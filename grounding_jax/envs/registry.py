"""Named envs in the shape of Brax and MuJoCo Playground: ``load(name) -> TaskEnv``.

A `TaskEnv` is the project's `Env` (the same physics, rewards and episode end the AL
trainer uses) with a `TaskSampler` and default `EnvParams` attached, so that
``reset(rng)`` draws a task by itself and ``step(state, action)`` needs nothing else. Its
`EnvState` has the fields Brax's wrappers read: ``pipeline_state`` (the project's `State`:
joints, velocities, sensors, task), ``obs``, ``reward``, ``done`` (float32, 1.0 once the
episode has ended), ``metrics`` and ``info``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from grounding_jax.sim import tasks
from grounding_jax.sim.env import DEFAULT_PARAMS, Env, EnvConfig, EnvParams, State, Task
from grounding_jax.sim.sampler import TaskSampler


@dataclasses.dataclass(frozen=True)
class TaskEnvConfig:
    """A registered env's configuration.

    Attributes:
        env: the static `EnvConfig` (backend, substeps, episode length, task set).
        sampler: the `TaskSampler` that ``reset(rng)`` draws tasks with (static).
        params: the default traced `EnvParams` (``step`` and ``reset`` take others).
    """

    env: EnvConfig = EnvConfig()
    sampler: TaskSampler = TaskSampler()
    params: EnvParams = DEFAULT_PARAMS

    def __post_init__(self) -> None:
        self.sampler.check(self.env.tasks)
        self.params.validate()

    def replace(self, overrides: Mapping[str, Any] | None) -> TaskEnvConfig:
        """This config with flat field overrides: each name is a field of `EnvConfig`,
        `TaskSampler` or `EnvParams` (``{"backend": "mjx", "start_noise": 0.2}``).

        Raises:
            ValueError: a name none of them has, listing the accepted names.
        """
        parts: dict[str, dict[str, Any]] = {p: {} for p in _PARTS}
        for name, value in (overrides or {}).items():
            owner = next((p for p, t in _PARTS.items() if name in _fields(t)), None)
            if owner is None:
                accepted = sorted(n for t in _PARTS.values() for n in _fields(t))
                raise ValueError(f"config_overrides: unknown field {name!r}; accepted fields: "
                                 f"{accepted}")
            parts[owner][name] = value
        return TaskEnvConfig(
            env=dataclasses.replace(self.env, **parts["env"]),
            sampler=dataclasses.replace(self.sampler, **parts["sampler"]),
            params=self.params.replace(**parts["params"]))


_PARTS = {"env": EnvConfig, "sampler": TaskSampler, "params": EnvParams}


def _fields(cls: type) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(cls))


@struct.dataclass
class EnvState:
    """One step of a `TaskEnv`, in Brax's ``State`` layout.

    Attributes:
        pipeline_state: the project's `State` (physics state, task, counters).
        obs: the observation ``[observation_size]``.
        reward: this step's reward.
        done: 1.0 once the episode has ended (absorbing), else 0.0.
        metrics: per-step scalars (the reward's terms, ``nan_actions``, ``invalid``).
        info: the palm's position and force and the joints' servo targets.
    """

    pipeline_state: State
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    metrics: dict[str, jax.Array]
    info: dict[str, jax.Array]


def _wrap(inner: State) -> EnvState:
    return EnvState(pipeline_state=inner, obs=inner.obs, reward=inner.reward,
                    done=inner.done.astype(jnp.float32), metrics=dict(inner.metrics),
                    info=dict(inner.info))


class TaskEnv:
    """A registered env: ``reset(rng)``, ``step(state, action)`` and the sizes.

    Attributes:
        name: its registry name.
        config: its `TaskEnvConfig`.
        unwrapped: the project's `Env` underneath (explicit tasks, ``set_task``, judging).
    """

    def __init__(self, name: str, config: TaskEnvConfig) -> None:
        self.name = name
        self.config = config
        self.unwrapped = Env(config.env)
        self.sampler = config.sampler

    @property
    def observation_size(self) -> int:
        """Units of the observation."""
        return self.unwrapped.tasks.obs_size

    @property
    def action_size(self) -> int:
        """Units of the action (each in [-1, 1])."""
        return self.unwrapped.tasks.action_size

    @property
    def backend(self) -> str:
        """The physics backend: ``"mujoco"`` (C MuJoCo, CPU) or ``"mjx"``."""
        return self.config.env.backend

    @property
    def dt(self) -> float:
        """Seconds of simulated time per step."""
        return self.unwrapped.dt

    @property
    def episode_length(self) -> int:
        """Steps after which an episode ends (sooner when a wrong object moves)."""
        return self.config.env.episode_length

    @property
    def task_set(self) -> tasks.TaskSet:
        """The `tasks.TaskSet` (actions, rewards, observation layout)."""
        return self.unwrapped.tasks

    def sample_task(self, rng: jax.Array) -> Task:
        """The task ``reset(rng)`` starts: the config's `TaskSampler` on the first half of
        ``rng``'s split."""
        return self.sampler.sample(jax.random.split(rng)[0])

    def reset(self, rng: jax.Array, params: EnvParams | None = None) -> EnvState:
        """A new episode with a task drawn from the config's sampler."""
        k_task, k_reset = jax.random.split(rng)
        return self.reset_task(k_reset, self.sampler.sample(k_task), params)

    def reset_task(self, rng: jax.Array, task: Task, params: EnvParams | None = None
                   ) -> EnvState:
        """A new episode with a given task (`grounding_jax.make_task`)."""
        return _wrap(self.unwrapped.reset(rng, task, self._params(params)))

    def step(self, state: EnvState, action: jax.Array, params: EnvParams | None = None
             ) -> EnvState:
        """One step; a finished episode stays as it ended."""
        return _wrap(self.unwrapped.step(state.pipeline_state, action, self._params(params)))

    def reset_done(self, state: EnvState, rng: jax.Array, params: EnvParams | None = None
                   ) -> EnvState:
        """Auto-reset with a fresh task: ``reset(rng)`` where ``state.done``, ``state``
        elsewhere (under ``vmap``, per env; the C backend simulates only the resets)."""
        k_task, k_reset = jax.random.split(rng)
        inner = self.unwrapped.reset_where(state.done > 0.5, state.pipeline_state, k_reset,
                                           self.sampler.sample(k_task), self._params(params))
        return _wrap(inner)

    def _params(self, params: EnvParams | None) -> EnvParams:
        return self.config.params if params is None else params

    def __repr__(self) -> str:
        return (f"TaskEnv({self.name!r}, backend={self.backend!r}, observation_size="
                f"{self.observation_size}, action_size={self.action_size})")


@dataclasses.dataclass(frozen=True)
class _Entry:
    make_config: Callable[[], TaskEnvConfig]
    doc: str


_ENVS: dict[str, _Entry] = {}


def register(name: str, make_config: Callable[[], TaskEnvConfig], doc: str = "") -> None:
    """Register an env under ``name``: ``make_config()`` gives its default config.

    Raises:
        ValueError: the name is taken.
    """
    if name in _ENVS:
        raise ValueError(f"name: an env named {name!r} is already registered")
    _ENVS[name] = _Entry(make_config, doc)


def names() -> tuple[str, ...]:
    """The registered env names."""
    return tuple(_ENVS)


def describe(name: str) -> str:
    """One line on what the env ``name`` is."""
    return _entry(name).doc


def _entry(name: str) -> _Entry:
    if name not in _ENVS:
        raise ValueError(f"name: unknown env {name!r}; accepted values: {names()}")
    return _ENVS[name]


def get_default_config(name: str) -> TaskEnvConfig:
    """The default `TaskEnvConfig` of the env ``name``."""
    return _entry(name).make_config()


def load(name: str, config: TaskEnvConfig | None = None,
         config_overrides: Mapping[str, Any] | None = None) -> TaskEnv:
    """The env ``name`` with ``config`` (default: its own) and flat ``config_overrides``
    (field names of `EnvConfig`, `TaskSampler` and `EnvParams`).

    Raises:
        ValueError: an unknown name or override field (listing the accepted ones), or a
            bad value (naming its field).
    """
    base = get_default_config(name) if config is None else config
    if not isinstance(base, TaskEnvConfig):
        raise ValueError(f"config: expected a TaskEnvConfig (get_default_config({name!r})), "
                         f"got {type(base).__name__}")
    return TaskEnv(name, base.replace(config_overrides))


def _builtin(task_set: str, placement: str, actions: tuple[int, ...] = (0, 1, 2)
             ) -> Callable[[], TaskEnvConfig]:
    def make() -> TaskEnvConfig:
        return TaskEnvConfig(env=EnvConfig(task_set=task_set),
                             sampler=TaskSampler(actions=actions, placement=placement))
    return make


register("paper", _builtin("paper", "fixed"),
         "the paper's 9 tasks: point/touch/push at the left, middle or right slot, 36 layouts")
register("free", _builtin("free", "random"),
         "objects anywhere on the reachable table; the target's (x, y) in the observation")
register("free_hand", _builtin("free_hand", "random"),
         "as 'free', with the palm's offset to the target in the observation too")
for _i, _action in enumerate(tasks.PAPER.action_names):
    register(f"paper_{_action}", _builtin("paper", "fixed", (_i,)),
             f"'paper' with only the {_action} action")
    register(f"free_{_action}", _builtin("free", "random", (_i,)),
             f"'free' with only the {_action} action")
