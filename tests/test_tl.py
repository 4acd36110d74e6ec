"""TL data and MLP: labels, input sizes, learning, vmap equivalence, padding, bad input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from grounding_jax.learn import tl
from grounding_jax.paper import tl_experiments
from grounding_jax.sim import scene, tl_data


@pytest.fixture(scope="module")
def data():
    return tl_data.load()


def test_labels_of_all_216_configurations(data):
    assert len(data.labels) == 216
    slots = scene.layout_shape_slots()
    for i in range(216):
        layout, word = divmod(i, 6)
        name = tl_data.TARGET_WORDS[word]
        if name in scene.SHAPES:  # shape word: where that shape stands
            expected = slots[layout][scene.SHAPES.index(name)]
        else:  # colour word: where that colour stands
            expected = scene.LAYOUTS[layout][1].index(name)
        assert data.labels[i] == expected
    assert np.bincount(data.labels).tolist() == [72, 72, 72]
    # each configuration is (layout, word) once
    assert len({(int(a), int(b)) for a, b in zip(data.layout, data.word, strict=True)}) == 216


def test_symbol_units_encode_colours_and_target(data):
    # layout 1: box/red cylinder/blue sphere/green (colour order red, blue, green)
    u = tl_data.symbol_units(1, "green")
    np.testing.assert_array_equal(u[:9], [1, 0, 0, 0, 0, 1, 0, 1, 0])
    np.testing.assert_array_equal(u[9:], [0, 0, 0, 0, 1, 0])
    assert tl_data.label_of(1, tl_data.word_index("green")) == 2


def test_replication_gives_exactly_1500_inputs_at_n20(data):
    assert tl_data.inputs(data, 20).shape == (216, 1500)
    assert tl_data.inputs(data, 1).shape == (216, 1215)
    x = tl_data.inputs(data, 3)
    np.testing.assert_array_equal(x[:, 1200:1215], x[:, 1230:1245])


@pytest.mark.parametrize("call, field", [
    (lambda d: tl_data.inputs(d, 0), "n"),
    (lambda d: tl_data.load(np.zeros((36, 1100))), "bitmaps"),
    (lambda d: tl_data.symbol_units(0, "purple"), "target word"),
    (lambda d: tl.validate(tl.TLHyper(hidden=0), tl.TLConfig()), "hidden"),
    (lambda d: tl.validate(tl.TLHyper(replication=0), tl.TLConfig()), "replication"),
    (lambda d: tl.validate(tl.TLHyper(lr=-0.1), tl.TLConfig()), "lr"),
    (lambda d: tl.validate(tl.TLHyper(image_scale=0.0), tl.TLConfig()), "image_scale"),
    (lambda d: tl.validate(tl.TLHyper(target_scale=float("nan")), tl.TLConfig()),
     "target_scale"),
    (lambda d: tl.validate(tl.TLHyper(hidden=80), tl.TLConfig(max_hidden=50)), "max_hidden"),
    (lambda d: tl.TLConfig(epochs=0), "epochs"),
    (lambda d: tl.TLConfig(noise_mode="gaussian"), "noise_mode"),
])
def test_bad_input_names_the_field(data, call, field):
    with pytest.raises(ValueError, match=field):
        call(data)


CFG = tl.TLConfig(epochs=150, max_hidden=20, max_replication=20, eval_every=50)


@pytest.fixture(scope="module")
def train_fn(data):
    return jax.jit(tl.make_train(CFG, data))


@pytest.fixture(scope="module")
def three_seeds(data):
    keys = jax.random.split(jax.random.key(7), 3)
    hp = tl.TLHyper(hidden=20, replication=20)
    return keys, hp, jax.jit(jax.vmap(tl.make_train(CFG, data), in_axes=(0, None)))(keys, hp)


def test_tl_really_learns_a_small_subset(data):
    subset = tl_data.TLData(*(a[:54] for a in data))  # 9 layouts x 6 words: 36 train, 18 test
    cfg = tl.TLConfig(epochs=300, max_hidden=20, max_replication=20, eval_every=50)
    keys = jax.random.split(jax.random.key(1), 3)
    _, m = jax.jit(jax.vmap(tl.make_train(cfg, subset), in_axes=(0, None)))(
        keys, tl.TLHyper(hidden=20))
    np.testing.assert_array_equal(np.asarray(m["final_train_acc"]), 1.0)
    rmse = np.asarray(m["train_rmse"])
    assert np.all(rmse[:, -1] < 0.5 * rmse[:, 0])


def test_tl_generalizes_on_the_full_set_after_few_epochs(three_seeds):
    _, _, (_, m) = three_seeds
    np.testing.assert_array_equal(np.asarray(m["final_train_acc"]), 1.0)
    assert np.all(np.asarray(m["final_test_acc"]) > 0.55)  # well above chance (1/3)


def test_vmapped_seeds_equal_separate_runs(three_seeds, train_fn):
    keys, hp, (params, m) = three_seeds
    for i in range(3):
        p1, m1 = train_fn(keys[i], hp)
        np.testing.assert_allclose(np.asarray(p1.w1), np.asarray(params.w1[i]), atol=1e-5)
        assert float(m1["final_test_acc"]) == pytest.approx(float(m["final_test_acc"][i]))


def test_padding_and_masking_equal_the_unpadded_network(data):
    hp = tl.TLHyper(hidden=8, replication=3)
    small = tl.TLConfig(epochs=20, max_hidden=8, max_replication=3, eval_every=10)
    big = tl.TLConfig(epochs=20, max_hidden=30, max_replication=12, eval_every=10)
    key = jax.random.key(3)
    ps, ms = jax.jit(tl.make_train(small, data))(key, hp)
    pb, mb = jax.jit(tl.make_train(big, data))(key, hp)
    np.testing.assert_allclose(np.asarray(pb.w1[:1245, :8]), np.asarray(ps.w1), atol=1e-5)
    np.testing.assert_allclose(np.asarray(pb.w2[:8]), np.asarray(ps.w2), atol=1e-5)
    k_init = jax.random.split(key, 4)[2]  # make_train's split: split, noise, init, epochs
    untrained = tl.init(k_init, hp, big)
    np.testing.assert_array_equal(np.asarray(pb.w2[8:]), np.asarray(untrained.w2[8:]))
    assert float(mb["final_test_acc"]) == pytest.approx(float(ms["final_test_acc"]))


def test_localize_uses_the_trained_network(three_seeds, data):
    _, hp, (params, _) = three_seeds
    p0 = jax.tree.map(lambda a: a[0], params)
    preds = [int(tl.localize(p0, jnp.asarray(data.bitmaps[i]), jnp.asarray(data.symbols[i]),
                             tl.TLHyper(replication=20, hidden=20))) for i in range(0, 216, 9)]
    truth = data.labels[::9]
    assert np.mean(np.array(preds) == truth) > 0.8


def test_run_grid_shapes_and_replication_matters(tmp_path):
    m = tl_experiments.run_grid(jax.random.key(0),
                                {"hidden": 20, "epochs": 40, "eval_every": 20},
                                {"replication": [1, 20]}, 2)
    assert m["final_test_acc"].shape == (2, 2)
    assert m["train_acc"].shape == (2, 2, 2)


def _reference_train(key, hp, cfg, data):
    """Plain online backprop (jax.grad) on the explicit replicated input, step by step."""
    n_all = len(data.labels)
    n_train = int(round(2 / 3 * n_all))
    k_split, _, k_init, k_epochs = jax.random.split(key, 4)
    tr = jax.random.permutation(k_split, n_all)[:n_train]
    np.testing.assert_array_equal(np.asarray(tl.split_indices(key, n_all)[0]), np.asarray(tr))
    params = tl.init(k_init, hp, cfg)
    x = tl.build_inputs(jnp.asarray(data.bitmaps), jnp.asarray(data.symbols), hp, cfg)
    _, hid_mask = tl.masks(hp, cfg)
    t = jax.nn.one_hot(jnp.asarray(data.labels), 3)

    @jax.jit
    def step(p, i):
        g = jax.grad(lambda q: 0.5 * jnp.sum((tl.apply(q, x[i], hid_mask)[1] - t[i]) ** 2))(p)
        return jax.tree.map(lambda w, d: w - hp.lr * d, p, g)

    for k in jax.random.split(k_epochs, cfg.epochs):
        k_order, _ = jax.random.split(k)
        for i in tr[jax.random.permutation(k_order, n_train)]:
            params = step(params, i)
    return params


@pytest.mark.parametrize("budget, image_scale, target_scale", [
    (0, 1.0, 1.0), (200, 1.0, 1.0), (0, 0.6, 3.0), (200, 0.6, 3.0)])
def test_compact_training_equals_plain_backprop_on_the_replicated_input(
        data, budget, image_scale, target_scale):
    # the reference trains on build_inputs' explicit input: on pixels = image_scale, the
    # target units = target_scale
    subset = tl_data.TLData(*(a[:30] for a in data))
    hp = tl.TLHyper(hidden=6, replication=4, lr=0.5, image_scale=image_scale,
                    target_scale=target_scale)
    cfg = tl.TLConfig(epochs=3, max_hidden=8, max_replication=5, eval_every=3,
                      pixel_budget=budget)
    key = jax.random.key(11)
    fast, _ = jax.jit(tl.make_train(cfg, subset))(key, hp)
    ref = _reference_train(key, hp, cfg, subset)
    for a, b in zip(jax.tree.leaves(fast), jax.tree.leaves(ref), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=2e-5)
    assert not np.allclose(np.asarray(fast.w2), np.asarray(tl.init(
        jax.random.split(key, 4)[2], hp, cfg).w2))  # it did train


def test_pixel_budget_checks():
    with pytest.raises(ValueError, match="pixel_budget"):
        tl.make_train(tl.TLConfig(pixel_budget=10))
    with pytest.raises(ValueError, match="noise"):
        tl.validate(tl.TLHyper(noise=0.1), tl.TLConfig(pixel_budget=300))


def test_build_inputs_scales_pixels_and_target_units_only(data):
    hp = tl.TLHyper(replication=2, image_scale=0.5, target_scale=4.0)
    cfg = tl.TLConfig(max_replication=3)
    x = np.asarray(tl.build_inputs(jnp.asarray(data.bitmaps[:4]), jnp.asarray(data.symbols[:4]),
                                   hp, cfg))
    np.testing.assert_array_equal(x[:, :1200], 0.5 * data.bitmaps[:4])
    for r in range(2):
        block = x[:, 1200 + 15 * r: 1215 + 15 * r]
        np.testing.assert_array_equal(block[:, :9], data.symbols[:4, :9])  # colour units
        np.testing.assert_array_equal(block[:, 9:], 4.0 * data.symbols[:4, 9:])
    assert not x[:, 1230:].any()  # the third replica is masked


def test_lookup_bound_is_exact_when_every_pair_was_seen_and_zero_when_none(data):
    everything = np.arange(216)
    assert tl_experiments.lookup_bound(data, everything, everything)["acc"] == 1.0
    # the training set holds only shape words: colour words have nothing to look up
    shape_only = everything[data.word < 3]
    r = tl_experiments.lookup_bound(data, shape_only, everything)
    assert r["acc_colour_words"] == 0.0 and r["acc_shape_words"] == 1.0


def test_reference_classifier_learns_a_separable_problem():
    x = jax.random.normal(jax.random.key(0), (90, 5))
    y = jnp.argmax(x[:, :3], axis=1)  # the largest of the first three features
    for hidden in (0, 16):
        pred = tl_experiments._adam_classifier(x[:60], y[:60], x[60:], jax.random.key(1),
                                               hidden, steps=500, lr=0.05)
        assert float(jnp.mean(pred == y[60:])) > 0.85
