"""The counters behind metrics.json's speed figures: XLA programs built, RL steps simulated
and the rollout-alone ceiling."""

from __future__ import annotations

import numpy as np

from grounding_jax.core import compiles
from grounding_jax.sim import physics, scene


def test_the_tally_counts_each_new_program_once_and_not_its_reuse():
    import jax
    import jax.numpy as jnp

    compiles.install()
    compiles.install()  # idempotent: one listener, not two

    @jax.jit
    def f(x):
        return jnp.sin(x) * 3.0 + 0.123456  # a program no other test builds

    before = compiles.tally()  # NumPy inputs: no eager program besides f
    f(np.ones(3, np.float32)).block_until_ready()
    f(np.zeros(3, np.float32)).block_until_ready()  # same shapes: reused, not built again
    once = compiles.tally() - before
    f(np.ones(4, np.float32)).block_until_ready()  # a new shape: a new program
    twice = compiles.tally() - before
    assert once.programs == 1 and twice.programs == 2
    assert once.by_name == {"jit(f)": 1}
    d = twice.as_dict(top=3)
    assert d["compiled"] + d["from_cache"] == 2 and d["most_built"] == {"jit(f)": 2}
    assert set(d["seconds"]) == {"trace", "lower", "build"} and twice.stages["build"] > 0


def test_the_physics_meter_counts_rl_steps_and_measures_a_ceiling():
    m, idx = scene.model(), scene.index()
    meter = physics.PhysicsMeter(m.nq, m.nv, m.nu, keep=8)
    state = np.zeros((5, 1 + m.nq + m.nv))
    state[:, 1:1 + m.nq] = scene.home_qpos()
    ctrl = np.tile(scene.home_qpos()[idx.arm_qpos], (5, 1))
    for _ in range(2 * meter.EVERY):
        meter.sample(state, ctrl, 10)
    meter.sample(state[:2], ctrl[:2], 7)
    assert meter.rl_steps == {10: 10 * meter.EVERY, 7: 2}
    assert meter.calls == 2 * meter.EVERY + 1
    assert meter._filled == 8  # 2 sampled calls of 5 rows, a reservoir of 8
    rate = meter.ceiling(physics.mujoco_runner(), batch=4, repeats=1)
    assert rate is not None and rate > 0
    empty = physics.PhysicsMeter(m.nq, m.nv, m.nu)
    assert empty.ceiling(physics.mujoco_runner()) is None


def test_the_runner_counts_only_the_live_rows_it_simulates():
    runner = physics.mujoco_runner()
    m, idx = runner.model, scene.index()
    qpos = np.tile(scene.home_qpos(), (4, 1)).astype(np.float32)
    qvel = np.zeros((4, m.nv), np.float32)
    ctrl = qpos[:, idx.arm_qpos]
    before = dict(runner.meter.rl_steps)
    runner.step(qpos, qvel, ctrl, 3, np.array([True, False, True, False]))
    assert runner.meter.rl_steps[3] - before.get(3, 0) == 2
