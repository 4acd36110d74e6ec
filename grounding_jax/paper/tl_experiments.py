"""TL experiments of the paper: accuracy at H=50/n=20, Fig 6 (hidden size), Fig 7 (replication
n), and the pixel-noise test. Each writes ``<name>.json`` and ``<name>.png`` under ``out``.

Grid points x seeds run through the sweep runner's groups: ``vmap``ped, ``jit``ted calls, one
compile per hidden size (see `run_grid`).
"""

from __future__ import annotations

import pathlib
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core.io import pyplot, write_figure
from grounding_jax.learn import tl
from grounding_jax.sim import scene, tl_data

PAPER = {
    "accuracy": {"test_acc": 0.95, "train_acc": 1.0},
    "noise": {"train_acc": 1.0, "test_acc": 0.75},
    "fig6": "test accuracy saturates at ~95% from ~50 hidden units",
    "fig7": "best ~95% at n=20; without replication <= 75%",
}


#: The network the experiments train: the paper's H=50, n=20 with the shipped input balance
#: and learning rate (`tl.TUNED`).
BASE = {"hidden": 50, "replication": 20, **tl.TUNED}


def run_grid(key: jax.Array, params: dict[str, Any], grid: dict[str, list], seeds: int
             ) -> dict[str, np.ndarray]:
    """Train every point of ``grid`` (the other fields from ``params``) with ``seeds`` seeds,
    through the sweep runner's groups (`sweep.run_group`, nothing written): one compile
    per static group (hidden size, epochs, noise mode), the rest ``vmap``ped and traced.

    Args:
        key: one PRNG key; split once into ``points * seeds`` run keys (row
            ``point * seeds + seed``, as a sweep splits its key).
        params: fixed fields of the TL sweep module (``sweep.FIELDS["tl"]``).
        grid: the swept fields, each a list of values; points are every combination.
        seeds: runs per point.

    Returns:
        Metrics with leading axes ``[points, seeds]``.
    """
    from grounding_jax import sweep

    spec = sweep.parse_spec({"name": "tl_experiment", "module": "tl", "seeds": seeds,
                             "params": params, "grid": grid}, "tl_experiments.run_grid")
    run_keys = sweep.split_run_keys(spec, key)
    n = len(spec.points()) * seeds
    out: dict[str, np.ndarray] = {}
    for group in range(len(spec.groups())):
        res = sweep.run_group(spec, group, run_keys, None)
        for k, v in res["metrics"].items():
            out.setdefault(k, np.zeros((n, *v.shape[1:]), v.dtype))[res["rows"]] = v
    return {k: v.reshape(-1, seeds, *v.shape[1:]) for k, v in out.items()}


def _summary(m: dict[str, np.ndarray], i: int) -> dict[str, float]:
    best = m["test_acc"][i].max(axis=-1)  # best test accuracy over the evaluation points
    return {
        "train_acc_mean": float(m["final_train_acc"][i].mean()),
        "train_acc_std": float(m["final_train_acc"][i].std()),
        "test_acc_mean": float(m["final_test_acc"][i].mean()),
        "test_acc_std": float(m["final_test_acc"][i].std()),
        "test_acc_per_seed": [float(v) for v in m["final_test_acc"][i]],
        "best_epoch_test_acc_mean": float(best.mean()),
        "test_acc_shape_words_mean": float(m["final_test_acc_shape_words"][i].mean()),
        "test_acc_colour_words_mean": float(m["final_test_acc_colour_words"][i].mean()),
        "train_rmse_mean": float(m["final_train_rmse"][i].mean()),
        "test_rmse_mean": float(m["final_test_rmse"][i].mean()),
    }


def _eval_every(epochs: int) -> int:
    """The default evaluation interval, or every epoch for runs shorter than it."""
    return min(tl.TLConfig().eval_every, epochs)


