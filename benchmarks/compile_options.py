"""The physics programs under XLA's default options and under `core.xla.physics_options`,
in this one process: compile seconds, run seconds and whether the outputs agree bit for bit.

Two programs stand for the physics programs of a run: an AL training run of a batch of
agents (``al.make_train`` under ``jit(vmap)``) and the greedy episodes of every task and
layout, judged as `al_eval.make_success` judges them. Each is compiled ahead of time under
both option sets with the persistent cache off (its builds are what is measured), then run
``--repeats`` times in alternation; the medians are compared as ratios.

Usage:  python benchmarks/compile_options.py [--agents 4] [--episodes 60] [--repeats 3]
Writes results/benchmarks/compile_options.json and prints its Markdown table (`table`).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import sys
import time

import jax
import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from grounding_jax.core import xla  # noqa: E402
from grounding_jax.learn import al, cacla  # noqa: E402
from grounding_jax.paper import al_eval  # noqa: E402
from grounding_jax.paper.al_experiments import TUNED  # noqa: E402
from grounding_jax.sim.env import DEFAULT_PARAMS, EnvConfig  # noqa: E402

OPTIONS = {"default": None, "physics_options": xla.CPU_PHYSICS_OPTIONS}


def _compiled(fun, args, options):
    t = time.perf_counter()
    c = jax.jit(fun, compiler_options=options).lower(*args).compile()
    return c, time.perf_counter() - t


def _timed(c, args) -> tuple[float, object]:
    t = time.perf_counter()
    out = jax.block_until_ready(c(*args))
    return time.perf_counter() - t, out


def _same(a, b) -> bool:
    return all(np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True)
               for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def _measure(fun, fargs, repeats: int) -> tuple[dict, object]:
    """One program under both option sets: its row, and its default build's output."""
    built = {k: _compiled(fun, fargs, o) for k, o in OPTIONS.items()}
    runs: dict[str, list[float]] = {k: [] for k in OPTIONS}
    outs = {}
    for _ in range(repeats):
        for k in OPTIONS:
            s, outs[k] = _timed(built[k][0], fargs)
            runs[k].append(s)
    compile_s = {k: built[k][1] for k in OPTIONS}
    run_s = {k: float(np.median(v)) for k, v in runs.items()}
    return {"compile_s": compile_s, "run_s": run_s,
            "compile_ratio": compile_s["physics_options"] / compile_s["default"],
            "run_ratio": run_s["physics_options"] / run_s["default"],
            "bitwise_equal": _same(outs["default"], outs["physics_options"])}, outs["default"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--episodes", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_compilation_cache", False)

    cfg = al.ALConfig(env=EnvConfig(), learner=cacla.CaclaConfig(),
                      phase1_episodes=args.episodes // 2,
                      phase2_episodes=args.episodes - args.episodes // 2)
    hp = al.validate(al.hyper(**TUNED))
    keys = jax.random.split(jax.random.key(0), args.agents)
    train = jax.vmap(al.make_train(cfg), in_axes=(0, None))
    evaluate = al.make_eval(EnvConfig(), al_eval.EVAL_STEPS)

    def episodes(agents, key, tasks):
        def one(agent, task):
            traj = evaluate(agent, key, task, DEFAULT_PARAMS)[1]
            return al_eval.episode_success(traj, task)
        return jax.vmap(jax.vmap(one, in_axes=(None, 0)), in_axes=(0, None))(agents, tasks)

    rows = {}
    rows["AL training"], trained = _measure(train, (keys, hp), args.repeats)
    # the agents just trained are what the episodes run
    rows["greedy episodes, judged"], _ = _measure(
        episodes, (trained[0], jax.random.key(1), al_eval.all_tasks()), args.repeats)
    result = {"options": xla.CPU_PHYSICS_OPTIONS, "agents": args.agents,
              "episodes": args.episodes, "repeats": args.repeats,
              "machine": platform.platform(), "devices": jax.local_device_count(),
              "programs": rows}
    out = HERE.parent / "results/benchmarks/compile_options.json"
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(table(result), end="")
    return 0


def table(result: dict) -> str:
    """The Markdown table of a run (``results/benchmarks/compile_options.json``)."""
    lines = ["| program | compile, XLA defaults (s) | compile, physics options (s) | ratio "
             "| run time ratio | outputs bit-equal |", "|---|---|---|---|---|---|"]
    for name, r in result["programs"].items():
        lines.append(f"| {name} | {r['compile_s']['default']:.1f} | "
                     f"{r['compile_s']['physics_options']:.1f} | {r['compile_ratio']:.2f} | "
                     f"{r['run_ratio']:.2f} | {'yes' if r['bitwise_equal'] else 'no'} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
