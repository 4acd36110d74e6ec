"""The C MuJoCo backend's rollout wrapper against a plain mj_step loop."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from grounding_jax import physics, scene


def test_rollout_runner_equals_a_plain_mj_step_loop():
    m = scene.model()
    idx = scene.index()
    rng = np.random.default_rng(0)
    qpos = np.tile(scene.home_qpos(), (5, 1))
    qpos[:, idx.arm_qpos] += rng.uniform(-0.2, 0.2, (5, 4))
    qvel = np.zeros((5, m.nv))
    qvel[:, idx.arm_dof] = rng.uniform(-0.5, 0.5, (5, 4))
    ctrl = qpos[:, idx.arm_qpos] + rng.uniform(-0.1, 0.1, (5, 4))
    q1, v1, s1 = physics.mujoco_runner().step(qpos.astype(np.float32), qvel.astype(np.float32),
                                              ctrl.astype(np.float32), 7)
    d = mujoco.MjData(m)
    for i in range(5):
        d.qpos[:] = qpos[i].astype(np.float32)
        d.qvel[:] = qvel[i].astype(np.float32)
        d.ctrl[:] = ctrl[i].astype(np.float32)
        d.qacc_warmstart[:] = 0.0
        d.time = 0.0
        for _ in range(7):
            mujoco.mj_step(m, d)
        np.testing.assert_allclose(q1[i], d.qpos, atol=1e-6)
        np.testing.assert_allclose(v1[i], d.qvel, atol=1e-5)
        np.testing.assert_allclose(s1[i], d.sensordata, atol=1e-5)
    assert not np.allclose(q1[0], qpos[0])  # it did move


def test_unknown_backend_names_the_accepted_values():
    with pytest.raises(ValueError, match=r"backend: unknown value 'bullet'.*'mujoco', 'mjx'"):
        physics.make_physics("bullet", 10)
