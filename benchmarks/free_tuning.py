"""Tuning runs of the free family's action learner (README "Beyond the paper", tuning table):
agents from a tuning key train on random placements with the shipped settings and schedule,
then are judged greedily on every slot of held-out placements from another key.

The keys are never train.py's (0): agents from ``--key`` (11 in the README's table), held-out
placements from ``--eval-key`` (999). ``--push-reward pose`` trains push to reach for the
pushing pose (minus the L1 distance to ``placement.push_pose``, as touch reaches for its
touching pose) instead of the shipped reward (minus the palm's distance to the target's
centre, the paper's), to compare the two on the same agents.

Usage:  python benchmarks/free_tuning.py [--agents 8] [--phase1 1000] [--phase2 1000]
        [--placements 12] [--key 11] [--eval-key 999] [--push-reward pose|centre]
Prints the median agent's success per action (min-max over agents), by slot, and the share of
episodes that moved a wrong object; writes results/benchmarks/free_tuning_<push>.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
import time

import jax
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import grounding_jax as gj  # noqa: E402
from grounding_jax import al, beyond, tasks  # noqa: E402
from grounding_jax import al_experiments as alx  # noqa: E402
from grounding_jax._io import atomic_write_text, library_versions  # noqa: E402
from grounding_jax.env import Env  # noqa: E402


def _pose_push(t, params):
    """Push reaches for its pushing pose, with the free family's penalty for touching a
    neighbour."""
    return -t["push_l1"] + tasks._avoid(t, params)


POSE = tasks.register(dataclasses.replace(
    tasks.FREE, name="free_pose_push",
    actions=(*tasks.FREE.actions[:2], tasks.Action("push", _pose_push, tasks.FREE.actions[2]
                                                   .success))))


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--agents", type=int, default=8)
    ap.add_argument("--phase1", type=int, default=1000)
    ap.add_argument("--phase2", type=int, default=1000)
    ap.add_argument("--placements", type=int, default=12)
    ap.add_argument("--key", type=int, default=11, help="the agents' tuning key")
    ap.add_argument("--eval-key", type=int, default=999, help="held-out placements' key")
    ap.add_argument("--push-reward", choices=("centre", "pose"), default="centre")
    args = ap.parse_args(argv)
    for name in ("agents", "phase1", "placements"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')}: must be >= 1, got {getattr(args, name)}")
    gj.enable_compilation_cache()
    cfg = beyond.config(args.phase1, args.phase2)
    if args.push_reward == "pose":
        cfg = dataclasses.replace(
            cfg, env=dataclasses.replace(cfg.env, task_set=POSE.name),
            learner=dataclasses.replace(cfg.learner, task_set=POSE.name))
    env = Env(cfg.env)
    hp = beyond.hyper()
    t = time.perf_counter()
    agents, _ = al.train_in_chunks(cfg, jax.random.split(jax.random.key(args.key), args.agents),
                                   hp, [cfg.episodes])
    train_s = time.perf_counter() - t
    judge = beyond.make_success(env, jax.random.key(args.eval_key), args.placements)
    out = jax.device_get(judge(agents, jax.random.key(0), hp.env))
    table = alx.success_table(out)
    act = np.asarray(out["action"])
    wrong = {a: float(np.asarray(out["wrong_moved"])[..., act == i].mean())
             for i, a in enumerate(tasks.FREE.action_names)}
    res = {**vars(args), "train_s": train_s, "by_action": table["by_action"],
           "spread": table["spread"], "by_task": table["by_task"], "wrong_moved": wrong,
           "libraries": library_versions()}
    for a in tasks.FREE.action_names:
        lo, *_, hi = table["spread"][a]
        slots = " / ".join(f"{table['by_task'][f'{a} {p}']:.0%}" for p in tasks.POSITIONS)
        print(f"{a}: median agent {table['by_action'][a]:.0%} ({lo:.0%}-{hi:.0%}); by slot "
              f"(pooled, left / middle / right) {slots}; wrong object moved in "
              f"{wrong[a]:.0%} of the episodes", flush=True)
    print(f"training {train_s:.0f} s")
    out_dir = pathlib.Path("results/benchmarks")
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / f"free_tuning_{args.push_reward}.json",
                      json.dumps(res, indent=2) + "\n")
    return res


if __name__ == "__main__":
    main()
