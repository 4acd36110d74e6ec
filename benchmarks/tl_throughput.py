"""TL throughput: the Fig 6 sweep (hidden sizes x seeds x epochs) three ways, in one process.

1. ``padded``: every hidden size padded to the largest and masked, all runs in one vmapped
   call -- one compile for the whole sweep;
2. ``grouped``: one compile per hidden size (no padding), seeds vmapped;
3. ``numpy``: the sequential baseline -- one NumPy MLP at a time, online back-propagation in
   a Python loop, as the paper's era would run it.

Prints wall times (compile reported separately) and the ratios; writes
results/benchmarks/tl_throughput.json.

Usage:  python benchmarks/tl_throughput.py [--epochs 600] [--seeds 5]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))
import grounding_jax as gj  # noqa: E402
from grounding_jax.learn import tl
from grounding_jax.sim import tl_data  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parent.parent
HIDDEN = [5, 10, 20, 30, 40, 50, 75, 100]


def numpy_run(x: np.ndarray, y: np.ndarray, train: np.ndarray, hidden: int, epochs: int,
              lr: float, rng: np.random.Generator) -> float:
    """One MLP, online backprop of the squared error, sigmoid units. Returns train accuracy."""
    d = x.shape[1]
    w1 = rng.uniform(-1, 1, (d, hidden)).astype(np.float32) / np.sqrt(d)
    b1 = np.zeros(hidden, np.float32)
    w2 = rng.uniform(-1, 1, (hidden, 3)).astype(np.float32) / np.sqrt(hidden)
    b2 = np.zeros(3, np.float32)
    t = np.eye(3, dtype=np.float32)[y]
    for _ in range(epochs):
        for i in rng.permutation(train):
            h = 1 / (1 + np.exp(-(x[i] @ w1 + b1)))
            o = 1 / (1 + np.exp(-(h @ w2 + b2)))
            do = (o - t[i]) * o * (1 - o)
            dh = (w2 @ do) * h * (1 - h)
            w2 -= lr * np.outer(h, do)
            b2 -= lr * do
            w1 -= lr * np.outer(x[i], dh)
            b1 -= lr * dh
    h = 1 / (1 + np.exp(-(x[train] @ w1 + b1)))
    o = 1 / (1 + np.exp(-(h @ w2 + b2)))
    return float(np.mean(o.argmax(1) == y[train]))


def timed(fn, *args):
    t = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--epochs", type=int, default=600)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--numpy-runs", type=int, default=None,
                    help="time only this many NumPy runs and scale up (default: all)")
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks" / "tl_throughput.json"))
    args = ap.parse_args()
    gj.enable_compilation_cache()
    data = tl_data.load()
    seeds = args.seeds
    keys = jax.random.split(jax.random.key(0), len(HIDDEN) * seeds)
    res: dict = {"epochs": args.epochs, "seeds": seeds, "hidden": HIDDEN,
                 "cpu_count": os.cpu_count(), "devices": [str(d) for d in jax.devices()]}

    # 1. padded: one compile
    budget = int(data.bitmaps.sum(1).max())  # sparse pixel rows, as the experiments use
    res["pixel_budget"] = budget
    cfg = tl.TLConfig(epochs=args.epochs, max_hidden=max(HIDDEN), max_replication=20,
                      eval_every=args.epochs, pixel_budget=budget)
    hp = tl.TLHyper(hidden=jnp.repeat(jnp.asarray(HIDDEN), seeds),
                    replication=jnp.full(len(keys), 20), lr=jnp.full(len(keys), 0.1),
                    noise=jnp.zeros(len(keys)))
    f = jax.jit(jax.vmap(tl.make_train(cfg, data)))
    t = time.perf_counter()
    comp = f.lower(keys, hp).compile()
    res["padded_compile_s"] = time.perf_counter() - t
    (_, m), res["padded_run_s"] = timed(comp, keys, hp)
    res["padded_train_acc"] = float(np.mean(m["final_train_acc"]))
    print(f"padded : compile {res['padded_compile_s']:.1f} s, run {res['padded_run_s']:.1f} s",
          flush=True)

    # 2. grouped: one compile per hidden size
    res["grouped_compile_s"], res["grouped_run_s"] = 0.0, 0.0
    accs = []
    for i, h in enumerate(HIDDEN):
        cfg_h = tl.TLConfig(epochs=args.epochs, max_hidden=h, max_replication=20,
                            eval_every=args.epochs, pixel_budget=budget)
        k = keys[i * seeds:(i + 1) * seeds]
        fh = jax.jit(jax.vmap(tl.make_train(cfg_h, data), in_axes=(0, None)))
        t = time.perf_counter()
        comp = fh.lower(k, tl.TLHyper(hidden=h)).compile()
        res["grouped_compile_s"] += time.perf_counter() - t
        (_, m), dt = timed(comp, k, tl.TLHyper(hidden=h))
        res["grouped_run_s"] += dt
        accs.append(float(np.mean(m["final_train_acc"])))
    res["grouped_train_acc"] = float(np.mean(accs))
    print(f"grouped: compile {res['grouped_compile_s']:.1f} s, run {res['grouped_run_s']:.1f} s",
          flush=True)

    # 3. sequential NumPy
    x = tl_data.inputs(data, 20).astype(np.float32)
    y = data.labels
    runs = [(h, s) for h in HIDDEN for s in range(seeds)]
    todo = runs if args.numpy_runs is None else runs[:: max(1, len(runs) // args.numpy_runs)]
    t = time.perf_counter()
    np_acc = []
    for h, s in todo:
        rng = np.random.default_rng(s)
        train, _ = tl_data.split(s)
        np_acc.append(numpy_run(x, y, train, h, args.epochs, 0.1, rng))
    dt = time.perf_counter() - t
    res["numpy_timed_runs"] = len(todo)
    res["numpy_run_s"] = dt * len(runs) / len(todo)
    res["numpy_train_acc"] = float(np.mean(np_acc))
    print(f"numpy  : {res['numpy_run_s']:.1f} s ({len(todo)} of {len(runs)} runs timed)",
          flush=True)

    best = min(res["padded_run_s"] + res["padded_compile_s"],
               res["grouped_run_s"] + res["grouped_compile_s"])
    res["speedup_padded_vs_numpy"] = res["numpy_run_s"] / res["padded_run_s"]
    res["speedup_grouped_vs_numpy"] = res["numpy_run_s"] / res["grouped_run_s"]
    res["speedup_best_incl_compile_vs_numpy"] = res["numpy_run_s"] / best
    print(f"speed-up over NumPy: padded {res['speedup_padded_vs_numpy']:.1f}x, grouped "
          f"{res['speedup_grouped_vs_numpy']:.1f}x (run only); best incl. compile "
          f"{res['speedup_best_incl_compile_vs_numpy']:.1f}x")
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=2) + "\n")
    print("\n" + table(res), end="")
    print("wrote", out)


def table(result: dict) -> str:
    """The Markdown table of a run (``results/benchmarks/tl_throughput.json``)."""
    r = result
    return "\n".join([
        "| way | compile (s) | run (s) | run speed-up over NumPy |", "|---|---|---|---|",
        f"| sequential NumPy MLPs (baseline) | – | {r['numpy_run_s']:.0f} | 1× |",
        f"| padded to H={max(r['hidden'])}, one compile | {r['padded_compile_s']:.1f} | "
        f"{r['padded_run_s']:.1f} | {r['speedup_padded_vs_numpy']:.1f}× |",
        f"| one compile per hidden size (kept) | {r['grouped_compile_s']:.1f} | "
        f"{r['grouped_run_s']:.1f} | {r['speedup_grouped_vs_numpy']:.1f}× |"]) + "\n"


if __name__ == "__main__":
    main()
