"""ESN and toroidal SOM: analytic checks."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from grounding_jax.learn import esn, som


@pytest.fixture(scope="module")
def net():
    return esn.init(jax.random.key(0))


def test_reservoir_spectral_radius_and_connectivity(net):
    w = np.asarray(net.w_res, np.float64)
    assert abs(np.max(np.abs(np.linalg.eigvals(w))) - 0.9) < 1e-4
    assert abs(np.mean(w != 0) - 0.2) <= 0.02
    w_in = np.asarray(net.w_in)
    assert w_in.shape == (90, 50) and w_in.min() >= -1 and w_in.max() <= 1


def test_run_under_scan_equals_a_python_loop(net):
    u = jax.random.normal(jax.random.key(1), (12, 90))
    x0 = jax.random.uniform(jax.random.key(2), (50,), minval=-1, maxval=1)
    got = np.asarray(esn.run(net, u, x0))
    x = np.asarray(x0, np.float64)
    for t in range(12):
        x = np.asarray(u[t], np.float64) @ np.asarray(net.w_in) + x @ np.asarray(net.w_res)
        np.testing.assert_allclose(got[t], x, rtol=1e-4, atol=1e-4)


def test_run_compiles_once_for_every_net_and_sequence_of_a_shape(net):
    # eagerly, a scan compiled anew per call: a robot naming thousands of episodes ran out
    # of memory
    u = jax.random.normal(jax.random.key(3), (7, net.w_in.shape[0]))
    esn.run(net, u)
    size = esn._run._cache_size()
    other = net.replace(w_res=net.w_res * 0.5)
    np.testing.assert_allclose(esn.run(other, 2 * u)[0], 2 * u[0] @ net.w_in, rtol=1e-5)
    assert esn._run._cache_size() == size


@pytest.mark.parametrize("ridge", [0.0, 1e-9])
def test_readout_recovers_a_known_linear_map(ridge):
    x = jax.random.normal(jax.random.key(3), (400, 50))
    w = jax.random.normal(jax.random.key(4), (50, 9))
    got = esn.fit_readout(x, x @ w, ridge=ridge)
    np.testing.assert_allclose(np.asarray(got), np.asarray(w), atol=1e-3)


def test_readout_recovers_a_map_from_ill_conditioned_states():
    # many rows, columns spanning 4 decades: a pinv cut-off that grows with the row count
    # (numpy/jax default) drops the small directions; the fit must keep them
    scale = jnp.logspace(0, -4, 50)
    x = jax.random.normal(jax.random.key(5), (20000, 50)) * scale
    w = jax.random.normal(jax.random.key(6), (50, 9))
    got = np.asarray(esn.fit_readout(x, x @ w))
    np.testing.assert_allclose(got, np.asarray(w), rtol=0.05, atol=0.05)


def test_decode_and_targets_round_trip():
    d = esn.targets(jnp.array([2, 0]), jnp.array([5, 1]))
    a, word = esn.decode(d)
    assert a.tolist() == [2, 0] and word.tolist() == [5, 1]


@pytest.mark.parametrize("make, field", [
    (lambda: esn.ESNConfig(spectral_radius=0.0), "spectral_radius"),
    (lambda: esn.ESNConfig(connectivity=0.0), "connectivity"),
    (lambda: esn.ESNConfig(connectivity=1.5), "connectivity"),
    (lambda: esn.ESNConfig(n_res=0), "n_res"),
    (lambda: esn.run(esn.init(jax.random.key(0)), jnp.zeros((5, 80))), "inputs"),
    (lambda: esn.fit_readout(jnp.zeros((5, 50)), jnp.zeros((4, 9))), "states"),
    (lambda: som.SOMConfig(rows=0), "rows"),
])
def test_bad_input_names_the_field(make, field):
    with pytest.raises(ValueError, match=field):
        make()


def test_torus_distance_wraps():
    d = lambda a, b: float(som.torus_distance(jnp.array(a, float), jnp.array(b, float), 8, 10))  # noqa: E731
    assert d((0, 0), (0, 9)) == 1.0  # (0, 0) is next to (0, W-1)
    assert d((0, 0), (7, 0)) == 1.0
    assert d((0, 0), (4, 5)) == pytest.approx(np.hypot(4, 5))  # the farthest cell
    assert d((2, 3), (2, 3)) == 0.0


def test_som_separates_three_gaussian_blobs():
    k = jax.random.split(jax.random.key(5), 3)
    centres = jnp.array([[4.0, 0, 0, 0], [0, 4.0, 0, 0], [0, 0, 4.0, 0]])
    data = jnp.concatenate([c + 0.5 * jax.random.normal(kk, (100, 4)) for c, kk in
                            zip(centres, k, strict=True)])
    labels = np.repeat(np.arange(3), 100)
    w = som.train(jax.random.key(6), data, som.SOMConfig(rows=6, cols=6, epochs=20))
    units = np.asarray(som.bmu(w, data))
    assert som.purity(units, labels) > 0.95
    assert len(np.unique(units)) > 3  # the map spreads the data over several cells
    # a map where every sample lands on one unit is as impure as the label mix
    assert som.purity(np.zeros(300, int), labels) == pytest.approx(1 / 3)
