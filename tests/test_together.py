"""The modules learning together: what the AL is told of the TL, the TL in rounds, the
stage's config and order (the stage itself runs in test_train's quick run)."""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from grounding_jax.learn import al, cacla, tl
from grounding_jax.learn import together as tg
from grounding_jax.paper.stage import stages
from grounding_jax.paper.stages import together as T
from grounding_jax.sim import scene, tl_data
from grounding_jax.sim.env import Env, EnvConfig, make_task


def test_told_index_names_the_object_at_each_layout_and_position():
    data = tl_data.load()
    index = tg.told_index(data)
    assert index.shape == (len(scene.LAYOUTS), 3, 2)
    assert len(np.unique(index)) == tl_data.N_CONFIGS  # every configuration once
    lay, pos, kind = np.meshgrid(np.arange(36), np.arange(3), np.arange(2), indexing="ij")
    np.testing.assert_array_equal(data.layout[index], lay)
    np.testing.assert_array_equal(data.labels[index], pos)
    np.testing.assert_array_equal(data.word[index] >= 3, kind == 1)  # shape words first


def test_told_table_is_the_winner_one_hot_or_the_outputs():
    outputs = jax.random.uniform(jax.random.key(0), (2, tl_data.N_CONFIGS, 3))
    index = tg.told_index()
    raw = tg.told_table(outputs, "output")
    np.testing.assert_array_equal(raw[1, 4, 2, 1], outputs[1, index[4, 2, 1]])
    win = np.asarray(tg.told_table(outputs, "winner"))
    assert win.shape == (2, 36, 3, 2, 3) and set(np.unique(win)) == {0.0, 1.0}
    np.testing.assert_array_equal(win.argmax(-1), np.asarray(raw).argmax(-1))
    with pytest.raises(ValueError, match="told.*winner"):
        tg.told_table(outputs, "soft")


def test_a_task_tells_the_actor_other_units_and_keeps_its_reward():
    env = Env(EnvConfig())
    task = make_task("touch", "left", layout=2)
    told = task.replace(target_units=jnp.asarray([0.0, 0.2, 0.9]))
    a, b = env.reset(jax.random.key(0), task), env.reset(jax.random.key(0), told)
    target = env.tasks.obs_target
    np.testing.assert_array_equal(a.obs[target], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(b.obs[target], [0.0, 0.2, 0.9])
    np.testing.assert_array_equal(np.delete(a.obs, np.arange(a.obs.size)[target]),
                                  np.delete(b.obs, np.arange(b.obs.size)[target]))
    act = jnp.full(4, 0.3)
    assert float(env.step(a, act).reward) == float(env.step(b, act).reward)
    with pytest.raises(ValueError, match="target_units"):
        env.reset(jax.random.key(0), task.replace(target_units=jnp.asarray([0.0, jnp.nan, 1])))
    free = Env(EnvConfig(task_set="free"))
    with pytest.raises(ValueError, match="target_units.*'position'"):
        free.reset(jax.random.key(0), make_task("touch", "left", task_set="free",
                                                placement="random", key=jax.random.key(1))
                   .replace(target_units=jnp.ones(3)))


@pytest.fixture(scope="module")
def short_train():
    config = al.ALConfig(phase1_episodes=2, phase2_episodes=2)
    return config, jax.jit(al.make_train(config))


def test_an_al_told_the_true_positions_learns_as_one_told_nothing(short_train):
    config, train = short_train
    hp = al.hyper()
    truth = jnp.broadcast_to(jax.nn.one_hot(jnp.arange(3), 3)[None, :, None], (36, 3, 2, 3))
    a, ma = train(jax.random.key(3), hp)
    b, mb = train(jax.random.key(3), hp.replace(told=truth))
    assert jax.tree.all(jax.tree.map(lambda x, y: bool(jnp.array_equal(x, y)), a, b))
    np.testing.assert_array_equal(ma["return"], mb["return"])
    # told always "left": other observations, other updates
    c, _ = train(jax.random.key(3), hp.replace(told=jnp.zeros((36, 3, 2, 3)).at[..., 0].set(1)))
    assert not jnp.array_equal(a.actor.w1, c.actor.w1)
    assert isinstance(a, cacla.Agent)


def test_the_tl_trained_in_rounds_is_the_tl_trained_at_once():
    config = tl.TLConfig(epochs=6, eval_every=6)
    key = jax.random.key(7)
    params, metrics = jax.jit(tl.make_train(config))(key, tg.TL_HYPER)
    start, advance, to_params = tl.make_rounds(config)
    step = jax.jit(advance, static_argnums=4)
    state = start(key, tg.TL_HYPER)
    for first in (0, 2, 4):
        state, (_, test) = step(key, tg.TL_HYPER, state, first, 2)
    got = to_params(key, tg.TL_HYPER, state)
    for x, y in zip(jax.tree.leaves(params), jax.tree.leaves(got), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-6)
    assert float(test) == pytest.approx(float(metrics["final_test_acc"]))


@pytest.mark.parametrize("told", [np.zeros((36, 3, 3)), np.zeros((36, 2, 2, 3)),
                                  np.full((36, 3, 2, 3), np.nan)])
def test_a_told_table_of_another_shape_or_not_finite_is_named(told):
    with pytest.raises(ValueError, match=r"told: .*\[\.\.\., 36, 3, 2, 3\]"):
        al.validate(al.ALHyper(told=told))
    assert al.validate(al.ALHyper(told=np.zeros((2, 36, 3, 2, 3)))).told.shape[0] == 2


@pytest.mark.parametrize("changes, needle", [
    ({"rounds": 3}, "tl_epochs: 40 does not split"),
    ({"phase2_episodes": 31}, "phase1_episodes"),
    ({"an_configs": 146}, "an_configs <= 144"),
    ({"told": "soft"}, "told"),
    ({"layouts": "some"}, "layouts"),
    ({"agents": 0}, "agents"),
])
def test_a_bad_together_config_is_named(changes, needle):
    with pytest.raises(ValueError, match=needle):
        stages()["together"].make_config("quick", changes)


def test_both_orders_spend_the_same_budget():
    for rounds in (1, 2, 6):
        seq, tog = T.order("sequence", rounds), T.order("together", rounds)
        assert sorted(seq) == sorted(tog) and len(seq) == 3 * rounds
        assert seq[:rounds] == ["tl"] * rounds and tog[:3] == ["tl", "al", "an"]


def test_the_seeds_benchmark_pools_agents_and_counts_who_did_better(monkeypatch):
    monkeypatch.syspath_prepend(str(pathlib.Path(__file__).parent.parent / "benchmarks"))
    import together_seeds

    def arm(touch):
        return {"tl_test_acc": [0.9, 0.9], "named": [1.0, 1.0],
                "success": {"point": [1.0, 1.0], "touch": touch, "push": [0.5, 0.5]}}

    runs = [{"arms": {"sequence": arm([0.2, 0.5]), "together": arm([0.4, 0.5])}},
            {"arms": {"sequence": arm([0.6, 0.1]), "together": arm([0.3, 0.1])}}]
    got = together_seeds.pooled(runs)
    assert got["touch"]["agents"] == 4
    assert (got["touch"]["together_better"], got["touch"]["together_worse"]) == (1, 1)
    assert got["touch"]["sequence"]["median"] == pytest.approx(0.35)
    assert got["push"]["together_better"] == got["push"]["together_worse"] == 0
    text = together_seeds.table({"keys": [1, 2], "changes": {"tl": "slow"}, "pooled": got})
    assert "tl=slow" in text and "| touch | 35% (10-60%) | 35% (10-50%) | 1 / 1 |" in text
