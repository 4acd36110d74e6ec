"""TL experiments of the paper: accuracy at H=50/n=20, Fig 6 (hidden size), Fig 7 (replication
n), and the pixel-noise test. Each writes ``<name>.json`` and ``<name>.png`` under ``out``.

Grid points x seeds run as ``vmap``ped, ``jit``ted calls, one compile per hidden size (see
:func:`run_grid`).
"""

from __future__ import annotations

import dataclasses
import pathlib
import time
from typing import Any

import jax
import numpy as np

from grounding_jax import tl, tl_data
from grounding_jax._io import pyplot, write_figure

PAPER = {
    "accuracy": {"test_acc": 0.95, "train_acc": 1.0},
    "noise": {"train_acc": 1.0, "test_acc": 0.75},
    "fig6": "test accuracy saturates at ~95% from ~50 hidden units",
    "fig7": "best ~95% at n=20; without replication <= 75%",
}


def run_grid(key: jax.Array, grid: list[dict[str, Any]], seeds: int, config: tl.TLConfig,
             data: tl_data.TLData | None = None) -> dict[str, np.ndarray]:
    """Train every grid point with ``seeds`` seeds.

    Points are grouped by hidden size -- one compile per size, everything else (seeds, n,
    learning rate, noise) ``vmap``ped and traced. ``benchmarks/tl_throughput.py`` measured
    this faster than padding every size to the largest and running one compile.

    Args:
        key: one PRNG key; split once into ``len(grid) * seeds`` run keys.
        grid: hyperparameter dicts (fields of :class:`tl.TLHyper`).
        seeds: runs per grid point.
        config: static config (``max_hidden`` is set per group; ``max_replication`` must
            cover the grid).
        data: TL data (default: the cached configurations).

    Returns:
        Metrics with leading axes ``[len(grid), seeds]``.
    """
    data = tl_data.load() if data is None else data
    if config.pixel_budget == 0 and all(g.get("noise", 0.0) == 0 for g in grid):
        # clean bitmaps: sparse pixel updates give the same result with less memory traffic
        config = dataclasses.replace(config, pixel_budget=int(data.bitmaps.sum(1).max()))
    default = tl.TLHyper()
    rows = [{f: g.get(f, getattr(default, f)) for f in ("lr", "hidden", "replication", "noise")}
            for g in grid for _ in range(seeds)]

    tl.validate(tl.stack_hyper(rows), dataclasses.replace(
        config, max_hidden=max(int(r["hidden"]) for r in rows)))
    keys = jax.random.split(key, len(rows))
    out: dict[str, list] = {}
    order = []
    for h in sorted({int(r["hidden"]) for r in rows}):
        idx = [i for i, r in enumerate(rows) if int(r["hidden"]) == h]
        cfg = dataclasses.replace(config, max_hidden=h)
        train = jax.jit(jax.vmap(tl.make_train(cfg, data)))
        _, m = jax.block_until_ready(train(keys[np.asarray(idx)],
                                           tl.stack_hyper([rows[i] for i in idx])))
        for k, v in m.items():
            out.setdefault(k, []).append(np.asarray(v))
        order.extend(idx)
    inv = np.argsort(order)
    return {k: np.concatenate(v)[inv].reshape(len(grid), seeds, *v[0].shape[1:])
            for k, v in out.items()}


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


def accuracy(key: jax.Array, out: pathlib.Path, seeds: int = 5, epochs: int = 600,
             noise: float = 0.0, name: str = "accuracy", noise_mode: str = "fixed") -> dict:
    """H=50, n=20 over ``seeds`` seeds (``noise`` > 0: the pixel-flip test)."""
    cfg = tl.TLConfig(epochs=epochs, max_hidden=50, max_replication=20, noise_mode=noise_mode)
    t = time.perf_counter()
    m = run_grid(key, [{"hidden": 50, "replication": 20, "noise": noise}], seeds, cfg)
    res = {"hidden": 50, "replication": 20, "noise": noise, "noise_mode": noise_mode,
           "epochs": epochs, "seeds": seeds,
           **_summary(m, 0), "wall_s": time.perf_counter() - t,
           "paper": PAPER["noise" if noise else "accuracy"]}
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ep = np.arange(1, m["test_acc"].shape[-1] + 1) * cfg.eval_every
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
    base = {"hidden": 50, "replication": 20}
    grid = [{**base, field: int(v)} for v in values]
    cfg = tl.TLConfig(epochs=epochs, max_replication=max(g["replication"] for g in grid))
    t = time.perf_counter()
    m = run_grid(key, grid, seeds, cfg)
    points = [{field: int(v), **_summary(m, i)} for i, v in enumerate(values)]
    res = {"field": field, "values": [int(v) for v in values], "fixed": base, "seeds": seeds,
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
