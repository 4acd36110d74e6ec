"""The point/touch/push environment as pure functions: ``reset(key, task)``, ``step(state, a)``.

Semantics follow the paper (section 2.2; docs/env.md states what we measured here):

- observation (11): the 4 arm joints scaled to [-1, 1] by eq. 1 with the paper's limits, the
  touch bit (the arm touches an object), the action one-hot (point/touch/push) and the
  position one-hot (left/middle/right);
- action (4): change of the 4 scaled joints; ``action_scale`` (1/3) times it is added to the
  current scaled joints, the result is clipped to the model's joint limits and becomes the
  position servos' target for ``substeps`` physics steps;
- reward at every step: point -- minus the L1 distance (scaled units) between the joints and
  the stored pointing configuration of the target position; touch -- minus the palm's distance
  to the target's original position, ``touch_other_penalty`` added when touching another
  object and ``touch_target_penalty`` when touching the target; push -- minus the palm's
  distance to the target's original position;
- moving a wrong object (further than ``wrong_move_threshold`` from where it stood) ends the
  episode ``wrong_move_extra_steps`` steps later; otherwise it ends after ``episode_length``.

``done`` is absorbing: stepping a finished episode returns it unchanged (on the C backend its
physics is skipped), so batches of episodes can run in lockstep and learners mask with it;
``reset_where`` is the auto-reset that restarts finished episodes in their batch slots instead.
NaN entries of an action are replaced by zero (no move) and counted in
``metrics["nan_actions"]``; they never reach the physics state.

Concrete parameters and tasks are checked on the host (a clear ``ValueError``). Traced ones
cannot be, so inside ``jit`` an episode whose parameters are not finite (or overflow
float32), whose task indices are out of range (which JAX's gathers would clamp silently), or
whose physics state or observation goes non-finite is flagged: ``metrics["invalid"]`` is 1
from that step on (0 otherwise). Check it when you feed traced values in.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from grounding_jax.core.checks import (
    FINITE,
    NON_NEGATIVE,
    POSITIVE,
    Rule,
    check_config,
    check_rules,
    integer_at_least,
)
from grounding_jax.sim import physics, scene, tasks, tl_data
from grounding_jax.sim import placement as free

OBS_SIZE, ACTION_SIZE = tasks.OBS_SIZE, tasks.ACTION_SIZE


#: What each count of `EnvConfig` accepts (its ``__post_init__`` and the sweep runner
#: read it).
CONFIG_RULES: dict[str, Rule] = {"substeps": integer_at_least(1),
                                 "episode_length": integer_at_least(1)}


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Static configuration: anything here changes the compiled code.

    Attributes:
        backend: ``"mujoco"`` (C MuJoCo via ``mujoco.rollout``; CPU) or ``"mjx"`` (pure JAX).
        substeps: physics steps (5 ms each) per RL step.
        episode_length: RL steps per episode (the paper: 75).
        task_set: name of the `tasks.TaskSet` (actions, their rewards and the
            observation's layout; default the paper's point/touch/push).
    """

    backend: str = "mujoco"
    substeps: int = 10
    episode_length: int = 75
    task_set: str = tasks.PAPER.name

    def __post_init__(self) -> None:
        physics.check_backend(self.backend)
        check_config(self, CONFIG_RULES)
        tasks.get(self.task_set)

    @property
    def tasks(self) -> tasks.TaskSet:
        """The `tasks.TaskSet` named by ``task_set``."""
        return tasks.get(self.task_set)


