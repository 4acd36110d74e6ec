"""AL training throughput: the sequential reference vs the vectorized trainer, and the physics
ceiling, all measured in this one process (ratios, not absolute times, are the result).

- sequential reference (``reference_cacla.py``): one agent at a time, NumPy + ``mj_step``;
  its RL steps/s does not depend on how many agents are queued, so it is measured on
  ``--ref-agents`` agents and compared per RL step;
- vectorized trainer (``al.make_train`` under ``jit(vmap)``), C MuJoCo backend, at each batch
  size, compiled ahead of time (compile time reported apart) and timed on one run;
- MJX on the CPU (few episodes: it is ~30x slower than C MuJoCo here);
- the ceiling: ``mujoco.rollout`` alone doing the same physics (the same batch, RL-step-sized
  calls of ``substeps`` steps) on all cores.

Usage:  python benchmarks/al_throughput.py [--batches 32 256] [--episodes 50]
Writes results/benchmarks/al_throughput.json and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import sys
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
import reference_cacla  # noqa: E402
from env_throughput import raw_rollout  # noqa: E402

import grounding_jax as gj  # noqa: E402
from grounding_jax import al, al_experiments  # noqa: E402
from grounding_jax.env import EnvConfig  # noqa: E402

SUBSTEPS = 10
HP = dict(al_experiments.TUNED)
AL = dict(al_experiments.TUNED_AL)  # the shipped rule and decays, in both trainers


def bench_reference(agents: int, episodes: int) -> dict:
    total = physics = steps = 0.0
    for seed in range(agents):
        _, t = reference_cacla.train(seed, phase1_episodes=episodes, phase2_episodes=0,
                                     substeps=SUBSTEPS, **HP, **AL)
        total, physics, steps = total + t["total_s"], physics + t["physics_s"], steps + t["steps"]
    return {"rl_steps_per_s": steps / total, "physics_share": physics / total, "steps": steps}


def bench_trainer(backend: str, batch: int, episodes: int) -> dict:
    cfg = al.ALConfig(env=EnvConfig(backend=backend, substeps=SUBSTEPS),
                      phase1_episodes=episodes, phase2_episodes=0)
    fn = jax.jit(jax.vmap(al.make_train(cfg), in_axes=(0, None)))
    keys = jax.random.split(jax.random.key(0), batch)
    hp = al.hyper(**HP, **AL)
    t = time.perf_counter()
    compiled = fn.lower(keys, hp).compile()
    compile_s = time.perf_counter() - t
    t = time.perf_counter()
    _, m = compiled(keys, hp)
    steps = float(np.asarray(m["steps"]).sum())
    run_s = time.perf_counter() - t
    # Episodes cut short by a wrong move have fewer steps: count only the steps taken (the
    # reference counts the same way; finished episodes cost no physics on the C backend).
    row = {"backend": backend, "batch": batch, "episodes": episodes, "compile_s": compile_s,
           "run_s": run_s, "rl_steps_per_s": steps / run_s,
           "lockstep_slots_per_s": batch * episodes * cfg.env.episode_length / run_s}
    print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in row.items()}),
          flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batches", type=int, nargs="+", default=[32, 256])
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--ref-agents", type=int, default=4)
    ap.add_argument("--mjx-batch", type=int, default=32)
    ap.add_argument("--mjx-episodes", type=int, default=2)
    ap.add_argument("--out", default=str(HERE.parent / "results" / "benchmarks" /
                                         "al_throughput.json"))
    args = ap.parse_args()
    gj.enable_compilation_cache()

    ref = bench_reference(args.ref_agents, args.episodes)
    print(f"sequential reference: {ref['rl_steps_per_s']:,.0f} RL steps/s "
          f"({ref['physics_share']:.0%} of its time in mj_step)", flush=True)
    rows = []
    for batch in args.batches:
        row = bench_trainer("mujoco", batch, args.episodes)
        calls = max(3, 20000 // batch)
        row["ceiling_rl_steps_per_s"] = raw_rollout(batch, calls) / SUBSTEPS
        rows.append(row)
    if args.mjx_batch:
        rows.append(bench_trainer("mjx", args.mjx_batch, args.mjx_episodes))

    print("\n| trainer | agents | episodes | RL steps/s | x reference | ceiling (rollout alone) "
          "| % of ceiling | compile (s) |")
    print("|---|---|---|---|---|---|---|---|")
    print(f"| sequential reference (NumPy + mj_step) | 1 at a time | {args.episodes} | "
          f"{ref['rl_steps_per_s']:,.0f} | 1.00 | - | - | - |")
    for r in rows:
        ceil = r.get("ceiling_rl_steps_per_s")
        r["over_reference"] = r["rl_steps_per_s"] / ref["rl_steps_per_s"]
        if ceil:
            r["of_ceiling"] = r["rl_steps_per_s"] / ceil
        ceil_txt = f"{ceil:,.0f} | {r['of_ceiling']:.0%}" if ceil else "- | -"
        print(f"| vectorized, {r['backend']} | {r['batch']} | {r['episodes']} | "
              f"{r['rl_steps_per_s']:,.0f} | {r['over_reference']:.2f} | {ceil_txt} | "
              f"{r['compile_s']:.1f} |")
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"substeps": SUBSTEPS, "cpu_count": os.cpu_count(), "platform": platform.platform(),
            "jax": jax.__version__, "mujoco": mujoco.__version__,
            "devices": [str(d) for d in jax.devices()], "hyperparameters": HP}
    out.write_text(json.dumps({"meta": meta, "reference": ref, "rows": rows}, indent=2) + "\n")
    print("wrote", out)


if __name__ == "__main__":
    jnp.zeros(())  # initialise JAX before timing anything
    main()
