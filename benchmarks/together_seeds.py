"""The modules learning together against one after another, on more seeds than one run has:
the ``together`` stage's paper profile run again with other keys, its agents pooled.

One run judges 5 agents per arm, and an agent's touch varies from 0% to 78%: this gathers
the agents of several keys (each key's agents differ, the two arms of a key share them) and
counts, agent by agent, which arm did better. Writes ``results/tuning/together_seeds.json``.

``--tl-curves`` instead measures how fast each TL setting of the stage
(`grounding_jax.learn.together.TL_HYPERS`) finds its answers: 5 TLs from the first key, test
accuracy every 100 of 600 epochs (``results/tuning/together_tl_curves.json``).

Usage:  python benchmarks/together_seeds.py [--keys 41,42] [--profile paper]
        [--set field=value ...] [--tl-curves]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile
import time

import jax
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from grounding_jax.core.io import atomic_write_text  # noqa: E402
from grounding_jax.paper.stage import Inputs, stages  # noqa: E402
from grounding_jax.paper.stages import together as T  # noqa: E402

MEASURES = ("tl_test_acc", *T.ACTIONS, "named")


def per_agent(arm: dict) -> dict[str, list[float]]:
    """An arm's final measures, agent by agent."""
    return {"tl_test_acc": arm["tl_test_acc"], "named": arm["named"], **arm["success"]}


def pooled(runs: list[dict]) -> dict:
    """Every key's agents together: per measure and arm the median agent and the min-max,
    and how many agents did better, worse or the same together than in sequence."""
    out = {}
    for m in MEASURES:
        seq = np.concatenate([per_agent(r["arms"]["sequence"])[m] for r in runs])
        tog = np.concatenate([per_agent(r["arms"]["together"])[m] for r in runs])
        d = tog - seq
        out[m] = {"sequence": T.spread(seq.tolist()), "together": T.spread(tog.tolist()),
                  "together_better": int(np.sum(d > 1e-6)),
                  "together_worse": int(np.sum(d < -1e-6)), "agents": int(d.size)}
    return out


def table(result: dict) -> str:
    """The Markdown table of ``results/tuning/together_seeds.json``."""
    p = result["pooled"]
    changes = "".join(f", {k}={v}" for k, v in result.get("changes", {}).items())
    lines = [f"| measure ({p['touch']['agents']} agents, keys {result['keys']}{changes}) | in "
             "sequence: median (min-max) | together | agents better / worse together |",
             "|---|---|---|---|"]
    cell = lambda s: f"{100 * s['median']:.0f}% ({100 * s['min']:.0f}-{100 * s['max']:.0f}%)"  # noqa: E731
    for m in MEASURES:
        r = p[m]
        lines.append(f"| {m} | {cell(r['sequence'])} | {cell(r['together'])} | "
                     f"{r['together_better']} / {r['together_worse']} |")
    return "\n".join(lines)


def tl_curves(key: jax.Array, n: int = 5, epochs: int = 600, every: int = 100) -> dict:
    """Each TL setting's test accuracy every ``every`` epochs, ``n`` TLs from ``key``."""
    from grounding_jax.learn import tl
    from grounding_jax.learn import together as tg

    cfg = tl.TLConfig(epochs=epochs, eval_every=every, max_hidden=50, max_replication=20)
    train = jax.jit(jax.vmap(tl.make_train(cfg), in_axes=(0, None)))
    keys = jax.random.split(key, n)
    return {name: np.asarray(train(keys, hp)[1]["test_acc"]).T.tolist()
            for name, hp in tg.TL_HYPERS.items()} | {"epochs": list(range(every, epochs + 1,
                                                                          every))}


def curves_table(result: dict) -> str:
    """The Markdown table of ``results/tuning/together_tl_curves.json``: the median TL's test
    accuracy after each block of epochs."""
    epochs = result["curves"]["epochs"]
    lines = [f"| TL setting ({result['tls']} TLs, key {result['key']}) | "
             + " | ".join(f"{e} epochs" for e in epochs) + " |",
             "|---" * (len(epochs) + 1) + "|"]
    for name, rows in result["curves"].items():
        if name != "epochs":
            lines.append(f"| {name} | " + " | ".join(
                f"{100 * float(np.median(r)):.0f}%" for r in rows) + " |")
    return "\n".join(lines)


def stage_table(res: dict) -> str:
    """The arms' table of one run of the stage (its ``together.json``)."""
    return "\n".join(T.arms_table(res))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keys", default="41,42")
    ap.add_argument("--profile", default="paper")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    ap.add_argument("--out", default=str(ROOT / "results" / "tuning" / "together_seeds.json"))
    ap.add_argument("--tl-curves", action="store_true")
    args = ap.parse_args(argv)
    keys = [int(k) for k in args.keys.split(",")]
    if args.tl_curves:
        result = {"key": keys[0], "tls": 5, "curves": tl_curves(jax.random.key(keys[0]))}
        out = pathlib.Path(args.out).with_name("together_tl_curves.json")
        atomic_write_text(out, json.dumps(result, indent=1) + "\n")
        print(curves_table(result))
        return 0
    stage = stages()["together"]
    changes = dict(s.split("=", 1) for s in args.set)
    config = stage.make_config(args.profile, changes)  # bad fields fail before any run
    runs = []
    t0 = time.perf_counter()
    for k in keys:
        inputs = Inputs(modules=ROOT / "results" / args.profile / "modules",
                        profile=args.profile, backend="mujoco", seed=k)
        with tempfile.TemporaryDirectory() as scratch:  # its figure is not kept
            runs.append(stage.run(jax.random.key(k), inputs, pathlib.Path(scratch), config))
    result = {"keys": keys, "profile": args.profile, "changes": changes,
              "wall_s": time.perf_counter() - t0, "pooled": pooled(runs),
              "runs": [{"key": k, "summary": {a: r["arms"][a]["summary"] for a in T.ARMS},
                        "per_agent": {a: per_agent(r["arms"][a]) for a in T.ARMS}}
                       for k, r in zip(keys, runs, strict=True)]}
    atomic_write_text(pathlib.Path(args.out), json.dumps(result, indent=1) + "\n")
    print(table(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
