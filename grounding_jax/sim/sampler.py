"""The task sampler: which task an episode gets, drawn from a key.

`TaskSampler.sample` is the one draw the project's AL trainer makes for each training
episode, and the one a registered env (`grounding_jax.envs`) makes in ``reset(rng)``: an
action and a position (uniform over the allowed ones), a layout (uniform over the 36, or
layout 0 only) and, for objects placed anywhere, a placement (`placement.sample`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from grounding_jax.sim import placement as free
from grounding_jax.sim import scene, tasks
from grounding_jax.sim.env import Task

#: Where the objects stand: the paper's slots, or anywhere on the reachable table.
PLACEMENTS = ("fixed", "random")


@dataclasses.dataclass(frozen=True)
class TaskSampler:
    """What a random task is drawn from (static: it shapes the compiled draw).

    Attributes:
        actions: action indices to draw from (of the task set the env runs).
        positions: position indices (0 left, 1 middle, 2 right) to draw from.
        random_layout: draw the layout from all 36 (else layout 0 always).
        placement: ``"fixed"`` (the paper's slots) or ``"random"`` (one placement per
            task, anywhere on the reachable table).
    """

    actions: tuple[int, ...] = (0, 1, 2)
    positions: tuple[int, ...] = (0, 1, 2)
    random_layout: bool = True
    placement: str = "fixed"

    def __post_init__(self) -> None:
        if self.placement not in PLACEMENTS:
            raise ValueError(f"placement: unknown value {self.placement!r}; accepted values: "
                             f"{PLACEMENTS}")
        for name, n in (("actions", None), ("positions", tasks.N_POSITIONS)):
            v = tuple(int(i) for i in getattr(self, name))
            if not v or any(i < 0 or (n is not None and i >= n) for i in v):
                hint = f" in 0..{n - 1}" if n is not None else " >= 0"
                raise ValueError(f"{name}: must be a non-empty tuple of indices{hint}, got "
                                 f"{getattr(self, name)!r}")
            object.__setattr__(self, name, v)

    def check(self, task_set: tasks.TaskSet) -> TaskSampler:
        """ValueError unless every action is one of ``task_set``'s. Returns self."""
        n = task_set.n_actions
        if any(a >= n for a in self.actions):
            raise ValueError(f"actions: task set {task_set.name!r} has actions 0..{n - 1} "
                             f"({task_set.action_names}), got {self.actions!r}")
        return self

    def sample(self, key: jax.Array) -> Task:
        """A random `Task` from ``key`` (jit- and vmap-able)."""
        ka, kp, kl = jax.random.split(key, 3)
        n_layouts = len(scene.LAYOUTS) if self.random_layout else 1
        task = Task(action=jax.random.choice(ka, jnp.asarray(self.actions, jnp.int32)),
                    position=jax.random.choice(kp, jnp.asarray(self.positions, jnp.int32)),
                    layout=jax.random.randint(kl, (), 0, n_layouts, jnp.int32))
        if self.placement == "random":  # a key of its own: the other draws stay
            task = task.replace(placement=free.sample(jax.random.fold_in(key, 1)))
        return task