@struct.dataclass
class EnvParams:
    """Traced parameters: a sweep over these compiles once.

    Attributes:
        action_scale: factor applied to the action before it moves the joints (paper: 1/3).
        touch_other_penalty: added to the touch reward while touching a non-target object.
        touch_target_penalty: added to the touch reward while touching the target.
        touch_moved_penalty: the free family's touch reward loses this much per metre the
            target has moved (``tasks.FREE``, and ``tasks.PAPER_TOUCH_POSE``; the paper's
            task set does not use it).
        touch_bonus: added to the free family's touch reward while the arm touches the
            target (and to ``tasks.PAPER_TOUCH_POSE``'s; the paper's does not use it).
        touch_still_penalty: the free family's touch reward loses this much per scaled-joint
            unit (L1) the arm moves in a step while it touches the target: once in contact,
            hold still (0, the default: off; the paper family does not use it).
        push_moved_bonus: added to the paper family's push reward (not the free family's)
            per metre the target has moved, counted up to ``tasks.PUSH_MOVED_CAP`` (0, the
            default: the paper's reward, minus the palm's distance to the target, which pays
            for reaching it, not for moving it).
        push_other_penalty: added to the paper family's push reward while the arm touches a
            non-target object or one has moved (0, the default: the paper's reward, which
            lets a push from a random start sweep a neighbour aside; the free family's
            rewards pay ``touch_other_penalty`` for it instead).
        wrong_move_threshold: metres a non-target object may move before it counts as moved.
        wrong_move_extra_steps: steps the episode goes on after a wrong object moved.
        start_noise: half-width (scaled joint units) of the uniform random start around the
            home pose; 0 starts every episode at home (the paper's training), > 0 gives the
            random starts of Fig 11.
    """

    action_scale: Any = 1.0 / 3.0
    touch_other_penalty: Any = -0.5
    touch_target_penalty: Any = -0.3
    touch_moved_penalty: Any = 10.0
    touch_bonus: Any = 0.0
    touch_still_penalty: Any = 0.0
    push_moved_bonus: Any = 0.0
    push_other_penalty: Any = 0.0
    wrong_move_threshold: Any = 0.01
    wrong_move_extra_steps: Any = 3
    start_noise: Any = 0.0

    def validate(self) -> EnvParams:
        """Check concrete values (skipped for traced ones). Returns self."""
        check_rules(self, PARAM_RULES)
        return self


#: What each field of `EnvParams` accepts (``validate`` and the sweep runner read it).
PARAM_RULES: dict[str, Rule] = {
    "action_scale": POSITIVE, "touch_other_penalty": FINITE, "touch_target_penalty": FINITE,
    "touch_moved_penalty": NON_NEGATIVE, "touch_bonus": FINITE,
    "touch_still_penalty": NON_NEGATIVE, "push_moved_bonus": NON_NEGATIVE,
    "push_other_penalty": FINITE,
    "wrong_move_threshold": POSITIVE,
    "wrong_move_extra_steps": integer_at_least(0), "start_noise": NON_NEGATIVE,
}

DEFAULT_PARAMS = EnvParams()


@struct.dataclass
class Task:
    """What to do: an action on the object at a position, in one of the 36 layouts.

    ``action``, ``position`` and ``layout`` are int32 arrays (so a task can be traced, batched
    and replaced mid-episode). ``placement`` is ``None`` for the paper's three fixed slots, or
    float32 ``[3, 3]`` (x, y, yaw of the left, middle and right slot; see
    `grounding_jax.sim.placement`) for objects placed anywhere on the reachable table. Build
    one from names with `make_task`.

    Two optional float32 ``[2]`` fields serve the ``"free"`` task set (whose actor is told
    the target's coordinates): ``target_xy`` -- the coordinates the actor is told (e.g. the
    TL's estimate from the camera, or where the target stood at the start); ``None`` tells it
    the simulator's, every step. ``velocity`` -- the target slides on the table at this
    velocity (m/s) until it reaches the reachable region's border; ``None`` keeps it still.
    """

    action: jax.Array
    position: jax.Array
    layout: jax.Array
    placement: jax.Array | None = None
    target_xy: jax.Array | None = None
    velocity: jax.Array | None = None
    target_units: jax.Array | None = None