def accuracy(key: jax.Array, out: pathlib.Path, seeds: int = 5, epochs: int = 600,
             noise: float = 0.0, name: str = "accuracy", noise_mode: str = "fixed") -> dict:
    """H=50, n=20 over ``seeds`` seeds (``noise`` > 0: the pixel-flip test)."""
    eval_every = _eval_every(epochs)
    t = time.perf_counter()
    m = run_grid(key, {**BASE, "epochs": epochs, "noise_mode": noise_mode,
                       "eval_every": eval_every}, {"noise": [noise]}, seeds)
    res = {**BASE, "noise": noise, "noise_mode": noise_mode,
           "epochs": epochs, "seeds": seeds,
           **_summary(m, 0), "wall_s": time.perf_counter() - t,
           "paper": PAPER["noise" if noise else "accuracy"]}
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ep = np.arange(1, m["test_acc"].shape[-1] + 1) * eval_every
    for key_, lab in (("train_acc", "train"), ("test_acc", "test")):
        mu, sd = m[key_][0].mean(0), m[key_][0].std(0)
        ax.plot(ep, mu, label=lab)
        ax.fill_between(ep, mu - sd, mu + sd, alpha=0.2)
    ax.set(xlabel="epoch", ylabel="accuracy", ylim=(0, 1.02),
           title=f"TL H=50 n=20{f' noise {noise:.0%} ({noise_mode})' if noise else ''}"
                 f" ({seeds} seeds)")
    ax.legend()
    write_figure(out, name, res, fig)
    plt.close(fig)
    return res


def sweep(key: jax.Array, out: pathlib.Path, field: str, values: list[int], seeds: int = 5,
          epochs: int = 600, name: str = "fig6") -> dict:
    """Test accuracy against ``field`` (``"hidden"``: Fig 6; ``"replication"``: Fig 7)."""
    if field not in ("hidden", "replication"):
        raise ValueError(f"field: unknown value {field!r}; accepted values: "
                         "('hidden', 'replication')")
    fixed = {k: v for k, v in BASE.items() if k != field}
    t = time.perf_counter()
    m = run_grid(key, {**fixed, "epochs": epochs, "eval_every": _eval_every(epochs)},
                 {field: [int(v) for v in values]}, seeds)
    points = [{field: int(v), **_summary(m, i)} for i, v in enumerate(values)]
    res = {"field": field, "values": [int(v) for v in values], "fixed": BASE, "seeds": seeds,
           "epochs": epochs, "points": points, "wall_s": time.perf_counter() - t,
           "paper": PAPER[name] if name in PAPER else None}
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.2))
    mu = np.array([p["test_acc_mean"] for p in points])
    sd = np.array([p["test_acc_std"] for p in points])
    ax.errorbar(values, mu, yerr=sd, marker="o", capsize=3, label="test (ours)")
    ax.plot(values, [p["train_acc_mean"] for p in points], "--", label="train (ours)")
    ax.axhline(0.95, color="gray", lw=0.8, ls=":", label="paper ~95%")
    label = "hidden units" if field == "hidden" else "replication n"
    ax.set(xlabel=label, ylabel="accuracy", ylim=(0, 1.02),
           title=f"TL accuracy vs {label} ({seeds} seeds, {epochs} epochs)")
    ax.legend()
    write_figure(out, name, res, fig)
    plt.close(fig)
    return res


def lookup_bound(data: tl_data.TLData, train_idx: np.ndarray, test_idx: np.ndarray) -> dict:
    """Accuracy of a lookup that knows what the task is made of: a test configuration takes
    the majority label of the training configurations with its target word and its colour
    order (colour words) or shape order (shape words); with none, it is counted wrong.

    Returns:
        ``acc``, ``acc_shape_words``, ``acc_colour_words``.
    """
    # scene.LAYOUTS is the product SHAPE_ORDERS x COLOUR_ORDERS, in that order
    shape_order, colour_order = np.divmod(data.layout, len(scene.COLOUR_ORDERS))
    is_shape = data.word < len(scene.SHAPES)
    order = np.where(is_shape, shape_order, colour_order)
    right = []
    for i in test_idx:
        same = train_idx[(data.word[train_idx] == data.word[i]) & (order[train_idx] == order[i])]
        votes = np.bincount(data.labels[same], minlength=3)
        right.append(len(same) > 0 and votes.argmax() == data.labels[i])
    right = np.asarray(right)
    shape_test = is_shape[test_idx]
    return {"acc": float(right.mean()), "acc_shape_words": float(right[shape_test].mean()),
            "acc_colour_words": float(right[~shape_test].mean())}


