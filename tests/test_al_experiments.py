"""Success criteria of the AL evaluation on hand-made trajectories (analytic answers)."""

from __future__ import annotations

import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from grounding_jax.paper import al_eval
from grounding_jax.sim.env import Task

N = 100


def _traj(l1=1.0, touched_at=(), moved=0.0, wrong_at=-1, done_at=N - 1, l1_wobble=0.0):
    touched = np.zeros(N, np.float32)
    touched[list(touched_at)] = 1.0
    steps = np.arange(N)
    wrong = np.where((wrong_at >= 0) & (steps >= wrong_at), wrong_at, -1)
    l1s = l1 + l1_wobble * (steps % 2)  # a period-2 oscillation of the given amplitude
    return types.SimpleNamespace(
        reward=jnp.zeros(N), done=jnp.asarray(steps >= done_at), wrong_since=jnp.asarray(wrong),
        metrics={"point_l1": jnp.asarray(l1s, jnp.float32),
                 "touched_target": jnp.asarray(touched),
                 "target_moved": jnp.full(N, moved)})


def _task(action: int) -> Task:
    return Task(jnp.int32(action), jnp.int32(0), jnp.int32(0))


@pytest.mark.parametrize("action, traj, ok", [
    (0, _traj(l1=0.05), 1.0),
    (0, _traj(l1=0.15), 0.0),
    (0, _traj(l1=0.05, l1_wobble=0.03), 0.0),  # oscillating: L1 range 0.03 >= 0.02
    (0, _traj(l1=0.05, l1_wobble=0.01), 1.0),
    (0, _traj(l1=0.05, moved=0.015), 0.0),  # pointing knocked its target
    (0, _traj(l1=0.05, wrong_at=40), 0.0),  # or another object
    (1, _traj(touched_at=(N - 3,)), 1.0),
    (1, _traj(touched_at=(N // 2,)), 1.0),  # the first step of the second half
    (1, _traj(touched_at=(N // 2 - 1,)), 0.0),  # only in the first half
    (1, _traj(touched_at=(80,), moved=0.04), 0.0),  # touched, but shoved the target
    (1, _traj(touched_at=(80,), moved=0.02), 1.0),
    (1, _traj(touched_at=(N - 3,), wrong_at=70), 0.0),  # a wrong object moved
    (2, _traj(moved=0.03), 1.0),
    (2, _traj(moved=0.01), 0.0),
    (2, _traj(moved=0.05, wrong_at=10), 0.0),
    (2, _traj(moved=0.05, touched_at=(5,)), 1.0),  # push ignores when it touched
])
def test_episode_success(action, traj, ok):
    assert float(al_eval.episode_success(traj, _task(action))["success"]) == ok


def test_switch_success_counts_only_what_moved_after_the_switch():
    # objects: [steps, shape, 3] in qpos; the target of (push, left, layout 0) is the box
    from grounding_jax.sim import scene
    idx = scene.index()
    qpos = np.zeros((N, idx.nq), np.float32)
    box, sphere = (idx.object_qpos[scene.SHAPES.index(s), 0] for s in ("box", "sphere"))
    qpos[:10, sphere] = 0.0
    qpos[10:, sphere] = 0.05  # the sphere was pushed before the switch (step 20)...
    qpos[60:, box] = 0.03  # ...the box, the second task's target, after it
    t = types.SimpleNamespace(reward=jnp.zeros(N), done=jnp.zeros(N, bool),
                              wrong_since=jnp.full(N, 10), qpos=jnp.asarray(qpos),
                              metrics={"point_l1": jnp.ones(N),
                                       "touched_target": jnp.zeros(N),
                                       "target_moved": jnp.zeros(N)})
    def judge(traj, task):  # under jit: the task is traced, as in make_switch_success
        f = jax.jit(lambda q, tk: al_eval.episode_success(types.SimpleNamespace(
            **{**vars(traj), "qpos": q}), tk, since=20))
        return f(traj.qpos, task)

    out = judge(t, Task(jnp.int32(2), jnp.int32(0), jnp.int32(0)))
    assert float(out["success"]) == 1.0 and float(out["target_moved"]) == pytest.approx(0.03)
    qpos[70:, sphere] = 0.08  # the sphere moving again after the switch is a wrong move
    t.qpos = jnp.asarray(qpos)
    assert float(judge(t, Task(jnp.int32(2), jnp.int32(0), jnp.int32(0)))["success"]) == 0.0


def test_switch_pairs_change_the_action_or_the_position():
    first, second = al_eval.switch_pairs((0,))
    assert first.action.shape == (36,)
    same_a = np.asarray(first.action) == np.asarray(second.action)
    same_p = np.asarray(first.position) == np.asarray(second.position)
    assert np.all(same_a ^ same_p)  # exactly one of the two changes


def test_success_table_groups_by_action_and_task():
    tasks = al_eval.all_tasks((0, 6))
    assert tasks.action.shape == (18,)
    s = np.zeros((2, 1, 18), np.float32)
    s[:, :, np.asarray(tasks.action) == 2] = 1.0  # every push succeeded
    s[0, :, (np.asarray(tasks.action) == 0) & (np.asarray(tasks.position) == 1)] = 1.0
    t = al_eval.success_table({"success": s, "action": tasks.action, "position": tasks.position})
    # by_action is the median agent's rate (agent 0: 2/6 of point, agent 1: 0)
    assert t["by_action"] == {"point": pytest.approx(1 / 6), "touch": 0.0, "push": 1.0}
    assert t["spread"]["point"][0] == 0.0 and t["spread"]["point"][-1] == pytest.approx(2 / 6)
    assert t["pooled"]["point"] == pytest.approx(1 / 6)
    assert t["by_task"]["point middle"] == 0.5 and t["by_task"]["point left"] == 0.0
    assert t["per_agent"] == pytest.approx([8 / 18, 6 / 18])
