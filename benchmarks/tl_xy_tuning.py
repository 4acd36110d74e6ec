"""Tuning runs of the continuous TL's learning rate (docs/beyond.md): one localizer
per (lr, lr_final) point, all from the same key (the same train/test split and initial
weights), trained in one ``vmap`` on the shipped scenes with train.py's paper-profile sizes
(200 hidden units, 60,000 updates); held-out error in cm, overall and for the shape and the
colour words.

The keys are never train.py's (its localizers take theirs from ``jax.random.key(seed)``'s
split): the docs' rows come from ``--key 0`` and ``--key 1``.

Usage:  python benchmarks/tl_xy_tuning.py [--key 0] [--steps 60000]
        [--grid 1e-3:1,1e-3:0.01,3e-3:0.01]
Prints each point's error; writes results/tuning/tl_xy_tuning_k<key>.json.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import grounding_jax as gj  # noqa: E402
from grounding_jax.core.io import atomic_write_text, library_versions  # noqa: E402
from grounding_jax.learn import tl_xy  # noqa: E402
from grounding_jax.sim import tasks


def _grid(text: str) -> list[tuple[float, float]]:
    try:
        points = [tuple(float(v) for v in p.split(":")) for p in text.split(",") if p.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected lr:lr_final pairs, got {text!r}") from None
    if not points or any(len(p) != 2 for p in points):
        raise argparse.ArgumentTypeError(f"expected lr:lr_final pairs, got {text!r}")
    return points


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--key", type=int, default=0)
    ap.add_argument("--steps", type=int, default=60000)
    ap.add_argument("--grid", type=_grid, default=_grid("1e-3:1,1e-3:0.01,3e-3:0.01"),
                    help="lr:lr_final points, comma-separated")
    args = ap.parse_args(argv)
    if args.steps < 10:
        ap.error(f"--steps: must be >= 10, got {args.steps}")
    hps = [tl_xy.XYHyper(lr=lr, lr_final=f).validate() for lr, f in args.grid]
    gj.enable_compilation_cache()
    data = tl_xy.load()
    cfg = tl_xy.XYConfig(hidden=200, replication=20, steps=args.steps,
                         eval_every=args.steps // 10)
    stacked = jax.tree.map(lambda *x: jnp.asarray(x, jnp.float32), *hps)
    t = time.perf_counter()
    _, m = jax.jit(jax.vmap(tl_xy.make_train(cfg, data), in_axes=(None, 0)))(
        jax.random.key(args.key), stacked)
    err = np.asarray(m["test_err_cm"])  # [points, test scenes, 6 words]
    res = {"key": args.key, "steps": args.steps, "scenes": len(data.layout),
           "wall_s": time.perf_counter() - t, "words": list(tasks.TARGET_WORDS),
           "points": [], "libraries": library_versions()}
    shapes = [tasks.TARGET_WORDS.index(w) for w in tasks.SHAPES]
    colours = [tasks.TARGET_WORDS.index(w) for w in tasks.COLOURS]
    for i, (lr, f) in enumerate(args.grid):
        e = err[i]
        row = {"lr": lr, "lr_final": f,
               "median_cm": float(np.median(e)), "p95_cm": float(np.quantile(e, 0.95)),
               "shape_median_cm": float(np.median(e[:, shapes])),
               "shape_p95_cm": float(np.quantile(e[:, shapes], 0.95)),
               "colour_median_cm": float(np.median(e[:, colours])),
               "colour_p95_cm": float(np.quantile(e[:, colours], 0.95)),
               "curve_p95_cm": np.asarray(m["test_p95_cm"][i]).tolist()}
        res["points"].append(row)
        print(f"lr {lr:g} -> x{f:g}: median {row['median_cm']:.2f} cm, p95 {row['p95_cm']:.2f} "
              f"cm; shape words {row['shape_median_cm']:.2f} / {row['shape_p95_cm']:.2f}; "
              f"colour words {row['colour_median_cm']:.2f} / {row['colour_p95_cm']:.2f}",
              flush=True)
    out = pathlib.Path("results/tuning")
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / f"tl_xy_tuning_k{args.key}.json", json.dumps(res, indent=2) + "\n")
    return res


if __name__ == "__main__":
    main()
