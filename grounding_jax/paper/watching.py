"""Beyond the paper: the robot names actions it only watches (``Robot.watch``; the method is
motor resonance, `grounding_jax.robot.observer`).

Watched episodes come from robots the observer is not: the AL agents trained beside its own
from other seeds (paper family: random layouts; free family: placements drawn from a key
nothing else uses), and scripted arm movements that do each action another way (a slow
straight path in joint space to a pointing, touching or pushing pose; for the paper's push,
the sweep from behind the object that the env check uses). A watched episode is named right
when both words are: the action, and a word that names the target (its shape or its colour:
the observer cannot hear which one the watched robot was told).
"""

from __future__ import annotations

import functools
import pathlib
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core import xla
from grounding_jax.core.io import pyplot, write_figure
from grounding_jax.learn import al
from grounding_jax.paper import al_eval
from grounding_jax.robot import observer
from grounding_jax.sim import placement as free_placement
from grounding_jax.sim import rollout, scene, scripted, tl_data
from grounding_jax.sim.env import Env, EnvConfig, EnvParams, Task

#: the goal: action and target words right on another agent's episodes (joint route)
GOAL = 0.95
#: RL steps of a watched episode (the env's episode length: what an episode lasts)
STEPS = 75
#: steps a scripted movement takes to reach its pose (a learned actor takes ~10-20)
SCRIPT_APPROACH = 35


