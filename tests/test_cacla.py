"""CACLA: gradients, the update rules (phase 1 and 2), critic convergence, vmap, bad input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from grounding_jax.learn import cacla

CFG = cacla.CaclaConfig()
CFG_SHAPES = {"w1": (11, 40)}


@pytest.fixture(scope="module")
def agent():
    return cacla.init(jax.random.key(0), CFG)


def _obs(seed: int) -> jax.Array:
    return jax.random.uniform(jax.random.key(seed), (11,), minval=-1, maxval=1)


def _fd_check(f, params, eps=1e-2, n=12):
    """Central finite differences of scalar ``f`` against ``jax.grad`` on random entries."""
    flat, unravel = ravel_pytree(params)
    grad = ravel_pytree(jax.grad(f)(params))[0]
    for i in np.random.default_rng(0).choice(flat.size, size=n, replace=False):
        e = jnp.zeros_like(flat).at[i].set(eps)
        fd = (f(unravel(flat + e)) - f(unravel(flat - e))) / (2 * eps)
        assert abs(float(fd) - float(grad[i])) < 1e-3 + 1e-2 * abs(float(grad[i])), i


def test_actor_and_critic_gradients_match_finite_differences(agent):
    obs = _obs(1)
    w = jnp.array([0.3, -0.7, 0.2, 0.5])
    _fd_check(lambda a: jnp.dot(cacla.actor_apply(a, obs)[1], w), agent.actor)
    _fd_check(lambda c: cacla.critic_apply(c, obs), agent.critic)


def test_written_out_gradients_equal_autodiff(agent):
    # update() uses hand-written gradients (fixed-order sums, batch-invariant); they must be
    # the networks' true gradients
    obs, err = _obs(3), jnp.array([0.3, -0.7, 0.2, 0.5])
    h, v = cacla._critic(agent.critic, obs)
    auto = jax.grad(cacla.critic_apply)(agent.critic, obs)
    for a, b in zip(jax.tree.leaves(cacla._critic_grad(agent.critic, obs, h)),
                    jax.tree.leaves(auto), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-7)
    h, mean = cacla.actor_apply(agent.actor, obs)
    auto = jax.grad(lambda a: jnp.dot(cacla.actor_apply(a, obs)[1], err))(agent.actor)
    for a, b in zip(jax.tree.leaves(cacla._actor_grad(agent.actor, obs, h, mean, err)),
                    jax.tree.leaves(auto), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-7)


def _transition(agent, reward, prev_reward=0.0, seed=2):
    obs, nxt = _obs(seed), _obs(seed + 100)
    a, _ = cacla.act(agent, obs, jax.random.key(seed), cacla.CaclaHyper(sigma=0.3))
    return cacla.Transition(obs=obs, action=a, reward=jnp.float32(reward), next_obs=nxt,
                            done=jnp.bool_(False), prev_reward=jnp.float32(prev_reward))


def _changed(a, b) -> bool:
    return any(not np.array_equal(np.asarray(x), np.asarray(y))
               for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def test_phase2_moves_the_actor_only_when_delta_is_positive(agent):
    hp = cacla.CaclaHyper(gamma=0.0, phase1=0.0, actor_lr=0.1)
    v = float(cacla.critic_apply(agent.critic, _obs(2)))
    for reward, should_move in [(v + 0.5, True), (v - 0.5, False), (v, False)]:
        tr = _transition(agent, reward)
        new, info = cacla.update(agent, tr, hp)
        assert float(info["delta"]) == pytest.approx(reward - v, abs=1e-5)
        assert _changed(new.actor, agent.actor) is should_move
        assert float(info["actor_updated"]) == float(should_move)
        if reward != v:
            assert _changed(new.critic, agent.critic)


def test_actor_moves_toward_the_explored_action(agent):
    tr = _transition(agent, 10.0)
    new, _ = cacla.update(agent, tr, cacla.CaclaHyper(actor_lr=0.05))
    before = cacla.actor_apply(agent.actor, tr.obs)[1]
    after = cacla.actor_apply(new.actor, tr.obs)[1]
    assert float(jnp.linalg.norm(after - tr.action)) < float(jnp.linalg.norm(before - tr.action))


def test_phase1_uses_the_reward_rise_not_delta(agent):
    hp = cacla.CaclaHyper(phase1=1.0, actor_lr=0.1)
    v = float(cacla.critic_apply(agent.critic, _obs(2)))
    # delta < 0 but the reward rose: the actor moves
    new, _ = cacla.update(agent, _transition(agent, v - 1.0, prev_reward=v - 2.0), hp)
    assert _changed(new.actor, agent.actor)
    # delta > 0 but the reward fell: it does not
    new, _ = cacla.update(agent, _transition(agent, v + 1.0, prev_reward=v + 2.0), hp)
    assert not _changed(new.actor, agent.actor)


@pytest.mark.parametrize("gamma, reward, value", [(0.0, -0.7, -0.7), (0.5, 0.4, 0.8)])
def test_critic_converges_on_a_one_state_bandit(agent, gamma, reward, value):
    # one state looping onto itself: V = r / (1 - gamma)
    obs = _obs(3)
    hp = cacla.CaclaHyper(critic_lr=0.05, gamma=gamma)
    tr = cacla.Transition(obs=obs, action=jnp.zeros(4), reward=jnp.float32(reward),
                          next_obs=obs, done=jnp.bool_(False), prev_reward=jnp.float32(0))

    def body(a, _):
        return cacla.update(a, tr, hp)[0], None

    trained, _ = jax.lax.scan(body, agent, None, length=2000)
    assert float(cacla.critic_apply(trained.critic, obs)) == pytest.approx(value, abs=1e-3)


def test_vmapped_update_equals_a_loop(agent):
    agents = jax.vmap(lambda k: cacla.init(k, CFG))(jax.random.split(jax.random.key(5), 3))
    trs = [_transition(jax.tree.map(lambda x, i=i: x[i], agents), r, seed=10 + i)
           for i, r in enumerate([1.0, -1.0, 0.3])]
    batch = jax.tree.map(lambda *x: jnp.stack(x), *trs)
    hp = cacla.CaclaHyper(actor_lr=0.01)
    out, _ = jax.jit(jax.vmap(lambda a, t: cacla.update(a, t, hp)))(agents, batch)
    for i in range(3):  # bit for bit (the sums add in one order alone and batched)
        one, _ = jax.jit(lambda a, t: cacla.update(a, t, hp))(
            jax.tree.map(lambda x, i=i: x[i], agents), trs[i])
        for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(out), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b)[i])


def test_cacla_var_repeats_large_improvements(agent):
    cfg = cacla.CaclaConfig(var=True)
    hp = cacla.CaclaHyper(actor_lr=0.01)
    small = _transition(agent, float(cacla.critic_apply(agent.critic, _obs(2))) + 0.1)
    big = small.replace(reward=small.reward + 5.0)
    d_small = cacla.update(agent, small, hp, cfg)[0].actor.w2 - agent.actor.w2
    d_big = cacla.update(agent, big, hp, cfg)[0].actor.w2 - agent.actor.w2
    assert float(jnp.abs(d_big).sum()) > 3 * float(jnp.abs(d_small).sum())


@pytest.mark.parametrize("kwargs, field", [
    (dict(actor_lr=-0.001), "actor_lr"), (dict(critic_lr=0.0), "critic_lr"),
    (dict(sigma=0.0), "sigma"), (dict(sigma=-1.0), "sigma"), (dict(gamma=1.5), "gamma"),
    (dict(phase1=0.5), "phase1"),
])
def test_invalid_hyperparameters_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        cacla.validate(cacla.CaclaHyper(**kwargs))


def test_invalid_sizes_name_the_field():
    with pytest.raises(ValueError, match="actor_hidden"):
        cacla.CaclaConfig(actor_hidden=0)
    with pytest.raises(ValueError, match="critic_hidden"):
        cacla.CaclaConfig(critic_hidden=-3)


def test_unused_hidden_units_stay_zero_and_change_nothing():
    """A 3/2-unit agent built at 8/6 units computes what the 3/2-unit agent computes."""
    key = jax.random.key(3)
    small = cacla.init(key, cacla.CaclaConfig(actor_hidden=3, critic_hidden=2))
    big = cacla.init(key, cacla.CaclaConfig(actor_hidden=8, critic_hidden=6), actor_units=3,
                     critic_units=jnp.asarray(2))  # units may be traced values
    # the used units get the same weights (each unit has its own key), the rest zeros
    np.testing.assert_array_equal(big.actor.w1[:, :3], small.actor.w1)
    np.testing.assert_array_equal(big.actor.w2[:3], small.actor.w2)
    np.testing.assert_array_equal(big.critic.w2[:2], small.critic.w2)
    assert not np.any(big.actor.w1[:, 3:]) and not np.any(big.critic.w2[2:])
    hp = cacla.CaclaHyper(actor_lr=0.1, critic_lr=0.1, gamma=0.5)
    rng = np.random.default_rng(0)
    update = jax.jit(cacla.update)
    for _ in range(20):
        obs, nxt = (jnp.asarray(rng.uniform(-1, 1, 11), jnp.float32) for _ in range(2))
        tr = cacla.Transition(obs=obs, action=jnp.asarray(rng.uniform(-1, 1, 4), jnp.float32),
                              reward=jnp.asarray(rng.uniform(-1, 0), jnp.float32),
                              next_obs=nxt, done=jnp.asarray(False),
                              prev_reward=jnp.asarray(-1.0))
        small, _ = update(small, tr, hp)
        big, _ = update(big, tr, hp)
    assert not np.any(big.actor.w1[:, 3:]) and not np.any(big.actor.w2[3:])
    assert not np.any(big.critic.w1[:, 2:]) and not np.any(big.critic.w2[2:])
    np.testing.assert_allclose(big.actor.w1[:, :3], small.actor.w1, atol=1e-6)
    np.testing.assert_allclose(big.critic.w2[:2], small.critic.w2, atol=1e-6)
    obs = jnp.linspace(-1, 1, 11)
    np.testing.assert_allclose(cacla.actor_apply(big.actor, obs)[1],
                               cacla.actor_apply(small.actor, obs)[1], atol=1e-6)
    np.testing.assert_allclose(cacla.critic_apply(big.critic, obs),
                               cacla.critic_apply(small.critic, obs), atol=1e-6)


@pytest.mark.parametrize("heads", [(0, 1, 2), (0, 1, 1)])
def test_actions_with_their_own_network_learn_only_from_their_own_episodes(heads):
    """An update on touch (action 1) changes touch's network -- and push's, where the two
    share one -- and leaves point's as it was; each slot computes what a plain network with
    its leaves computes."""
    agent = cacla.init(jax.random.key(4), cacla.CaclaConfig(heads=heads))
    assert agent.actor.w1.shape == (3, *CFG_SHAPES["w1"]) and agent.critic.b2.shape == (3, 1)
    shares = np.asarray(heads) == heads[1]  # the slots that are touch's network
    for net in (agent.actor, agent.critic):
        for leaf in jax.tree.leaves(net):
            np.testing.assert_array_equal(leaf[1], leaf[np.flatnonzero(shares)[-1]])
        assert np.any(net.w1[0] != net.w1[1]) and np.any(net.w2[0] != net.w2[1])
    obs = _obs(1).at[5:8].set(jnp.array([0.0, 1.0, 0.0]))  # the action one-hot: touch
    tr = cacla.Transition(obs=obs, action=jnp.full(4, 0.5), reward=jnp.asarray(1.0),
                          next_obs=obs, done=jnp.asarray(False), prev_reward=jnp.asarray(0.0))
    hp = cacla.CaclaHyper(actor_lr=0.1, critic_lr=0.1, phase1=1.0)
    new, info = cacla.update(agent, tr, hp, cacla.CaclaConfig(heads=heads))
    assert info["actor_updated"] == 1.0
    for old, now in zip(jax.tree.leaves(agent.actor) + jax.tree.leaves(agent.critic),
                        jax.tree.leaves(new.actor) + jax.tree.leaves(new.critic), strict=True):
        old, now = np.asarray(old), np.asarray(now)
        np.testing.assert_array_equal(old[~shares], now[~shares])
        assert np.all(np.any((old != now).reshape(3, -1), axis=1) == shares)
        np.testing.assert_array_equal(now[1], now[np.flatnonzero(shares)[-1]])
    plain = cacla.head(new.actor, obs)
    assert plain.w1.shape == CFG_SHAPES["w1"]
    np.testing.assert_array_equal(cacla.actor_apply(new.actor, obs)[1],
                                  cacla.actor_apply(plain, obs)[1])
    point = obs.at[5:8].set(jnp.array([1.0, 0.0, 0.0]))
    np.testing.assert_array_equal(cacla.actor_apply(new.actor, point)[1],
                                  cacla.actor_apply(cacla.head(agent.actor, point), point)[1])


def test_cacla_var_keeps_a_running_variance_per_network():
    """With networks per action, a touch transition updates the running variance of touch and
    push's network only; point's stays as it was."""
    cfg = cacla.CaclaConfig(var=True, heads=(0, 1, 1))
    agent = cacla.init(jax.random.key(4), cfg)
    assert agent.var_delta.shape == (3,)
    assert cacla.init(jax.random.key(4), cacla.CaclaConfig(heads=(0, 1, 1))).var_delta.shape == ()
    obs = _obs(1).at[5:8].set(jnp.array([0.0, 1.0, 0.0]))  # touch
    tr = cacla.Transition(obs=obs, action=jnp.full(4, 0.5), reward=jnp.asarray(3.0),
                          next_obs=obs, done=jnp.asarray(False), prev_reward=jnp.asarray(0.0))
    hp = cacla.CaclaHyper(actor_lr=0.01, var_beta=0.5)
    new, info = cacla.update(agent, tr, hp, cfg)
    delta = float(info["delta"])
    np.testing.assert_allclose(np.asarray(new.var_delta),
                               [1.0, 0.5 + 0.5 * delta ** 2, 0.5 + 0.5 * delta ** 2], rtol=1e-6)


@pytest.mark.parametrize("heads", [(0, 1), (0, 2, 2), (1, 1, 1), "abc"])
def test_bad_heads_name_the_field_and_what_is_accepted(heads):
    with pytest.raises(ValueError, match=r"heads: got .*one network index per action"):
        cacla.CaclaConfig(heads=heads)
    assert cacla.CaclaConfig(heads=[0, 1, 1]).heads == (0, 1, 1)  # from JSON: a list