@struct.dataclass
class State:
    """Everything an episode carries; a pytree whose structure never changes across steps."""

    qpos: jax.Array
    qvel: jax.Array
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    task: Task
    step: jax.Array  # RL steps taken in this episode
    wrong_since: jax.Array  # step at which a wrong object first moved, -1 if none
    object_start: jax.Array  # [3 shapes, 3] object positions at reset
    sensordata: jax.Array
    metrics: dict[str, jax.Array]
    info: dict[str, jax.Array]


def _index(value: Any, names: tuple[str, ...], field: str) -> int:
    if isinstance(value, str):
        if value not in names:
            raise ValueError(f"{field}: unknown value {value!r}; accepted values: {names}")
        return names.index(value)
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        if not 0 <= value < len(names):
            raise ValueError(f"{field}: index {value} out of range; accepted: 0..{len(names) - 1}"
                             f" for {names}")
        return int(value)
    raise ValueError(f"{field}: expected a name or an index, got {value!r}; "
                     f"accepted values: {names}")


def layout_names() -> tuple[str, ...]:
    """Names of the 36 layouts, in index order (see `scene.layout_name`)."""
    return tuple(scene.layout_name(i) for i in range(len(scene.LAYOUTS)))


def make_task(action: str | int, position: str | int, layout: str | int = 0,
              task_set: str = tasks.PAPER.name, placement: Any = None,
              key: jax.Array | None = None, target_xy: Any = None,
              velocity: Any = None) -> Task:
    """A `Task` from names or indices, validated.

    Args:
        action: ``"point"``, ``"touch"`` or ``"push"`` (or 0..2); an action of ``task_set``.
        position: ``"left"``, ``"middle"`` or ``"right"`` (or 0..2), or the word that names
            the target (``"red"``, ``"box"``, ...; its slot in ``layout``).
        layout: index 0..35 or a name from `layout_names`: which shape and colour
            stands in each slot.
        task_set: the name of the `tasks.TaskSet` the action belongs to.
        placement: ``None`` (the paper's fixed slots), ``"random"`` (drawn with ``key`` by
            `placement.sample`) or explicit coordinates ``[3, 2]`` / ``[3, 3]`` (x, y
            [, yaw] of the left, middle and right slot; checked by `placement.check`).
        key: PRNG key for ``placement="random"``.
        target_xy: the target's coordinates (metres) the actor is told, ``[2]``; default
            the simulator's (see `Task`).
        velocity: the target's sliding velocity (m/s), ``[2]``; needs a placement. With a
            velocity only the target must lie in the reachable region (see
            `placement.moving`).

    Returns:
        The task: int32 scalars, and the float32 placement, coordinates and velocity when
        given.

    Raises:
        ValueError: naming the field and the accepted values (or the allowed region).
    """
    a = _index(action, tasks.get(task_set).action_names, "action")
    if isinstance(layout, str):
        names = layout_names()
        if layout not in names:
            raise ValueError(f"layout: unknown value {layout!r}; accepted values: an index "
                             f"0..35 or a name such as {names[0]!r} (see layout_names())")
        lay = names.index(layout)
    else:
        lay = _index(layout, tuple(str(i) for i in range(len(scene.LAYOUTS))), "layout")
    if isinstance(position, str) and position in tasks.TARGET_WORDS:
        p = tl_data.label_of(lay, tl_data.word_index(position))
    elif isinstance(position, str) and position not in scene.POSITIONS:
        raise ValueError(f"position: unknown value {position!r}; accepted values: "
                         f"{scene.POSITIONS + tasks.TARGET_WORDS} (a slot or a target word)")
    else:
        p = _index(position, scene.POSITIONS, "position")
    if isinstance(placement, str):
        if placement != "random":
            raise ValueError(f"placement: unknown value {placement!r}; accepted values: None "
                             f"(the paper's slots), 'random' or coordinates [3, 2] / [3, 3]")
        if key is None:
            raise ValueError("key: placement='random' needs a PRNG key (key=jax.random.key(0))")
        placed = free.sample(key)
    elif placement is not None:
        reach = (p,) if velocity is not None else (0, 1, 2)  # see placement.moving
        placed = jnp.asarray(free.check(placement, reach=reach))
        if placed.ndim != 2:
            raise ValueError(f"placement: expected one placement [3, 2|3], got shape "
                             f"{placed.shape}")
    else:
        placed = None
    if velocity is not None and placement is None:
        raise ValueError("velocity: a moving target needs a placement (e.g. "
                         "placement.moving(key, speed)); accepted: None without one")
    i32 = jnp.int32
    task = Task(action=jnp.asarray(a, i32), position=jnp.asarray(p, i32),
                layout=jnp.asarray(lay, i32), placement=placed,
                target_xy=_vector(target_xy, "target_xy"), velocity=_vector(velocity, "velocity"))
    _check_task(task, tasks.get(task_set).n_actions)
    return task