def paper_tasks(key: jax.Array, n: int) -> Task:
    """``n`` paper-family tasks: actions and slots in turn, layouts drawn from ``key``."""
    layout = np.asarray(jax.random.randint(key, (n,), 0, len(scene.LAYOUTS)))
    i = np.arange(n)
    return jax.device_put(Task(action=(i % 3).astype(np.int32),
                               position=(i // 3 % 3).astype(np.int32),
                               layout=layout.astype(np.int32)))


def free_tasks(key: jax.Array, n: int) -> Task:
    """``n`` free-family tasks: random placements (and layouts) from ``key``, each placement's
    9 commands (actions and slots in turn) before the next placement's."""
    placements = -(-n // 9)
    tasks = al_eval.free_tasks(key, placements)  # action-major: [3 actions, 3 slots, P]
    order = np.arange(9 * placements).reshape(3, 3, placements).transpose(2, 1, 0).ravel()
    return jax.device_put(jax.tree.map(lambda x: np.asarray(x)[order[:n]], tasks))


@functools.lru_cache(maxsize=8)
def _runner(config: EnvConfig, steps: int):
    """Jitted greedy episodes of one agent over a batch of tasks: (states [N, T], success)."""
    env = Env(config)
    evaluate = al.make_eval(env, steps)

    def one(agent, key, task, params):
        _, traj, _ = evaluate(agent, key, task, params)
        return traj, al_eval.episode_success(traj, task, task_set=env.tasks)["success"]

    return xla.physics_jit(jax.vmap(one, in_axes=(None, 0, 0, None)), config)


def agent_episodes(agent, config: EnvConfig, key: jax.Array, tasks: Task, params: EnvParams,
                   steps: int = STEPS):
    """Greedy episodes of ``agent`` on a batch of tasks: (states ``[N, steps]``, success
    ``[N]``)."""
    keys = jax.random.split(key, int(tasks.action.shape[0]))
    return _runner(config, steps)(agent, keys, tasks, params)


def _pose(action: jax.Array, xy: jax.Array) -> jax.Array:
    """The scripted movement's final pose (radians) for an action at table point ``xy``."""
    return jnp.stack([free_placement.pointing_pose(xy), free_placement.touch_pose(xy),
                      free_placement.push_pose(xy)])[action]


@functools.lru_cache(maxsize=8)
def _script_runner(config: EnvConfig, steps: int):
    """Jitted scripted episodes over a batch of tasks: (states [N, T], success)."""
    env = Env(config)
    # NumPy here, constants of the program once traced (no program of their own)
    home = np.radians(np.asarray(scene.HOME_POSE_DEG)).astype(np.float32)
    sweeps = np.stack([scripted.push_waypoints(p, steps) for p in range(3)]).astype(np.float32)
    pointing = np.asarray(scene.pointing_configs(), np.float32)

    def one(key, task: Task, params):
        placed = (jnp.asarray(free_placement.fixed()) if task.placement is None
                  else task.placement)
        pose = _pose(task.action, placed[task.position, :2])
        if task.placement is None:  # the paper's point: its stored pointing pose
            pose = jnp.where(task.action == 0, jnp.asarray(pointing)[task.position], pose)
        frac = jnp.minimum((jnp.arange(steps) + 1.0) / SCRIPT_APPROACH, 1.0)[:, None]
        path = home + frac * (pose - home)
        if task.placement is None:  # the paper's push: the sweep from behind the object
            path = jnp.where(task.action == 2, jnp.asarray(sweeps)[task.position], path)

        _, traj = rollout.run_episode(
            env, key, task, lambda s: scripted.tracking_action(path, s.step, s.obs), params,
            steps)
        return traj, al_eval.episode_success(traj, task, task_set=env.tasks)["success"]

    return xla.physics_jit(jax.vmap(one, in_axes=(0, 0, None)), config)


def scripted_episodes(config: EnvConfig, key: jax.Array, tasks: Task, params: EnvParams,
                      steps: int = STEPS):
    """Scripted episodes (see module doc) on a batch of tasks: (states, success)."""
    keys = jax.random.split(key, int(tasks.action.shape[0]))
    return _script_runner(config, steps)(keys, tasks, params)


def judge(robot, states, tasks: Task, success) -> dict:
    """Watch a batch of episodes and score the naming.

    Returns:
        ``acc`` (both words right), ``action_acc``, ``target_acc``, ``command_acc`` (the
        resonance's action and slot right), ``acc_succeeded`` (over the episodes the watched
        robot did right), ``confusion`` (``[true action][named action]`` counts), ``n``.
    """
    rows = robot.resonance(states)
    names = tuple(robot.env_config.tasks.action_names)
    action, slot = np.asarray(tasks.action), np.asarray(tasks.position)
    layout, ok_run = np.asarray(tasks.layout), np.asarray(success) > 0
    named_a = np.array([names.index(r["named"][0]) if r["named"] else -1 for r in rows])
    named_w = np.array([tl_data.word_index(r["named"][1]) if r["named"] else -1
                        for r in rows])
    cmd_a = np.array([names.index(r["action"]) for r in rows])
    cmd_p = np.array([scene.POSITIONS.index(r["position"]) for r in rows])
    a_ok = named_a == action
    t_ok = np.array([w >= 0 and observer.names_target(lay, w, s)
                     for w, lay, s in zip(named_w, layout, slot, strict=True)])
    both = a_ok & t_ok
    confusion = np.zeros((len(names), len(names)), int)
    for t, n in zip(action, named_a, strict=True):
        if n >= 0:
            confusion[t, n] += 1
    return {"n": len(rows), "acc": float(both.mean()), "action_acc": float(a_ok.mean()),
            "target_acc": float(t_ok.mean()),
            "command_acc": float(((cmd_a == action) & (cmd_p == slot)).mean()),
            "acc_succeeded": float(both[ok_run].mean()) if ok_run.any() else None,
            "watched_success": float(ok_run.mean()), "confusion": confusion.tolist()}


def _pool(parts: list[dict]) -> dict:
    """Per-agent results pooled: the median agent, the spread, the summed confusion."""
    accs = [p["acc"] for p in parts]
    return {"acc_median": float(np.median(accs)), "acc_min": float(np.min(accs)),
            "acc_max": float(np.max(accs)), "acc_per_agent": accs,
            "acc_pooled": float(np.average(accs, weights=[p["n"] for p in parts])),
            "confusion": np.sum([p["confusion"] for p in parts], axis=0).tolist(),
            "agents": parts}


class _Family(NamedTuple):
    """What watching one family's episodes needs."""

    config: EnvConfig
    params: EnvParams
    tasks: Callable[[jax.Array, int], Task]  # (key, n) -> n tasks
    n_agents: int
    saved: int | None
    agent: Callable[[int], Any]  # i -> agent i


def _families(robot) -> dict[str, _Family | None]:
    """The robot's families (None where it has no modules for one)."""
    free = robot.free
    return {"paper": _Family(robot.env_config, EnvParams(), paper_tasks, robot.n_agents,
                             robot.saved_agent, lambda i: robot.with_agent(i).al.agent),
            "free": None if free is None else _Family(
                free.env_config, free.params, free_tasks, free.n_agents, free.saved_agent,
                lambda i: robot.with_free_agent(i).free.al.agent)}


def run(key: jax.Array, out: Any, robot, episodes: int, scripted_per_family: int) -> dict:
    """Watch other agents and scripted movements, in both families when the robot has them.

    Args:
        key: one PRNG key, split once here.
        out: output folder (``observer.json``, ``observer.png``).
        robot: the observer (`grounding_jax.robot.trained.Robot`), with ``agents``
            (and ``free.agents``) saved: the watched agents are all but its own.
        episodes: watched episodes per other agent.
        scripted_per_family: scripted episodes per family.

    Returns:
        ``other_agent`` (the median watched agent's accuracy, both families' agents
        together), ``frames`` (None: naming from frames is the ``watch_frames``
        stage's), ``paper``, ``free`` and ``scripted`` (see `judge`), ``goal``.
    """
    out = pathlib.Path(out)
    k_paper, k_free, k_script = jax.random.split(key, 3)
    res: dict[str, Any] = {"episodes_per_agent": episodes, "steps": STEPS, "goal": GOAL,
                           "frames": None,
                           "frames_note": "naming from frames only is the watch_frames "
                                          "stage (stages.watch_frames in metrics.json)"}
    families = _families(robot)
    parts = []
    for (name, fam), k_fam in zip(families.items(), (k_paper, k_free), strict=True):
        if fam is None or fam.n_agents < 2:
            continue
        per = []
        for i, k in zip(range(fam.n_agents), jax.random.split(k_fam, fam.n_agents),
                        strict=True):
            if i == fam.saved:
                continue
            k_task, k_run = jax.random.split(k)
            tasks = fam.tasks(k_task, episodes)
            states, ok = agent_episodes(fam.agent(i), fam.config, k_run, tasks, fam.params)
            per.append({"agent": i, **judge(robot, states, tasks, ok)})
        res[name] = _pool(per)
        parts += per
    if "paper" not in res:
        res["paper_note"] = "not watched: the modules hold no other paper-family AL agent"
    if "free" not in res:
        res["free_note"] = "not watched: the modules hold no other free-family agent"
    res["other_agent"] = (float(np.median([p["acc"] for p in parts])) if parts else None)
    res["scripted"] = {}
    k_sp, k_sf, k_rp, k_rf = jax.random.split(k_script, 4)
    for (name, fam), k_task, k_run in zip(families.items(), (k_sp, k_sf), (k_rp, k_rf),
                                          strict=True):
        if fam is not None:
            tasks = fam.tasks(k_task, scripted_per_family)
            states, ok = scripted_episodes(fam.config, k_run, tasks, fam.params)
            res["scripted"][name] = judge(robot, states, tasks, ok)
    figure(res, out, tuple(robot.env_config.tasks.action_names))
    return res


def figure(res: dict, out: pathlib.Path, names: tuple[str, ...]) -> None:
    """The confusion of true and named actions, per source of watched episodes."""
    plt = pyplot()
    panels = [(f"{fam} family, other agents", res[fam]["confusion"])
              for fam in ("paper", "free") if fam in res]
    panels += [(f"{fam} family, scripted", r["confusion"])
               for fam, r in res["scripted"].items()]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.4 * len(panels), 3.4), squeeze=False)
    for ax, (title, m) in zip(axes[0], panels, strict=True):
        m = np.asarray(m)
        ax.imshow(m, cmap="Blues")
        for i in range(m.shape[0]):
            for j in range(m.shape[1]):
                ax.text(j, i, str(m[i, j]), ha="center", va="center", fontsize=9)
        ax.set_xticks(range(len(names)), names)
        ax.set_yticks(range(len(names)), names)
        ax.set_xlabel("named")
        ax.set_ylabel("done")
        ax.set_title(title, fontsize=9)
    fig.suptitle("The observer naming watched actions (motor resonance, joint route)")
    fig.tight_layout()
    write_figure(out, "observer", res, fig)  # observer.json: every figure of the part

