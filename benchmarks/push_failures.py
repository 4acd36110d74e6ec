"""Why pushes fail: a saved robot's agents judged on every push task from home and from random
starts, each failure told apart as a neighbour moved (the episode's wrong move) or the target
moved less than the 2 cm a push needs.

Usage:  python benchmarks/push_failures.py [--modules results/paper/touch_memory/modules]
        [--noise 0,0.3] [--key 7] [--tag NAME]
Writes results/tuning/push_failures_<tag>.json and prints a line per start noise.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import jax
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import grounding_jax as gj  # noqa: E402
from grounding_jax.core.io import atomic_write_text  # noqa: E402
from grounding_jax.paper import al_eval  # noqa: E402
from grounding_jax.sim.env import Env, EnvParams  # noqa: E402

OUT = pathlib.Path(__file__).resolve().parents[1] / "results" / "tuning"
PUSH = 2


def failures(out: dict) -> dict:
    """Push episodes of a judge's output ``[agents, 1, tasks]``, their failures split."""
    push = np.asarray(out["action"]) == PUSH
    ok = np.asarray(out["success"])[:, 0][:, push] > 0
    wrong = np.asarray(out["wrong_moved"])[:, 0][:, push] > 0
    moved = np.asarray(out["target_moved"])[:, 0][:, push]
    short = ~ok & ~wrong
    return {"episodes": int(ok.size), "failed": int((~ok).sum()),
            "neighbour_moved": int((~ok & wrong).sum()), "target_moved_under_2cm": int(short.sum()),
            "short_target_moved_cm_median": float(np.median(moved[short]) * 100)
            if short.any() else None,
            "per_agent_success": [float(x) for x in ok.mean(axis=1)]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modules", default="results/paper/touch_memory/modules")
    ap.add_argument("--noise", default="0,0.3")
    ap.add_argument("--key", type=int, default=7)
    ap.add_argument("--tag", default="touch_memory")
    args = ap.parse_args()
    robot = gj.load(args.modules)
    judge = al_eval.make_success(Env(robot.env_config), layouts=al_eval.ALL_LAYOUTS,
                                 actions=(PUSH,))
    rows = {}
    for noise in (float(x) for x in args.noise.split(",")):
        out = jax.device_get(judge(robot.agents, jax.random.key(args.key),
                                   EnvParams(start_noise=noise)))
        rows[str(noise)] = r = failures(out)
        print(f"start noise {noise}: {r['failed']} of {r['episodes']} pushes failed: "
              f"{r['neighbour_moved']} moved a neighbour, {r['target_moved_under_2cm']} moved "
              "the target < 2 cm", flush=True)
    config = json.loads((pathlib.Path(args.modules) / "config.json").read_text())
    res = {"modules": args.modules, "variant": config["config"].get("extra", {}), "key": args.key,
           "levels": rows}
    atomic_write_text(OUT / f"push_failures_{args.tag}.json", json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
