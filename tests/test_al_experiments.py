"""Success criteria of the AL evaluation on hand-made trajectories (analytic answers)."""

from __future__ import annotations

import types

import jax.numpy as jnp
import numpy as np
import pytest

from grounding_jax import al_experiments as ax
from grounding_jax.env import Task

N = 75


def _traj(l1=1.0, touched_at=(), moved=0.0, wrong_at=-1, done_at=N - 1):
    touched = np.zeros(N, np.float32)
    touched[list(touched_at)] = 1.0
    steps = np.arange(N)
    wrong = np.where((wrong_at >= 0) & (steps >= wrong_at), wrong_at, -1)
    return types.SimpleNamespace(
        reward=jnp.zeros(N), done=jnp.asarray(steps >= done_at), wrong_since=jnp.asarray(wrong),
        metrics={"point_l1": jnp.full(N, l1), "touched_target": jnp.asarray(touched),
                 "target_moved": jnp.full(N, moved)})


def _task(action: int) -> Task:
    return Task(jnp.int32(action), jnp.int32(0), jnp.int32(0))


@pytest.mark.parametrize("action, traj, ok", [
    (0, _traj(l1=0.05), 1.0),
    (0, _traj(l1=0.15), 0.0),
    (1, _traj(touched_at=(N - 3,)), 1.0),
    (1, _traj(touched_at=(N - 11,)), 0.0),  # not in the last 10 steps
    (1, _traj(touched_at=(N - 3,), wrong_at=70), 0.0),  # a wrong object moved
    (1, _traj(touched_at=(30,), done_at=35), 1.0),  # episode ended early: its own last steps
    (2, _traj(moved=0.03), 1.0),
    (2, _traj(moved=0.01), 0.0),
    (2, _traj(moved=0.05, wrong_at=10), 0.0),
    (0, _traj(l1=0.05, touched_at=(N - 1,), moved=0.5), 1.0),  # point ignores touch and push
])
def test_episode_success(action, traj, ok):
    assert float(ax.episode_success(traj, _task(action))["success"]) == ok


def test_success_table_groups_by_action_and_task():
    tasks = ax.all_tasks((0, 6))
    assert tasks.action.shape == (18,)
    s = np.zeros((2, 1, 18), np.float32)
    s[:, :, np.asarray(tasks.action) == 2] = 1.0  # every push succeeded
    s[0, :, (np.asarray(tasks.action) == 0) & (np.asarray(tasks.position) == 1)] = 1.0
    t = ax.success_table({"success": s, "action": tasks.action, "position": tasks.position})
    assert t["by_action"] == {"point": pytest.approx(1 / 6), "touch": 0.0, "push": 1.0}
    assert t["by_task"]["point middle"] == 0.5 and t["by_task"]["point left"] == 0.0
    assert t["per_agent"] == pytest.approx([8 / 18, 6 / 18])
