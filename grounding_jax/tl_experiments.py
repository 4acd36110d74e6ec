"""TL experiments of the paper: accuracy at H=50/n=20, Fig 6 (hidden size), Fig 7 (replication
n), and the pixel-noise test. Each writes ``<name>.json`` and ``<name>.png`` under ``out``.

Every grid point x seed is one row of a single ``vmap``ped, ``jit``ted call (sizes padded and
masked, see :mod:`grounding_jax.tl`), so each experiment compiles once.
"""

from __future__ import annotations

import json
import os
import pathlib
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax import tl, tl_data

PAPER = {
    "accuracy": {"test_acc": 0.95, "train_acc": 1.0},
    "noise": {"train_acc": 1.0, "test_acc": 0.75},
    "fig6": "test accuracy saturates at ~95% from ~50 hidden units",
    "fig7": "best ~95% at n=20; without replication <= 75%",
}


def run_grid(key: jax.Array, grid: list[dict[str, Any]], seeds: int, config: tl.TLConfig,
             data: tl_data.TLData | None = None) -> dict[str, np.ndarray]:
    """Train every grid point with ``seeds`` seeds in one vmapped call.

    Args:
        key: one PRNG key; split once into ``len(grid) * seeds`` run keys.
        grid: hyperparameter dicts (fields of :class:`tl.TLHyper`).
        seeds: runs per grid point.
        config: static config (its padded sizes must cover the grid).
        data: TL data (default: the cached configurations).

    Returns:
        Metrics with leading axes ``[len(grid), seeds]``.
    """
    rows = [dict(g) for g in grid for _ in range(seeds)]
    hp = tl.TLHyper(**{f: jnp.asarray([r.get(f, getattr(tl.TLHyper(), f)) for r in rows],
                                      jnp.float32 if f in ("lr", "noise") else jnp.int32)
                       for f in ("lr", "hidden", "replication", "noise")})
    tl.validate(hp, config)
    keys = jax.random.split(key, len(rows))
    train = jax.jit(jax.vmap(tl.make_train(config, data)))
    _, metrics = jax.block_until_ready(train(keys, hp))
    return {k: np.asarray(v).reshape(len(grid), seeds, *v.shape[1:]) for k, v in metrics.items()}


def _write(out: pathlib.Path, name: str, payload: dict, fig) -> None:
    out.mkdir(parents=True, exist_ok=True)
    tmp = out / f".{name}.json.tmp"
    tmp.write_text(json.dumps(payload, indent=2) + "\n")
    os.replace(tmp, out / f"{name}.json")
    tmp_png = out / f".{name}.tmp.png"
    fig.savefig(tmp_png, dpi=110, bbox_inches="tight")
    os.replace(tmp_png, out / f"{name}.png")


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _summary(m: dict[str, np.ndarray], i: int) -> dict[str, float]:
    best = m["test_acc"][i].max(axis=-1)  # best test accuracy over the evaluation points
    return {
        "train_acc_mean": float(m["final_train_acc"][i].mean()),
        "train_acc_std": float(m["final_train_acc"][i].std()),
        "test_acc_mean": float(m["final_test_acc"][i].mean()),
        "test_acc_std": float(m["final_test_acc"][i].std()),
        "test_acc_per_seed": [float(v) for v in m["final_test_acc"][i]],
        "best_epoch_test_acc_mean": float(best.mean()),
        "train_rmse_mean": float(m["final_train_rmse"][i].mean()),
        "test_rmse_mean": float(m["final_test_rmse"][i].mean()),
    }


def accuracy(key: jax.Array, out: pathlib.Path, seeds: int = 5, epochs: int = 600,
             noise: float = 0.0, name: str = "accuracy") -> dict:
    """H=50, n=20 over ``seeds`` seeds (``noise`` > 0: the pixel-flip test)."""
    cfg = tl.TLConfig(epochs=epochs, max_hidden=50, max_replication=20)
    t = time.perf_counter()
    m = run_grid(key, [{"hidden": 50, "replication": 20, "noise": noise}], seeds, cfg)
    res = {"hidden": 50, "replication": 20, "noise": noise, "epochs": epochs, "seeds": seeds,
           **_summary(m, 0), "wall_s": time.perf_counter() - t,
           "paper": PAPER["noise" if noise else "accuracy"]}
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.2))
    ep = np.arange(1, m["test_acc"].shape[-1] + 1) * cfg.eval_every
    for key_, lab in (("train_acc", "train"), ("test_acc", "test")):
        mu, sd = m[key_][0].mean(0), m[key_][0].std(0)
        ax.plot(ep, mu, label=lab)
        ax.fill_between(ep, mu - sd, mu + sd, alpha=0.2)
    ax.set(xlabel="epoch", ylabel="accuracy", ylim=(0, 1.02),
           title=f"TL H=50 n=20{f' noise {noise:.0%}' if noise else ''} ({seeds} seeds)")
    ax.legend()
    _write(out, name, res, fig)
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
    cfg = tl.TLConfig(epochs=epochs, max_hidden=max(g["hidden"] for g in grid),
                      max_replication=max(g["replication"] for g in grid))
    t = time.perf_counter()
    m = run_grid(key, grid, seeds, cfg)
    points = [{field: int(v), **_summary(m, i)} for i, v in enumerate(values)]
    res = {"field": field, "values": [int(v) for v in values], "fixed": base, "seeds": seeds,
           "epochs": epochs, "points": points, "wall_s": time.perf_counter() - t,
           "paper": PAPER[name] if name in PAPER else None}
    plt = _plt()
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
    _write(out, name, res, fig)
    plt.close(fig)
    return res