def _vector(value: Any, field: str) -> jax.Array | None:
    """An optional float32 ``[2]`` field of a task, checked (finite, shape)."""
    if value is None:
        return None
    arr = np.asarray(value, np.float64)
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{field}: expected two finite numbers (x, y), got {arr.tolist()}")
    return jnp.asarray(arr, jnp.float32)


def _traced_faults(task: Task, params: EnvParams, n_actions: int) -> jax.Array:
    """True where a (possibly traced) task or parameter set cannot be used: non-finite or
    float32-overflowing parameters, task indices out of range, non-finite task vectors."""
    bad = jnp.zeros((), bool)
    for leaf in jax.tree.leaves(params):
        bad |= ~jnp.all(jnp.isfinite(jnp.asarray(leaf, jnp.float32)))
    for field, n in (("action", n_actions), ("position", tasks.N_POSITIONS),
                     ("layout", len(scene.LAYOUTS))):
        v = jnp.asarray(getattr(task, field))
        bad |= jnp.any((v < 0) | (v >= n))
    for field in ("placement", "target_xy", "velocity", "target_units"):
        v = getattr(task, field)
        if v is not None:
            bad |= ~jnp.all(jnp.isfinite(v))
    return bad


def _check_task(task: Task, n_actions: int = tasks.N_ACTIONS) -> None:
    """Range-check the concrete fields of a task (traced ones are checked by make_task)."""
    for field, n in (("action", n_actions), ("position", tasks.N_POSITIONS),
                     ("layout", len(scene.LAYOUTS))):
        v = getattr(task, field)
        if isinstance(v, jax.core.Tracer):
            continue
        arr = np.asarray(v)
        if not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"task.{field}: expected integers, got dtype {arr.dtype}")
        if arr.size and (arr.min() < 0 or arr.max() >= n):
            raise ValueError(f"task.{field}: values must be in 0..{n - 1}, got {arr}")
    concrete = lambda v: v is not None and not isinstance(v, jax.core.Tracer)  # noqa: E731
    if concrete(task.placement):
        # a moving target's neighbours may be parked out of reach (placement.moving)
        moving = task.velocity is not None and concrete(task.position) and np.ndim(
            task.position) == 0
        reach = (int(task.position),) if moving else (0, 1, 2)
        free.check(task.placement, "task.placement", reach=reach)
    for field, n in (("target_xy", 2), ("velocity", 2), ("target_units", tasks.N_POSITIONS)):
        v = getattr(task, field)
        if concrete(v):
            arr = np.asarray(v)
            if arr.shape[-1:] != (n,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"task.{field}: expected {n} finite numbers per task, got "
                                 f"{arr.tolist()}")


# ------------------------------------------------------------------------- joint scaling
_LIMITS = jnp.asarray(np.radians(scene.PAPER_LIMITS_DEG), jnp.float32)


def scale_joints(q: jax.Array) -> jax.Array:
    """Eq. 1: joint angles (radians) -> [-1, 1] over the paper's limits."""
    lo, hi = _LIMITS[:, 0], _LIMITS[:, 1]
    return 2.0 * (q - lo) / (hi - lo) - 1.0