def _adam_classifier(x_tr, y_tr, x_te, key, hidden: int, steps: int = 2000, lr: float = 1e-3,
                     l2: float = 1e-4):
    """Softmax cross-entropy with L2, full batch, optax Adam: a linear model (``hidden`` 0)
    or one ReLU hidden layer. Returns the test predictions."""
    import optax

    d = x_tr.shape[1]
    k1, k2 = jax.random.split(key)
    if hidden:
        params = {"w1": jax.random.normal(k1, (d, hidden)) * jnp.sqrt(2.0 / d),
                  "b1": jnp.zeros(hidden),
                  "w2": jax.random.normal(k2, (hidden, 3)) * jnp.sqrt(1.0 / hidden),
                  "b2": jnp.zeros(3)}
    else:
        params = {"w2": jnp.zeros((d, 3)), "b2": jnp.zeros(3)}

    def logits(p, x):
        h = jax.nn.relu(x @ p["w1"] + p["b1"]) if hidden else x
        return h @ p["w2"] + p["b2"]

    def loss(p):
        ce = optax.softmax_cross_entropy_with_integer_labels(logits(p, x_tr), y_tr).mean()
        return ce + l2 * sum(jnp.sum(w ** 2) for k, w in p.items() if k.startswith("w"))

    opt = optax.adam(lr)

    def step(carry, _):
        p, s = carry
        g = jax.grad(loss)(p)
        u, s = opt.update(g, s, p)
        return (optax.apply_updates(p, u), s), None

    (params, _), _ = jax.lax.scan(step, (params, opt.init(params)), None, length=steps)
    return jnp.argmax(logits(params, x_te), -1)


def reference(key: jax.Array, out: pathlib.Path, tl_result: dict, seeds: int,
              name: str = "reference") -> dict:
    """Our TL beside the lookup bound and two standard learners (optax Adam, softmax
    cross-entropy, L2 1e-4, 2000 full-batch steps, on the paper's inputs: bitmap + 20 copies
    of the 15 symbolic units): logistic regression and an MLP with 50 ReLU units. All on the
    train/test splits the TL's `accuracy` run used (``key`` is that run's key).

    Returns:
        Per learner: mean, std and min test accuracy over the splits, and the accuracy on
        patterns naming a shape / a colour.
    """
    data = tl_data.load()
    x = np.asarray(tl_data.inputs(data, 20), np.float32)  # sliced on the host, per split
    y = np.asarray(data.labels)
    is_shape = data.word < len(scene.SHAPES)
    keys = jax.random.split(key, seeds)
    fit = jax.jit(_adam_classifier, static_argnums=4)
    t = time.perf_counter()
    rows: dict[str, list] = {"lookup": [], "logistic regression (Adam)": [],
                             "MLP 50 ReLU (Adam)": []}
    for k in keys:
        tr, te = (np.asarray(i) for i in tl.split_indices(k))
        rows["lookup"].append(lookup_bound(data, tr, te))
        for label, hidden in (("logistic regression (Adam)", 0), ("MLP 50 ReLU (Adam)", 50)):
            pred = np.asarray(fit(x[tr], y[tr], x[te], jax.random.fold_in(k, hidden), hidden))
            right = pred == data.labels[te]
            rows[label].append({"acc": float(right.mean()),
                                "acc_shape_words": float(right[is_shape[te]].mean()),
                                "acc_colour_words": float(right[~is_shape[te]].mean())})

    def summary(r: list[dict]) -> dict:
        acc = np.array([v["acc"] for v in r])
        return {"test_acc_mean": float(acc.mean()), "test_acc_std": float(acc.std()),
                "test_acc_min": float(acc.min()),
                "test_acc_shape_words_mean": float(np.mean([v["acc_shape_words"] for v in r])),
                "test_acc_colour_words_mean": float(np.mean([v["acc_colour_words"]
                                                             for v in r]))}

    res = {"seeds": seeds, "learners": {k: summary(v) for k, v in rows.items()}}
    res["learners"]["our TL (paper's network, tuned input balance)"] = {
        "test_acc_mean": tl_result["test_acc_mean"], "test_acc_std": tl_result["test_acc_std"],
        "test_acc_min": min(tl_result["test_acc_per_seed"]),
        "test_acc_shape_words_mean": tl_result["test_acc_shape_words_mean"],
        "test_acc_colour_words_mean": tl_result["test_acc_colour_words_mean"]}
    res["wall_s"] = time.perf_counter() - t
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.2))
    names = list(res["learners"])
    mu = [res["learners"][n]["test_acc_mean"] for n in names]
    sd = [res["learners"][n]["test_acc_std"] for n in names]
    ax.barh(names, mu, xerr=sd, capsize=3)
    ax.axvline(0.95, color="gray", lw=0.8, ls=":")
    ax.set(xlim=(0, 1.02), xlabel=f"test accuracy ({seeds} splits)",
           title="TL beside the lookup bound and standard learners")
    fig.tight_layout()
    write_figure(out, name, res, fig)
    plt.close(fig)
    return res
