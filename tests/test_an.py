"""The action namer end to end on a small trained AL/TL fixture: the data, and the accuracy it
reaches (stated and asserted; the paper's > 99% is a results/ figure, not a unit-test one)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from grounding_jax.learn import al, an, esn
from grounding_jax.paper import al_experiments
from grounding_jax.sim import tl_data


@pytest.fixture(scope="module")
def fixture_data():
    cfg = al.ALConfig(phase1_episodes=100, phase2_episodes=50)
    hp = al.hyper(**al_experiments.TUNED)
    agent, _ = jax.jit(al.make_train(cfg))(jax.random.key(0), hp)
    tl_h, tl_acc = an.tl_hidden(jax.random.key(1), epochs=100)
    home = an.dataset(agent, tl_h, jax.random.key(2), steps=60)
    rand = an.dataset(agent, tl_h, jax.random.key(3), steps=60, start_noise=0.5)
    return home, rand, tl_h, tl_acc


def test_dataset_pairs_actor_and_tl_activity_with_the_sentence(fixture_data):
    home, rand, tl_h, _ = fixture_data
    data = tl_data.load()
    assert home["inputs"].shape == (648, 60, 90) and tl_h.shape == (216, 50)
    np.testing.assert_array_equal(home["inputs"][:, 7, 40:], tl_h[home["config"]])
    np.testing.assert_array_equal(home["position"], data.labels[home["config"]])
    assert (np.bincount(home["action"]) == 216).all()
    # random starts change the actor's activity, not the sentence
    assert not np.allclose(home["actor_hidden"][:, 0], rand["actor_hidden"][:, 0])
    np.testing.assert_array_equal(home["word"], rand["word"])


def test_namer_names_train_and_test_sequences(fixture_data):
    home, rand, _, _ = fixture_data
    res = an.train_namer(jax.random.key(4), home, rand)
    assert res["train_mask"].sum() == 3 * 144  # 2/3 of the 216 configurations, 3 actions each
    # measured on this fixture: train 100%, test 97.2%, random starts 95.4% (not the
    # paper's > 99% on test: this TL generalizes to 79% of its test configurations); naming
    # settles at step 0 (home) / 1 (random start and state), median
    assert res["train"]["acc"] >= 0.99
    assert res["test"]["acc"] >= 0.94
    assert res["test_random"]["acc"] >= 0.92
    assert res["test_random"]["settle_median"] <= 5
    # an untrained readout names nothing reliably
    zero = res["net"].replace(w_out=res["net"].w_out * 0)
    out = esn.apply(zero, esn.run(zero, home["inputs"][0]))
    assert float(np.abs(out).max()) == 0.0