def unscale_joints(j: jax.Array) -> jax.Array:
    """Inverse of `scale_joints`."""
    lo, hi = _LIMITS[:, 0], _LIMITS[:, 1]
    return lo + (j + 1.0) * 0.5 * (hi - lo)


class Env:
    """The environment for one static `EnvConfig`.

    ``reset`` and ``step`` are pure functions of their arguments and may be used under
    ``jax.jit``, ``jax.vmap`` and ``jax.lax.scan`` on both backends.

    Attributes:
        pointing_poses: the stored pointing pose of each slot (left, middle, right), its 4
            joints scaled to [-1, 1] as the observation holds them: `[3, 4]`, what the point
            reward measures the joints against.
    """

    def __init__(self, config: EnvConfig = EnvConfig()) -> None:
        self.config = config
        self.tasks = config.tasks
        idx = scene.index()
        self._idx = idx
        self.arm_qpos = jnp.asarray(idx.arm_qpos)  # qpos addresses of the 4 arm joints
        self._physics_step, self._physics_forward = physics.make_physics(
            config.backend, config.substeps)
        self._qpos_home = jnp.asarray(scene.home_qpos(), jnp.float32)
        self._shape_slot = jnp.asarray(scene.layout_shape_slots())  # [36, shape] -> position
        slot_shape = np.argsort(scene.layout_shape_slots(), axis=1)  # [36, position] -> shape
        self._slot_shape = jnp.asarray(slot_shape, jnp.int32)
        self._object_pos = jnp.asarray(scene.object_positions(), jnp.float32)
        self.pointing_poses = scale_joints(jnp.asarray(scene.pointing_configs(), jnp.float32))
        self._range = jnp.asarray(idx.joint_range, jnp.float32)
        self._home_scaled = scale_joints(jnp.asarray(np.radians(scene.HOME_POSE_DEG),
                                                     jnp.float32))
        self._dt = float(scene.model().opt.timestep) * config.substeps  # seconds per RL step

    @property
    def dt(self) -> float:
        """Seconds of simulated time per RL step (``substeps`` physics steps)."""
        return self._dt

    # ------------------------------------------------------------------ helpers
    def _place(self, task: Task) -> jax.Array:
        """qpos of the objects' free joints for a task's layout and placement: [3 shapes, 7]."""
        if task.placement is not None:
            return free.free_joint_qpos(task.placement)[self._shape_slot[task.layout]]
        pos = self._object_pos[self._shape_slot[task.layout]]  # [shape, 3]
        quat = jnp.broadcast_to(jnp.array([1.0, 0, 0, 0], jnp.float32), (3, 4))
        return jnp.concatenate([pos, quat], axis=1)

    def _objects(self, qpos: jax.Array) -> jax.Array:
        return qpos[self._idx.object_qpos[:, :3]]  # [shape, 3]

    def _target_units(self, task: Task, object_start: jax.Array,
                      palm: jax.Array) -> jax.Array:
        """The observation's target part: the position one-hot, or the target's
        coordinates (the task's ``target_xy``, else where the target is meant to be), then,
        with ``hand_obs``, the palm's offset to that point (``obs_target`` + ``obs_hand``)."""
        if self.tasks.target_obs == "position":
            if task.target_units is not None:
                return jnp.asarray(task.target_units, jnp.float32)
            return jax.nn.one_hot(task.position, tasks.N_POSITIONS)
        if task.target_units is not None:
            raise ValueError(f"task.target_units: only the 'position' target observation reads "
                             f"it; this task set's is {self.tasks.target_obs!r} (use target_xy)")
        target = object_start[self._slot_shape[task.layout, task.position]]
        xy = target[:2] if task.target_xy is None else task.target_xy
        units = free.target_units(xy, self.tasks.target_obs)
        if not self.tasks.hand_obs:
            return units
        told = jnp.concatenate([xy, target[2:]])
        return jnp.concatenate([units, jnp.tanh((palm - told) / self.tasks.hand_scale)])

    def _evaluate(self, qpos, sensordata, task: Task, object_start, params: EnvParams,
                  joints_before=None):
        """Observation, reward and per-step metrics of a physics state (``object_start``:
        where each object is meant to be -- where it stood at reset, or a moving target's
        point on its path; ``joints_before``: the scaled joints before this step, None at
        reset)."""
        joints = scale_joints(qpos[self._idx.arm_qpos])
        arm_moved = (jnp.zeros((), jnp.float32) if joints_before is None
                     else jnp.sum(jnp.abs(joints - joints_before)))
        contacts = jnp.any(sensordata[self._idx.sensor_contact] > 0, axis=1)  # [shape]
        palm = sensordata[self._idx.sensor_palm_pos]
        obs = jnp.concatenate([
            joints, jnp.any(contacts).astype(jnp.float32)[None],
            jax.nn.one_hot(task.action, self.tasks.n_actions),
            self._target_units(task, object_start, palm)
        ])
        target_shape = self._slot_shape[task.layout, task.position]
        target_xy = object_start[target_shape, :2]
        if task.placement is None:
            pose = self.pointing_poses[task.position]
        else:  # the pointing map, interpolated at where the target is meant to be
            pose = scale_joints(free.pointing_pose(target_xy))
        if task.placement is None and self.tasks.actions is tasks.PAPER.actions:
            # the paper's rewards use no pose map: spare its hot path the interpolations
            touch_l1 = push_l1 = jnp.zeros((), jnp.float32)
        else:  # the touch and push pose maps (the free family's rewards)
            touch_l1 = jnp.sum(jnp.abs(joints - scale_joints(free.touch_pose(target_xy))))
            push_l1 = jnp.sum(jnp.abs(joints - scale_joints(free.push_pose(target_xy))))
        is_target = jnp.arange(3) == target_shape
        moved = jnp.linalg.norm(self._objects(qpos) - object_start, axis=1)  # [shape]
        now = self._objects(qpos)[target_shape]  # where the target is
        terms = {
            "point_l1": jnp.sum(jnp.abs(joints - pose)),
            "touch_l1": touch_l1,
            "push_l1": push_l1,
            "palm_target_dist": jnp.linalg.norm(palm - object_start[target_shape]),
            "palm_target_now": jnp.linalg.norm(palm - now),
            # the palm's height over the target's centre and its distance across the table
            "palm_over_target": palm[2] - now[2],
            "palm_target_across": jnp.linalg.norm(palm[:2] - now[:2]),
            "touched_target": jnp.any(contacts & is_target).astype(jnp.float32),
            "touched_other": jnp.any(contacts & ~is_target).astype(jnp.float32),
            "target_moved": moved[target_shape],
            "wrong_moved": jnp.any((moved > params.wrong_move_threshold) & ~is_target),
            "arm_moved": arm_moved,  # scaled-joint L1 the arm moved in this step
        }
        reward = self.tasks.reward(task.action, terms, params)
        return obs, reward.astype(jnp.float32), terms

    def _info(self, sensordata: jax.Array, ctrl: jax.Array) -> dict[str, jax.Array]:
        return {"palm_pos": sensordata[self._idx.sensor_palm_pos],
                "palm_force": sensordata[self._idx.sensor_palm_touch], "ctrl": ctrl}

    # ------------------------------------------------------------------ API
    def reset(self, key: jax.Array, task: Task, params: EnvParams = DEFAULT_PARAMS) -> State:
        """Start an episode.

        Args:
            key: PRNG key (used for the random start pose when ``params.start_noise > 0``).
            task: the `Task` (see `make_task`).
            params: traced `EnvParams`.

        Returns:
            The initial `State` (reward is that of the start pose).
        """
        return self._reset(key, task, params)

    def reset_where(self, when: jax.Array, state: State, key: jax.Array, task: Task,
                    params: EnvParams = DEFAULT_PARAMS) -> State:
        """Auto-reset: ``reset(key, task, params)`` where ``when``, ``state`` elsewhere.

        Under ``vmap`` ``when`` is per scene, and the C backend runs the reset's physics only
        for the scenes where it holds, so a batch can restart finished episodes at any step
        at little cost (as Brax's and PureJaxRL's auto-reset do).

        Args:
            when: bool scalar: start a new episode.
            state: the current state (kept where ``when`` is false).
            key: as for `reset`.
            task: as for `reset`.
            params: as for `reset`.

        Returns:
            The new or the unchanged `State`.
        """
        fresh = self._reset(key, task, params, live=when)
        return jax.tree.map(lambda n, o: jnp.where(when, n, o), fresh, state)

    def _reset(self, key: jax.Array, task: Task, params: EnvParams,
               live: jax.Array | None = None) -> State:
        _check_task(task, self.tasks.n_actions)
        params.validate()
        noise = jax.random.uniform(key, (4,), jnp.float32, -1.0, 1.0) * params.start_noise
        q_arm = jnp.clip(unscale_joints(self._home_scaled + noise), self._range[:, 0],
                         self._range[:, 1])
        qpos = self._qpos_home.at[self._idx.arm_qpos].set(q_arm)
        qpos = qpos.at[self._idx.object_qpos].set(self._place(task))
        qvel = jnp.zeros(self._idx.nv, jnp.float32)
        sensordata = self._physics_forward(qpos, qvel, live)
        object_start = self._objects(qpos)
        obs, reward, terms = self._evaluate(qpos, sensordata, task, object_start, params)
        if self.tasks.memory:
            obs = jnp.concatenate([obs, tasks.first_memory(self.tasks, obs[:tasks.N_JOINTS])])
        invalid = (_traced_faults(task, params, self.tasks.n_actions)
                   | ~jnp.all(jnp.isfinite(qpos)) | ~jnp.all(jnp.isfinite(obs)))
        metrics = {**terms, "nan_actions": jnp.zeros((), jnp.float32), "invalid": invalid}
        metrics = {k: jnp.asarray(v, jnp.float32) for k, v in metrics.items()}
        return State(
            qpos=qpos, qvel=qvel, obs=obs, reward=reward, done=jnp.zeros((), bool), task=task,
            step=jnp.zeros((), jnp.int32), wrong_since=jnp.full((), -1, jnp.int32),
            object_start=object_start, sensordata=sensordata, metrics=metrics,
            info=self._info(sensordata, q_arm),
        )

    def step(self, state: State, action: jax.Array, params: EnvParams = DEFAULT_PARAMS) -> State:
        """Advance one RL step.

        Args:
            state: current `State`.
            action: ``[4]`` change of the scaled joints (before ``action_scale``).
            params: traced `EnvParams`.

        Returns:
            The next `State` (same pytree structure and dtypes).
        """
        action = jnp.asarray(action)
        n = self.tasks.action_size
        if action.shape != (n,):
            raise ValueError(f"action: expected shape ({n},), got {action.shape}")
        params.validate()
        action = action.astype(jnp.float32)
        nan = jnp.isnan(action)
        action = jnp.where(nan, 0.0, action)
        before = scale_joints(state.qpos[self._idx.arm_qpos])
        target = before + params.action_scale * action
        ctrl = jnp.clip(unscale_joints(target), self._range[:, 0], self._range[:, 1])
        qpos, qvel, object_start = self._slide(state)
        qpos, qvel, sensordata = self._physics_step(qpos, qvel, ctrl, ~state.done)
        obs, reward, terms = self._evaluate(qpos, sensordata, state.task, object_start, params,
                                            before)
        if self.tasks.memory:
            obs = jnp.concatenate([obs, tasks.next_memory(self.tasks, state.obs, before,
                                                          action)])
        step = state.step + 1
        wrong_since = jnp.where((state.wrong_since < 0) & terms["wrong_moved"], step,
                                state.wrong_since)
        ended = (step >= self.config.episode_length) | (
            (wrong_since >= 0) & (step - wrong_since >= params.wrong_move_extra_steps))
        invalid = ((state.metrics["invalid"] > 0)
                   | _traced_faults(state.task, params, self.tasks.n_actions)
                   | ~jnp.all(jnp.isfinite(qpos)) | ~jnp.all(jnp.isfinite(obs)))
        metrics = {**terms, "nan_actions": state.metrics["nan_actions"] + jnp.sum(nan),
                   "invalid": invalid}
        metrics = {k: jnp.asarray(v, jnp.float32) for k, v in metrics.items()}
        new = state.replace(
            qpos=qpos, qvel=qvel, obs=obs, reward=reward, done=ended, step=step,
            wrong_since=wrong_since, object_start=object_start, sensordata=sensordata,
            metrics=metrics, info=self._info(sensordata, ctrl),
        )
        # a finished episode is absorbing: its state stays as it ended (and on the C backend
        # its physics is not run at all)
        return jax.tree.map(lambda n, o: jnp.where(state.done, o, n), new, state)

    def _slide(self, state: State) -> tuple[jax.Array, jax.Array, jax.Array]:
        """A moving target's next point on its path (stopped at the reachable region's
        border): the target is set there, at rest, before the physics step, and becomes
        where it is meant to be. Returns (qpos, qvel, object_start)."""
        task = state.task
        if task.velocity is None:
            return state.qpos, state.qvel, state.object_start
        shape = self._slot_shape[task.layout, task.position]
        lo = jnp.array([free.REACH_X[0], free.REACH_Y[0]], jnp.float32)
        hi = jnp.array([free.REACH_X[1], free.REACH_Y[1]], jnp.float32)
        here = state.object_start[shape, :2]
        there = jnp.clip(here + task.velocity * self._dt, jnp.minimum(lo, here),
                         jnp.maximum(hi, here))
        obj_qpos = jnp.asarray(self._idx.object_qpos)[shape]
        obj_dof = jnp.asarray(self._idx.object_dof)[shape]
        qpos = state.qpos.at[obj_qpos[:2]].set(there)
        qvel = state.qvel.at[obj_dof].set(0.0)
        return qpos, qvel, state.object_start.at[shape, :2].set(there)

    def with_episode_length(self, steps: int) -> Env:
        """This env with episodes of ``steps`` steps, sharing its physics backend and tables
        (an evaluation that runs past the training episode length uses it).

        Raises:
            ValueError: ``steps`` is not an integer >= 1 (naming ``episode_length``).
        """
        config = dataclasses.replace(self.config, episode_length=steps)
        if config == self.config:
            return self
        other = copy.copy(self)
        other.config = config
        return other

    def set_task(self, state: State, task: Task) -> State:
        """Replace the goal mid-episode (Fig 13): the arm and objects stay where they are.

        The observation's action/target units switch at once; rewards from the next step on
        refer to the new task, measured from where the objects stood at reset.
        """
        _check_task(task, self.tasks.n_actions)
        ts = self.tasks
        obs = state.obs.at[ts.obs_action].set(jax.nn.one_hot(task.action, ts.n_actions))
        units = self._target_units(task, state.object_start, state.info["palm_pos"])
        obs = obs.at[ts.obs_target.start:ts.obs_hand.stop].set(units)
        return state.replace(task=task, obs=obs)


def as_env(env: Env | EnvConfig | None = None, steps: int | None = None) -> Env:
    """``env`` itself, or an `Env` built from a static config (default
    ``EnvConfig()``); with ``steps``, its episodes last that many steps
    (`Env.with_episode_length`)."""
    env = env if isinstance(env, Env) else Env(EnvConfig() if env is None else env)
    return env if steps is None else env.with_episode_length(steps)


def make_env(backend: str = "mujoco", **kwargs: Any) -> Env:
    """Shorthand for ``Env(EnvConfig(backend=backend, **kwargs))``."""
    return Env(EnvConfig(backend=backend, **kwargs))
