"""Variants of the paper family's AL, trained on the same tuning keys and judged alike: each
variant changes the shipped settings by a few fields -- a task set (``task_set=paper_memory``:
the actor remembers its last two steps), the actor-critic heads (``heads=0-1-2``: a network
per action; default one for all, the paper's), traced env or learner fields (``start_noise=0.3``:
training episodes start from random postures; ``start_by_action=0-0-1``: only push's do;
``touch_target_penalty=0.1``: touching the target pays instead of costing 0.3) -- and is
judged the way the ``random_starts`` stage judges the saved robot: all three actions on every
layout, from home and from random starts at each noise level, with the same keys for every
variant.

The keys are never train.py's (0): agents from ``--key`` (21), judged from ``--eval-key``
(999).

Usage:  python benchmarks/al_variants.py VARIANT [VARIANT ...] [--agents 8] [--phase1 150]
        [--phase2 1050] [--judge-noise 0,0.15,0.3,0.5] [--key 21] [--eval-key 999]
        [--tag NAME]
        VARIANT: NAME or NAME:FIELD=VALUE,FIELD=VALUE (``shipped`` alone: no change)
Prints the median agent's success per action for each variant at each judged noise level;
writes results/tuning/al_variants_<tag>.json.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import jax

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import grounding_jax as gj  # noqa: E402
from grounding_jax.core.io import atomic_write_text, library_versions  # noqa: E402
from grounding_jax.paper.al_experiments import TUNED, TUNED_AL  # noqa: E402
from grounding_jax.paper.stages import random_starts as RS  # noqa: E402
from grounding_jax.paper.stages import touch_memory as TM  # noqa: E402

OUT = pathlib.Path(__file__).resolve().parents[1] / "results" / "tuning"


def parse_variant(text: str) -> tuple[str, dict, dict[str, float | list[float]]]:
    """``NAME[:FIELD=VALUE,...]`` -> (name, static fields -- ``task_set``, ``heads`` as
    ``0-1-2`` --, traced fields)."""
    name, _, rest = text.partition(":")
    fields: dict[str, float | list[float]] = {}
    static: dict = {"task_set": "paper", "heads": None}
    for item in filter(None, rest.split(",")):
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"variant {text!r}: expected FIELD=VALUE, got {item!r}")
        if key == "task_set":
            static["task_set"] = value
        elif key == "heads":
            static["heads"] = tuple(int(h) for h in value.split("-"))
        elif key == "start_by_action":  # one scale per action, as 0-0-1
            fields[key] = [float(v) for v in value.split("-")]
        else:
            fields[key] = float(value)
    return name, static, fields


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("variants", nargs="+")
    ap.add_argument("--agents", type=int, default=8)
    ap.add_argument("--phase1", type=int, default=150)
    ap.add_argument("--phase2", type=int, default=1050)
    ap.add_argument("--judge-noise", default="0,0.15,0.3,0.5")
    ap.add_argument("--key", type=int, default=21)
    ap.add_argument("--eval-key", type=int, default=999)
    ap.add_argument("--tag", default="variants")
    args = ap.parse_args(argv)
    variants = [parse_variant(v) for v in args.variants]
    gj.enable_compilation_cache()
    judged = RS.RandomStartsConfig(noise=tuple(float(v) for v in args.judge_noise.split(",")),
                                   layouts="all", perform_checks=0)
    keys = jax.random.split(jax.random.key(args.key), args.agents)
    rows = {}
    for name, static, fields in variants:
        t = time.perf_counter()
        agents, cfg = TM.train_variant(keys, args.phase1, args.phase2, static["task_set"],
                                       fields, static["heads"])
        train_s = time.perf_counter() - t
        print(f"{name}: trained in {train_s:.0f} s", flush=True)
        levels, _ = RS.judge_levels(agents, cfg.env, jax.random.key(args.eval_key), judged)
        rows[name] = {"task_set": static["task_set"], "heads": static["heads"],
                      "fields": fields, "train_s": train_s,
                      "levels": levels}
    res = {"agents": args.agents, "phase1": args.phase1, "phase2": args.phase2,
           "key": args.key, "eval_key": args.eval_key, "judged_noise": list(judged.noise),
           "layouts": judged.layouts, "shipped": {**TUNED, **TUNED_AL}, "variants": rows,
           "libraries": library_versions()}
    OUT.mkdir(parents=True, exist_ok=True)
    atomic_write_text(OUT / f"al_variants_{args.tag}.json", json.dumps(res, indent=1) + "\n")
    print("variant -> point/touch/push % of the median agent, judged from starts within "
          + ", ".join(f"±{n}" for n in judged.noise))
    for name, row in rows.items():
        cells = ["/".join(f"{100 * lv['by_action'][a]:.0f}" for a in ("point", "touch", "push"))
                 for lv in row["levels"].values()]
        print(f"  {name}: " + "  ".join(cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
