"""AL evaluation: success rates of trained agents, by the criteria below.

Success (greedy actor, one episode of ``EVAL_STEPS`` steps per task and layout; the criteria
judge, the rewards stay the paper's):

- point: final L1 distance to the stored pointing pose < ``POINT_L1`` (scaled joint units),
  no sustained oscillation (the L1 range over the last ``STILL_LAST`` steps < ``POINT_STILL``),
  the target moved < ``POINT_MOVED`` metres and no wrong object moved;
- touch: an arm capsule touches the target in the second half of the episode, the target
  moved < ``TOUCH_MOVED`` and no wrong object moved;
- push: the target moved >= ``PUSH_MOVED`` metres and no wrong object moved.

"Final" is the last step of the episode: step ``EVAL_STEPS``, or the step at which it ended
after a wrong object moved (such an episode fails every criterion).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core import trees, xla
from grounding_jax.learn import al, learners, tl_xy
from grounding_jax.sim import rollout, scene, tasks
from grounding_jax.sim.env import (
    DEFAULT_PARAMS,
    Env,
    EnvConfig,
    EnvParams,
    Task,
    as_env,
)
from grounding_jax.sim.tasks import N_ACTIONS, N_POSITIONS

DEFAULT_ENV = EnvConfig()
EVAL_STEPS = 100
# the criteria live with the actions' success rules in tasks.py
POINT_L1, POINT_STILL, POINT_MOVED = tasks.POINT_L1, tasks.POINT_STILL, tasks.POINT_MOVED
STILL_LAST, TOUCH_MOVED, PUSH_MOVED = tasks.STILL_LAST, tasks.TOUCH_MOVED, tasks.PUSH_MOVED
#: half-width (scaled joint units) of the random starts around home (Fig 11; the criteria)
RANDOM_START_NOISE = 0.5

#: The 6 layouts with colour order 0: every shape at every position once.
SHAPE_LAYOUTS = tuple(i * len(scene.COLOUR_ORDERS) for i in range(len(scene.SHAPE_ORDERS)))
#: All 36 layouts (the evaluation default: physics differs by shape, colour is only seen).
ALL_LAYOUTS = tuple(range(len(scene.LAYOUTS)))
#: [layout, position] -> the shape standing there
_TARGET_SHAPE = jnp.asarray(np.argsort(scene.layout_shape_slots(), axis=1), jnp.int32)


def all_tasks(layouts: tuple[int, ...] = ALL_LAYOUTS, actions: tuple[int, ...] = (0, 1, 2)
              ) -> Task:
    """Every (action, position, layout) combination of ``actions`` as a batched
    `Task`."""
    a, p, lay = np.meshgrid(np.asarray(actions), np.arange(N_POSITIONS), np.asarray(layouts),
                            indexing="ij")
    return Task(*(jnp.asarray(x.ravel(), jnp.int32) for x in (a, p, lay)))


def free_tasks(key: jax.Array, placements: int, actions: tuple[int, ...] = (0, 1, 2)) -> Task:
    """Every action of ``actions`` at every slot of ``placements`` random placements
    (`placement.sample`), each placement with a random layout, as a batched
    `Task` (for the ``"free"`` task set's evaluation)."""
    placed, layout = tl_xy.draw_scenes(key, placements)
    a, p, i = np.meshgrid(np.asarray(actions), np.arange(N_POSITIONS), np.arange(placements),
                          indexing="ij")
    i = i.ravel()
    # built in NumPy and put on the device whole: no program per field
    return jax.device_put(Task(action=a.ravel().astype(np.int32),
                               position=p.ravel().astype(np.int32),
                               layout=layout[i].astype(np.int32),
                               placement=placed[i].astype(np.float32)))


def episode_success(traj, task: Task, since: int = 0, task_set: tasks.TaskSet = tasks.PAPER
                    ) -> dict[str, jax.Array]:
    """Success of one greedy episode from its stacked states (see module doc).

    Args:
        traj: env states after each step, stacked on axis 0 (from ``al.make_eval``).
        task: the episode's task.
        since: steps before this one are not judged (a goal switch: the second task's
            touch must come in the second half of what is left, and only objects that move
            after the switch count against it).
        task_set: whose actions' success rules judge (see `grounding_jax.sim.tasks`).

    Returns:
        ``success`` (0/1), and the quantities it is judged on: ``final_point_l1``,
        ``point_l1_range`` (over the last steps), ``touched_late`` (second half),
        ``target_moved``, ``wrong_moved``, ``final_reward``.
    """
    n = traj.reward.shape[0]
    steps = jnp.arange(n)
    done = traj.done & (steps >= since)
    last = jnp.where(jnp.any(done), jnp.argmax(done), n - 1)
    at = lambda x: x[last]  # noqa: E731
    window = (steps > last - STILL_LAST) & (steps <= last)
    l1 = traj.metrics["point_l1"]
    l1_range = (jnp.max(jnp.where(window, l1, -jnp.inf))
                - jnp.min(jnp.where(window, l1, jnp.inf)))
    half = since + (n - since) // 2
    touched = jnp.any((traj.metrics["touched_target"] > 0) & (steps >= half) & (steps <= last))
    if since:
        objects = traj.qpos[:, scene.index().object_qpos[:, :3]]  # [steps, shape, 3]
        shift = jnp.linalg.norm(objects[last] - objects[since - 1], axis=-1)  # [shape]
        target = _TARGET_SHAPE[task.layout, task.position]
        is_target = jnp.arange(len(scene.SHAPES)) == target
        wrong = jnp.any((shift > DEFAULT_PARAMS.wrong_move_threshold) & ~is_target)
        moved = shift[target]
    else:
        wrong = at(traj.wrong_since) >= 0
        moved = at(traj.metrics["target_moved"])
    out = {"final_point_l1": at(l1), "point_l1_range": l1_range,
           "touched_late": touched.astype(jnp.float32), "target_moved": moved,
           "wrong_moved": wrong.astype(jnp.float32), "final_reward": at(traj.reward)}
    ok = task_set.success(task.action, out) & ~wrong
    return {"success": ok.astype(jnp.float32), **out}


_PROGRAMS: dict[tuple, object] = {}


def _success_program(env: Env, starts: int):
    """The jitted ``run(agents, key, params, batch)`` of `make_success`, one per (env type,
    static env config, starts): every success function of the same env shares its compiled
    programs (an evaluation of the same shapes is traced and compiled once per process)."""
    cache_key = (type(env), env.config, starts)
    if cache_key in _PROGRAMS:
        return _PROGRAMS[cache_key]
    evaluate = al.make_eval(env)

    def one(agent, key, task, params):
        _, traj, _ = evaluate(agent, key, task, params)
        return episode_success(traj, task, task_set=env.tasks)

    over_tasks = jax.vmap(one, in_axes=(None, 0, 0, None))
    over_starts = jax.vmap(over_tasks, in_axes=(None, 0, None, None))

    def run(agents, key: jax.Array, params: EnvParams, batch: Task):
        # a params leaf with a leading axis is per agent (a sweep's traced env fields)
        axes = jax.tree.map(lambda x: 0 if jnp.ndim(x) else None, params)
        over_agents = jax.vmap(over_starts, in_axes=(0, None, None, axes))
        keys = jax.random.split(key, (starts, batch.action.shape[0]))
        out = over_agents(agents, keys, batch, params)
        out["action"], out["position"] = batch.action, batch.position
        return out

    _PROGRAMS[cache_key] = xla.physics_jit(run, env)
    return _PROGRAMS[cache_key]


def make_success(env: Env | EnvConfig = DEFAULT_ENV, layouts: tuple[int, ...] = ALL_LAYOUTS,
                 starts: int = 1, actions: tuple[int, ...] = (0, 1, 2),
                 steps: int = EVAL_STEPS, batch: Task | None = None):
    """Build ``success(agents, key, env_params) -> dict`` for a batch of agents
    (``env_params`` leaves are shared scalars or per agent ``[agents]``).

    Each agent runs every task (``actions`` x 3 positions x ``layouts``, or the batched tasks
    ``batch``, e.g. `free_tasks`) ``starts`` times, for ``steps`` steps; every episode
    draws its own start pose (``env_params.start_noise``; 0 = the home pose).

    Returns:
        A function whose dict holds arrays ``[agents, starts, tasks]`` (see
        `episode_success`) plus ``action`` and ``position`` ``[tasks]``. Its optional
        ``batch`` argument runs other tasks of the same shapes instead (no new compile).
    """
    env = as_env(env, steps)
    default = all_tasks(layouts, actions) if batch is None else batch
    n_tasks = int(default.action.shape[0])
    run = _success_program(env, starts)

    def success(agents, key: jax.Array, params: EnvParams = DEFAULT_PARAMS,
                batch: Task | None = None):
        batch = default if batch is None else batch
        if int(batch.action.shape[0]) != n_tasks:
            raise ValueError(f"batch: {batch.action.shape[0]} tasks, this success runs "
                             f"{n_tasks}")
        # the default tasks and a caller's go through one program (not one per call form)
        return run(agents, key, params, batch)

    return success


def success_table(out: dict[str, jax.Array]) -> dict[str, object]:
    """Success rates from `make_success`'s output.

    Returns:
        ``by_action`` {name: rate of the median agent}, ``spread`` {name: [min, q25, median,
        q75, max] over agents}, ``per_agent_by_action`` {name: [agents] rates}, ``pooled``
        {name: rate over all agents' episodes}, ``by_task`` {"point left": pooled rate, ...}
        ``per_agent`` [agents] rates over all tasks and ``overall``, their median (rates in
        [0, 1]; actions that were not run are left out).
    """
    s = np.asarray(out["success"])  # [agents, starts, tasks]
    act, pos = np.asarray(out["action"]), np.asarray(out["position"])
    ran = [(i, a) for i, a in enumerate(scene.ACTIONS) if np.any(act == i)]
    per_agent = {a: s[..., act == i].reshape(s.shape[0], -1).mean(axis=1) for i, a in ran}
    return {
        "by_action": {a: float(np.median(v)) for a, v in per_agent.items()},
        "spread": {a: np.quantile(v, [0, 0.25, 0.5, 0.75, 1]).tolist()
                   for a, v in per_agent.items()},
        "per_agent_by_action": {a: v.tolist() for a, v in per_agent.items()},
        "pooled": {a: float(s[..., act == i].mean()) for i, a in ran},
        "by_task": {f"{a} {p}": float(s[..., (act == i) & (pos == j)].mean())
                    for i, a in ran for j, p in enumerate(scene.POSITIONS)},
        "per_agent": s.reshape(s.shape[0], -1).mean(axis=1).tolist(),
        "overall": float(np.median(s.reshape(s.shape[0], -1).mean(axis=1)))}


#: the success rates a sweep can record (per agent, in [0, 1]); "mean" averages the other four
SUCCESS_METRICS = ("point", "touch", "push", "rand_point", "mean")


#: Held-out placements of the free family's success rates in sweeps (a fixed key: the same
#: scenes for every run; training draws its placements from the agents' own keys).
FREE_EVAL_KEY, FREE_EVAL_PLACEMENTS = 1234, 12


def make_success_rates(env: Env | EnvConfig = DEFAULT_ENV, batch: int = 8,
                       layouts: tuple[int, ...] = ALL_LAYOUTS):
    """Build ``rates(agents, key, env_params) -> {name: [agents]}``: each agent's success rate
    per action from home, point from random starts (one per position and layout, within
    ``RANDOM_START_NOISE`` of home), and their mean -- the names of `SUCCESS_METRICS`.

    For an env whose actor is told the target's coordinates (the ``"free"`` task set) the
    tasks are every slot of `FREE_EVAL_PLACEMENTS` random placements (random layouts)
    drawn from `FREE_EVAL_KEY` instead of the paper's slots and ``layouts``.

    Agents are evaluated ``batch`` at a time (the stacked trajectories of a large batch would
    not fit in memory). ``env_params`` leaves may be per agent (a sweep's traced env fields).
    """
    env = as_env(env)
    if env.tasks.target_obs != "position":
        k = jax.random.key(FREE_EVAL_KEY)
        home = make_success(env, batch=free_tasks(k, FREE_EVAL_PLACEMENTS))
        rand = make_success(env, batch=free_tasks(k, FREE_EVAL_PLACEMENTS, actions=(0,)))
    else:
        home = make_success(env, layouts)
        rand = make_success(env, layouts, actions=(0,))

    def rates(agents, key: jax.Array, env_params: EnvParams = DEFAULT_PARAMS
              ) -> dict[str, np.ndarray]:
        k_home, k_rand = jax.random.split(key)
        n = jax.tree.leaves(agents)[0].shape[0]
        parts = []
        for i in range(0, n, batch):
            take = lambda x, i=i: x[i:i + batch] if jnp.ndim(x) else x  # noqa: E731
            a, p = jax.tree.map(take, agents), jax.tree.map(take, env_params)
            h = success_table(home(a, k_home, p))["per_agent_by_action"]
            r = success_table(rand(a, k_rand, p.replace(start_noise=RANDOM_START_NOISE)))
            parts.append({**h, "rand_point": r["per_agent_by_action"]["point"]})
        out = {k: np.concatenate([np.asarray(p[k], np.float32) for p in parts])
               for k in SUCCESS_METRICS[:-1]}
        out["mean"] = np.mean([out[k] for k in SUCCESS_METRICS[:-1]], axis=0)
        return out

    return rates


# ------------------------------------------------------------------------------ experiments
def take(tree, i: int):
    """Agent ``i`` of a batch of agents (every leaf's row ``i``), in one compiled call."""
    return trees.take(tree, i)


def make_switch_eval(env: Env | EnvConfig = DEFAULT_ENV, steps: int = 100,
                     switch_at: int = 20):
    """Build ``run(agent, key, first_task, second_task, env_params) -> traj``: the greedy
    policy for ``steps`` steps, the task replaced by ``second_task`` after ``switch_at`` steps
    (Fig 13). The episode length is raised to ``steps`` so it does not end on its own."""
    env = as_env(env, steps)

    def run(agent, key, first: Task, second: Task, params: EnvParams = DEFAULT_PARAMS):
        lrn = learners.for_state(agent)

        def policy(state, _):
            return lrn.policy(agent, state.obs)[0], None

        return rollout.rollout(env, env.reset(key, first, params), policy, steps, params,
                               switch=(switch_at, second))[0]

    return run


def switch_pairs(layouts: tuple[int, ...] = SHAPE_LAYOUTS) -> tuple[Task, Task]:
    """The goal switches of the paper's Fig 13 test, systematically: every first task (3
    actions x 3 positions x ``layouts``) followed by each task that differs in the action
    alone or in the position alone (4 per first task). Returns (first, second) batches."""
    rows = [(a, p, lay, a2, p2) for a in range(N_ACTIONS) for p in range(N_POSITIONS)
            for lay in layouts
            for a2, p2 in [(b, p) for b in range(N_ACTIONS) if b != a]
            + [(a, q) for q in range(N_POSITIONS) if q != p]]
    r = np.asarray(rows, np.int32).T
    return Task(r[0], r[1], r[2]), Task(r[3], r[4], r[2])


def make_switch_success(env: Env | EnvConfig = DEFAULT_ENV, steps: int = EVAL_STEPS,
                        switch_at: int = 20, layouts: tuple[int, ...] = SHAPE_LAYOUTS):
    """Build ``success(agents, key) -> dict`` over `switch_pairs`: each switched
    episode is judged by the second task's criterion at its end, counting only what happened
    after the switch (`episode_success` with ``since``); the episode runs all
    ``steps`` (a wrong-object move does not end it, it fails it).

    Returns:
        A function whose dict holds arrays ``[agents, pairs]`` plus ``action`` ``[pairs]``
        (the second task's action).
    """
    env = as_env(env, steps)
    run = make_switch_eval(env, steps, switch_at)
    first, second = switch_pairs(layouts)
    params = DEFAULT_PARAMS.replace(wrong_move_extra_steps=steps + 1)

    def one(agent, key, t1, t2):
        return episode_success(run(agent, key, t1, t2, params), t2, since=switch_at,
                               task_set=env.tasks)

    over_pairs = jax.vmap(one, in_axes=(None, None, 0, 0))

    def success(agents, key: jax.Array):
        out = jax.vmap(over_pairs, in_axes=(0, None, None, None))(agents, key, first, second)
        out["action"], out["position"] = second.action, second.position
        return out

    return xla.physics_jit(success, env)
