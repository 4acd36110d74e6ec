"""AL training loop: determinism, vmap equivalence, config checks and that a point task is
learned (the greedy actor ends far closer to the pointing pose than an untrained one)."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from grounding_jax.core.checks import POSITIVE
from grounding_jax.learn import al, cacla, learners
from grounding_jax.sim import env as env_mod
from grounding_jax.sim import scene

SMALL = al.ALConfig(phase1_episodes=2, phase2_episodes=2)


@pytest.fixture(scope="module")
def small_train():
    return jax.jit(al.make_train(SMALL))


def test_same_seed_gives_identical_metrics_and_episodes_are_recorded(small_train):
    hp = al.ALHyper()
    _, m1 = small_train(jax.random.key(3), hp)
    _, m2 = small_train(jax.random.key(3), hp)
    for k in m1:
        np.testing.assert_array_equal(np.asarray(m1[k]), np.asarray(m2[k]))
    assert m1["return"].shape == (4,)
    assert np.all(np.asarray(m1["steps"]) >= 1) and np.all(np.asarray(m1["steps"]) <= 75)
    _, m3 = small_train(jax.random.key(4), hp)
    assert not np.array_equal(np.asarray(m1["return"]), np.asarray(m3["return"]))


def test_vmapped_agents_equal_separate_runs(small_train):
    keys = jax.random.split(jax.random.key(0), 3)
    lrs = jnp.array([0.001, 0.01, 0.003])
    hp = jax.tree.map(lambda x: jnp.broadcast_to(jnp.asarray(x), (3,)), al.ALHyper())
    hp = hp.replace(learner=hp.learner.replace(actor_lr=lrs))
    agents, ms = jax.jit(jax.vmap(al.make_train(SMALL)))(keys, hp)
    for i in range(3):
        hp_i = al.ALHyper(learner=cacla.CaclaHyper(actor_lr=lrs[i]))
        agent, m = small_train(keys[i], hp_i)
        for k in m:  # bit for bit: the networks' sums add in one order alone and batched
            np.testing.assert_array_equal(np.asarray(m[k]), np.asarray(ms[k][i]), err_msg=k)
        for a, b in zip(jax.tree.leaves(agent), jax.tree.leaves(agents), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b[i]))


@pytest.mark.parametrize("make, field", [
    (lambda: al.ALConfig.from_schedule("fast"), "schedule"),
    (lambda: al.ALConfig(phase1_episodes=-1), "phase1_episodes"),
    (lambda: al.ALConfig(actions=(0, 5)), "actions"),
    (lambda: al.validate(al.hyper(sigma=0.0)), "sigma"),
    (lambda: al.validate(al.hyper(actor_lr=-1.0)), "actor_lr"),
    (lambda: al.validate(al.hyper(sigma_decay=0.0)), "sigma_decay"),
    (lambda: al.validate(al.hyper(actor_lr_decay=1.5)), "actor_lr_decay"),
    (lambda: al.validate(al.hyper(actor_init_scale=0.0)), "actor_init_scale"),
    (lambda: al.hyper(actor_lr=0.1, step_size=1.0), "step_size"),
    (lambda: al.ALConfig(learner=object()), "learner"),
    (lambda: al.validate(al.ALHyper(executed_target=0.5)), "executed_target"),
])
def test_bad_config_names_the_field(make, field):
    with pytest.raises(ValueError, match=field):
        make()


def test_executed_action_is_the_clipped_servo_move():
    lo, hi = np.radians(scene.PAPER_LIMITS_DEG).T
    q = np.where(np.arange(4) == 3, hi, (lo + hi) / 2)  # joint 3 at its upper limit
    a = np.array([0.3, -0.6, 1.4, 0.5])  # joint 3 pushes further into its limit
    ctrl = np.clip(env_mod.unscale_joints(env_mod.scale_joints(q) + a / 3), lo, hi)
    got = np.asarray(al.executed_action(q, ctrl, 1 / 3))
    np.testing.assert_allclose(got, [0.3, -0.6, 1.0, 0.0], atol=1e-5)  # limited to [-1, 1]


def test_actor_init_scale_scales_the_first_actions():
    cfg = al.ALConfig()
    full, _, _ = al.schedule(jax.random.key(3), cfg)
    small, _, _ = al.schedule(jax.random.key(3), cfg, al.hyper(actor_init_scale=0.1))
    np.testing.assert_allclose(small.actor.w2, 0.1 * full.actor.w2, rtol=1e-6)
    np.testing.assert_array_equal(small.actor.w1, full.actor.w1)


def test_schedules_are_configs():
    assert al.ALConfig.from_schedule("paper").episodes == 450
    nt = al.ALConfig.from_schedule("no_tricks")
    assert (nt.phase1_episodes, nt.episodes) == (0, 2000)


def test_training_in_chunks_of_256_agents_equals_each_alone(small_train):
    keys = jax.random.split(jax.random.key(5), 256)
    hp = al.ALHyper()
    seen = []
    agents, m = al.train_in_chunks(SMALL, keys, hp, [1, 3, 4],
                                   progress_fn=lambda n, ms: seen.append((n, ms)))
    assert [s["train/episodes"] for _, s in seen] == [1, 3, 4]
    assert seen[-1][0] == int(np.asarray(m["steps"]).sum()) > seen[0][0] > 0
    assert seen[-1][1]["train/return"] == pytest.approx(float(np.asarray(m["return"]).mean()))
    for i in (0, 1, 255):
        agent, mi = small_train(keys[i], hp)
        for k in mi:
            np.testing.assert_array_equal(np.asarray(m[k][i]), np.asarray(mi[k]), err_msg=k)
        for a, b in zip(jax.tree.leaves(agent), jax.tree.leaves(agents), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b[i]))
    with pytest.raises(ValueError, match="stops"):
        al.train_in_chunks(SMALL, keys, hp, [2, 3])
    with pytest.raises(ValueError, match="loop: unknown value 'fast'.*auto_reset"):
        al.train_in_chunks(SMALL, keys, hp, [4], loop="fast")


def test_auto_reset_equals_lockstep_bit_for_bit():
    # three agents whose episodes end at different steps (wrong moves end some early), so
    # the auto-reset loop really restarts slots mid-batch
    keys = jax.random.split(jax.random.key(2), 3)
    # a start curriculum too: each loop starts each episode with its own start noise
    hp = al.hyper(wrong_move_threshold=0.002, start_noise=0.3, start_ramp=0.5)
    runs = {loop: jax.jit(jax.vmap(al.make_train(SMALL, loop), in_axes=(0, None)))(keys, hp)
            for loop in al.LOOPS}
    (a1, m1), (a2, m2) = runs["auto_reset"], runs["lockstep"]
    steps = np.asarray(m1["steps"])
    assert steps.min() < 75 and len(set(steps.sum(axis=1))) > 1
    for k in m1:
        np.testing.assert_array_equal(np.asarray(m1[k]), np.asarray(m2[k]), err_msg=k)
    for a, b in zip(jax.tree.leaves(a1), jax.tree.leaves(a2), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_start_curriculum_grows_the_start_range_from_home(small_train):
    hp = al.hyper(start_noise=0.4, start_ramp=0.5)
    grown = [float(al.env_at(hp, jnp.float32(p)).start_noise) for p in (0.0, 0.25, 0.5, 0.9)]
    assert grown == pytest.approx([0.0, 0.2, 0.4, 0.4])
    assert float(al.env_at(hp.replace(start_ramp=0.0), jnp.float32(0.0)).start_noise) == \
        pytest.approx(0.4)
    key = jax.random.key(4)
    _, home = small_train(key, al.hyper(start_noise=0.0))
    _, ramp = small_train(key, hp)
    _, wide = small_train(key, hp.replace(start_ramp=0.0))
    first = {k: v[0] for k, v in home.items()}
    # the first episode (progress 0) starts at home; later ones, and every one without the
    # ramp, start elsewhere
    for k in first:
        np.testing.assert_array_equal(np.asarray(ramp[k][0]), np.asarray(first[k]), err_msg=k)
    assert not np.array_equal(np.asarray(wide["return"][0]), np.asarray(first["return"]))
    assert not np.array_equal(np.asarray(ramp["return"]), np.asarray(home["return"]))
    with pytest.raises(ValueError, match="start_ramp"):
        al.validate(al.hyper(start_ramp=1.5))


def test_start_noise_by_action_scales_each_actions_starts():
    hp = al.hyper(start_noise=0.4, start_ramp=0.5, start_by_action=[0.0, 0.5, 1.0])
    got = [[float(al.env_at(hp, jnp.float32(p), jnp.int32(a)).start_noise) for a in range(3)]
           for p in (0.25, 0.9)]
    assert got == [pytest.approx([0.0, 0.1, 0.2]), pytest.approx([0.0, 0.2, 0.4])]
    # traced, as a sweep batches it
    jitted = jax.jit(lambda h, a: al.env_at(h, jnp.float32(1.0), a).start_noise)
    assert float(jitted(hp, jnp.int32(1))) == pytest.approx(0.2)
    for bad in ([-1.0, 0.0, 1.0], 0.5):
        with pytest.raises(ValueError, match=r"start_by_action: .*accepted: None or numbers"):
            al.validate(al.hyper(start_by_action=bad))
    with pytest.raises(ValueError, match="action: None, but start_by_action is set"):
        al.env_at(hp, jnp.float32(0.5))
    with pytest.raises(ValueError, match=r"start_by_action: .*shape \[\.\.\., 3\]"):
        al.make_train(SMALL)(jax.random.key(0), al.hyper(start_by_action=[1.0, 1.0]))


def test_decay_reaches_the_final_value_at_the_last_episode():
    cfg = al.ALConfig(phase1_episodes=1, phase2_episodes=4)
    _, _, plan = al.schedule(jax.random.key(0), cfg)
    np.testing.assert_allclose(np.asarray(plan["progress"]), [0, 0.25, 0.5, 0.75, 1.0])
    np.testing.assert_array_equal(np.asarray(plan["phase1"]), [1, 0, 0, 0, 0])


def test_actor_lr_decay_freezes_the_actor_in_the_last_episode():
    # phase-1 rule on point tasks: the actor is updated in most steps of every episode
    cfg = al.ALConfig(phase1_episodes=4, phase2_episodes=0, actions=(0,), random_layout=False)
    keys = jax.random.split(jax.random.key(2), 1)
    hp = al.hyper(actor_lr=0.05, actor_lr_decay=1e-9)
    seen = {}
    agents, _ = al.train_in_chunks(cfg, keys, hp, [3, 4],
                                   lambda e, a, _: seen.setdefault(e, jax.device_get(a)))
    before = seen[3]
    np.testing.assert_allclose(np.asarray(agents.actor.w1), before.actor.w1, atol=1e-7)
    assert not np.allclose(np.asarray(agents.critic.w1), before.critic.w1)
    # while in earlier episodes the actor did move
    _, m0 = al.train_in_chunks(cfg, keys, al.hyper(actor_lr=0.05), [3, 4],
                               lambda e, a, _: seen.setdefault(("plain", e), jax.device_get(a)))
    assert not np.allclose(seen[("plain", 4)].actor.w1, seen[("plain", 3)].actor.w1)


# ------------------------------------------------------------------- the learner seam
@dataclasses.dataclass(frozen=True)
class _LinearConfig:
    task_set: str = "paper"


@struct.dataclass
class _LinearHyper:
    lr: Any = 0.1
    sigma: Any = 0.2


@struct.dataclass
class _LinearState:
    w: jax.Array
    updates: jax.Array


def _linear_init(key, config, hp):
    return _LinearState(w=jnp.zeros((11, 4)), updates=jnp.zeros((), jnp.int32))


def _linear_act(state, obs, key, hp):
    mean = jnp.tanh(obs @ state.w)
    return mean + hp.sigma * jax.random.normal(key, mean.shape), mean


def _linear_update(state, tr, hp, config):
    # pulled toward the explored action when the reward rose (CACLA's phase 1, no critic)
    err = tr.action - jnp.tanh(tr.obs @ state.w)
    rose = tr.reward > tr.prev_reward
    w = jnp.where(rose, state.w + hp.lr * jnp.outer(tr.obs, err), state.w)
    delta = tr.reward - tr.prev_reward
    return _LinearState(w=w, updates=state.updates + rose), {"delta": delta}


LINEAR = learners.Learner(
    name="test_linear", config_type=_LinearConfig, hyper_type=_LinearHyper,
    state_type=_LinearState, hyper_rules={"lr": POSITIVE, "sigma": POSITIVE},
    init=_linear_init, act=_linear_act, update=_linear_update,
    policy=lambda s, obs: (jnp.tanh(obs @ s.w), obs @ s.w),
    at_episode=lambda hp, phase1, progress: hp)


def test_another_learner_trains_and_evaluates_through_the_seam():
    learners.register(LINEAR)
    env_cfg = env_mod.EnvConfig(episode_length=6)
    cfg = al.ALConfig(env=env_cfg, learner=_LinearConfig(), phase1_episodes=0,
                      phase2_episodes=3)
    assert cfg.learning is LINEAR
    hp = al.validate(al.hyper(learner=LINEAR, lr=0.2))
    assert isinstance(hp.learner, _LinearHyper) and float(hp.learner.lr) == pytest.approx(0.2)
    with pytest.raises(ValueError, match="sigma"):
        al.validate(al.hyper(learner=LINEAR, sigma=-1.0))  # its own rule table
    with pytest.raises(ValueError, match="learner: hyperparameters CaclaHyper"):
        al.make_train(cfg)(jax.random.key(0), al.ALHyper())  # another learner's
    state, m = jax.jit(al.make_train(cfg))(jax.random.key(0), hp)
    assert isinstance(state, _LinearState)
    assert int(state.updates) > 0 and float(jnp.abs(state.w).sum()) > 0  # update was called
    assert np.all(np.asarray(m["td_error"]) > 0)  # from the learner's info["delta"]
    # evaluation finds the learner by the state's type
    first, traj, hidden = al.make_eval(env_cfg)(state, jax.random.key(1),
                                                env_mod.make_task("point", "left"))
    assert hidden.shape == (6, 4) and traj.obs.shape == (6, 11)
    np.testing.assert_allclose(np.asarray(hidden[0]), np.asarray(first.obs @ state.w),
                               rtol=1e-5, atol=1e-6)


def test_a_config_float_rule_refuses_strings_bools_and_non_finite_values():
    from grounding_jax.core.checks import check_config, integer_at_least

    @dataclasses.dataclass(frozen=True)
    class Cfg:
        rate: Any = 0.5
        count: Any = 3

    rules = {"rate": POSITIVE, "count": integer_at_least(1)}
    check_config(Cfg(), rules)
    check_config(Cfg(rate=2, count=np.int64(4)), rules)  # an int is a real; NumPy ints count
    check_config(Cfg(rate=np.float32(0.1)), rules)
    for bad in ("0.5", True, None, float("nan"), float("inf"), -1.0, 0.0):
        with pytest.raises(ValueError, match=r"rate: must be > 0, got"):
            check_config(Cfg(rate=bad), rules)
    for bad in (2.0, True, "3", 0):
        with pytest.raises(ValueError, match=r"count: must be an integer >= 1, got"):
            check_config(Cfg(count=bad), rules)
