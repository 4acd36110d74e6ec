"""The sequential reference (benchmarks/reference_cacla.py) is the same algorithm: its env gives
the JAX env's observations and rewards for the same actions, and its NumPy CACLA update equals
``cacla.update`` on the same weights and transition."""

from __future__ import annotations

import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grounding_jax as gj
from grounding_jax.learn import al, cacla
from grounding_jax.sim import scene

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "benchmarks"))
import reference_cacla as ref  # noqa: E402


@pytest.mark.parametrize("action, position, layout", [("point", "left", 0), ("push", "middle", 7),
                                                      ("touch", "right", 30)])
def test_reference_env_matches_the_jax_env(env_c, action, position, layout):
    # a smooth action sequence that reaches over the objects (touch/push make contacts)
    t = np.arange(40)[:, None]
    actions = np.clip(0.6 * np.sin(0.15 * t + np.array([0.0, 1.0, 2.0, 3.0])), -1, 1)
    actions[5:8] = [1.4, -1.2, 1.3, 1.5]  # beyond the actor's range: the executed one is clipped
    task = gj.make_task(action, position, layout)
    step = jax.jit(env_c.step)
    s = env_c.reset(jax.random.key(0), task)
    e = ref.SequentialEnv()
    obs, r = e.reset(int(task.action), int(task.position), layout)
    np.testing.assert_allclose(obs, np.asarray(s.obs), atol=1e-5)
    assert r == pytest.approx(float(s.reward), abs=1e-5)
    contact = False
    arm = np.asarray(scene.index().arm_qpos)
    for a in actions:
        q = np.asarray(s.qpos)[arm]
        s = step(s, jnp.asarray(a, jnp.float32))
        obs, r, done = e.step(a)
        # the executed action (the shipped actor target) is computed alike
        np.testing.assert_allclose(e.executed, al.executed_action(q, s.info["ctrl"], 1 / 3),
                                   atol=5e-3 if contact else 1e-4)
        contact |= bool(obs[4])
        # Free motion agrees to float32 rounding. Contacts amplify the float32 (JAX state) vs
        # float64 (reference) difference: measured up to 2.2e-3 on a push.
        tol = 5e-3 if contact else 1e-5
        np.testing.assert_allclose(obs, np.asarray(s.obs), atol=tol)
        assert r == pytest.approx(float(s.reward), abs=tol)
        assert done == bool(s.done)
        if done:  # the JAX env's finished episode is absorbing; the reference stops here
            break
    assert contact  # the sequence reaches the objects: the contact path is compared too


@pytest.mark.parametrize("phase1, reward", [(0.0, 0.5), (0.0, -2.0), (1.0, 0.5), (1.0, -2.0)])
def test_reference_update_equals_cacla_update(phase1, reward):
    agent = cacla.init(jax.random.key(1))
    rng = np.random.default_rng(0)
    obs, nxt = rng.uniform(-1, 1, 11), rng.uniform(-1, 1, 11)
    a = rng.uniform(-1, 1, 4)
    hp = cacla.CaclaHyper(actor_lr=0.05, critic_lr=0.1, sigma=0.3, gamma=0.5, phase1=phase1)
    tr = cacla.Transition(obs=jnp.asarray(obs, jnp.float32), action=jnp.asarray(a, jnp.float32),
                          reward=jnp.float32(reward), next_obs=jnp.asarray(nxt, jnp.float32),
                          done=jnp.asarray(False), prev_reward=jnp.float32(0.0))
    new, info = cacla.update(agent, tr, hp)

    def net(m, out_tanh):
        return ref.Net(*(np.asarray(x, np.float64).copy() for x in (m.w1, m.b1, m.w2, m.b2)),
                       out_tanh=out_tanh)

    actor, critic = net(agent.actor, True), net(agent.critic, False)
    _, mean = actor.forward(obs)
    delta = reward + 0.5 * critic.forward(nxt)[1][0] - critic.forward(obs)[1][0]
    critic.step_along(obs, np.ones(1), 0.1 * delta)
    if (reward > 0.0) if phase1 else (delta > 0):
        actor.step_along(obs, a - mean, 0.05)
    assert delta == pytest.approx(float(info["delta"]), abs=1e-5)
    for got, want in ((new.actor, actor), (new.critic, critic)):
        for f in ("w1", "b1", "w2", "b2"):
            np.testing.assert_allclose(np.asarray(getattr(got, f)), getattr(want, f), atol=1e-5)
