"""Env throughput: backend x batch -> RL steps/s and physics steps/s, compile times, baselines.

Everything is measured in this one process, so the ratios are meaningful on a noisy machine:
- raw ``mujoco.mj_step`` in a Python loop (one scene, one thread);
- ``mujoco.rollout`` alone (persistent pool, all cores) doing the same physics as the C
  backend's RL steps at each batch size: the ceiling for the C backend;
- the env (``jit(vmap(step))`` under ``lax.scan``) on each backend and batch size;
- compile time of that function cold (empty persistent cache) and warm (persistent cache
  filled, in-memory caches cleared).

Usage:  python benchmarks/env_throughput.py [--batches 1 32 256] [--backends mujoco mjx]
Writes results/benchmarks/env_throughput.json and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import sys
import tempfile
import time

# A private, empty persistent cache so "cold" really is cold; set before JAX is imported.
_CACHE = tempfile.mkdtemp(prefix="gj_bench_cache_")
os.environ["GROUNDING_JAX_CACHE"] = _CACHE

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))
import grounding_jax as gj  # noqa: E402
from grounding_jax.core.io import library_versions  # noqa: E402
from grounding_jax.sim import (
    physics,
    scene,  # noqa: E402
)

ROOT = pathlib.Path(__file__).resolve().parent.parent
SUBSTEPS = 10


def raw_mj_step(n: int = 20000) -> float:
    """Physics steps/s of ``mj_step`` in a plain Python loop."""
    m = scene.model()
    d = mujoco.MjData(m)
    d.qpos[:] = scene.home_qpos()
    d.ctrl[:] = np.radians(scene.HOME_POSE_DEG)
    for _ in range(200):
        mujoco.mj_step(m, d)
    t = time.perf_counter()
    for _ in range(n):
        mujoco.mj_step(m, d)
    return n / (time.perf_counter() - t)


def raw_rollout(batch: int, calls: int) -> float:
    """Physics steps/s of ``mujoco.rollout`` alone (the runner's pool), RL-step-sized calls."""
    runner = physics.mujoco_runner()
    m = runner.model
    qpos = np.tile(scene.home_qpos(), (batch, 1)).astype(np.float32)
    qvel = np.zeros((batch, m.nv), np.float32)
    ctrl = np.tile(np.radians(scene.HOME_POSE_DEG), (batch, 1)).astype(np.float32)
    runner.step(qpos, qvel, ctrl, SUBSTEPS)
    t = time.perf_counter()
    for _ in range(calls):
        qpos, qvel, _ = runner.step(qpos, qvel, ctrl, SUBSTEPS)
    return calls * batch * SUBSTEPS / (time.perf_counter() - t)


def make_fn(env: gj.Env, steps: int):
    """jit(vmap) of ``steps`` RL steps under lax.scan with a fixed smooth action pattern."""

    def run(state):
        def body(s, t):
            a = 0.3 * jnp.sin(0.2 * t + jnp.arange(4.0))
            return env.step(s, a), None

        return jax.lax.scan(body, state, jnp.arange(steps, dtype=jnp.float32))[0]

    return jax.jit(jax.vmap(run))


def bench_env(backend: str, batch: int, steps: int, repeats: int) -> dict:
    env = gj.make_env(backend, substeps=SUBSTEPS)
    keys = jax.random.split(jax.random.key(0), batch)
    tasks = gj.Task(action=jnp.zeros(batch, jnp.int32), position=jnp.arange(batch) % 3,
                    layout=jnp.arange(batch, dtype=jnp.int32) % 36)
    state = jax.jit(jax.vmap(env.reset))(keys, tasks)
    jax.block_until_ready(state)

    def build():
        fn = make_fn(env, steps)
        t = time.perf_counter()
        lowered = fn.lower(state)  # tracing + lowering: redone in every process
        t_lower = time.perf_counter() - t
        t = time.perf_counter()
        compiled = lowered.compile()  # XLA compile: what the persistent cache saves
        return compiled, t_lower, time.perf_counter() - t

    compiled, lower_cold, xla_cold = build()
    jax.clear_caches()  # drop in-memory caches; the persistent (disk) cache stays
    compiled, lower_warm, xla_warm = build()
    cold, warm = lower_cold + xla_cold, lower_warm + xla_warm

    jax.block_until_ready(compiled(state))  # warm-up run
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(compiled(state))
        best = min(best, time.perf_counter() - t)
    rl = batch * steps / best
    return {"backend": backend, "batch": batch, "rl_steps_per_s": rl,
            "physics_steps_per_s": rl * SUBSTEPS, "compile_cold_s": cold,
            "compile_warm_s": warm, "warm_over_cold": warm / cold,
            "xla_compile_cold_s": xla_cold, "xla_compile_warm_s": xla_warm,
            "xla_warm_over_cold": xla_warm / xla_cold, "trace_lower_s": lower_warm}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 32, 256])
    ap.add_argument("--backends", nargs="+", default=["mujoco", "mjx"],
                    choices=physics.BACKENDS)
    ap.add_argument("--steps", type=int, default=20, help="RL steps per timed call (C backend)")
    ap.add_argument("--mjx-steps", type=int, default=3, help="RL steps per timed call (MJX)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--mjx-cpu-256", action="store_true",
                    help="also run MJX at batch 256 on a CPU (hung idle on 2-core CPUs here)")
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks" / "env_throughput.json"))
    args = ap.parse_args()
    gj.enable_compilation_cache()

    mj = raw_mj_step()
    print(f"raw mj_step loop: {mj:,.0f} physics steps/s (1 thread)")
    rows = []
    for backend in args.backends:
        for batch in args.batches:
            on_cpu = jax.default_backend() == "cpu"
            if backend == "mjx" and batch >= 256 and on_cpu and not args.mjx_cpu_256:
                print(f"skipped: mjx batch {batch} on CPU (see --mjx-cpu-256)", flush=True)
                rows.append({"backend": backend, "batch": batch, "skipped":
                             "MJX at batch >= 256 hung idle on this 2-core CPU"})
                continue
            steps = args.steps if backend == "mujoco" else args.mjx_steps
            row = bench_env(backend, batch, steps, args.repeats)
            if backend == "mujoco":
                ceiling = raw_rollout(batch, max(3, 2000 // batch))
                row["rollout_alone_physics_steps_per_s"] = ceiling
                row["cost_over_raw_physics"] = ceiling / row["physics_steps_per_s"]
            rows.append(row)
            print(json.dumps({k: round(v, 3) if isinstance(v, float) else v
                              for k, v in row.items()}), flush=True)

    print("\n" + table({"rows": rows}), end="")
    print(f"\nraw mj_step loop: {mj:,.0f} physics steps/s")
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"substeps": SUBSTEPS, "cpu_count": os.cpu_count(), "platform": platform.platform(),
            **library_versions(),
            "devices": [str(d) for d in jax.devices()]}
    out.write_text(json.dumps({"meta": meta, "raw_mj_step_per_s": mj, "rows": rows},
                              indent=2) + "\n")
    print("wrote", out)



def table(result: dict) -> str:
    """The Markdown table of a run (``results/benchmarks/env_throughput.json``)."""
    lines = ["| backend | batch | RL steps/s | physics steps/s | rollout alone | RL-step cost / "
             "raw physics | compile cold (s) | compile warm (s) | warm/cold | XLA-only "
             "warm/cold |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        if "skipped" in r:
            lines.append(f"| {r['backend']} | {r['batch']} | skipped: {r['skipped']} ||||||||")
            continue
        alone = r.get("rollout_alone_physics_steps_per_s")
        over = r.get("cost_over_raw_physics")
        lines.append(f"| {r['backend']} | {r['batch']} | {r['rl_steps_per_s']:,.0f} | "
                     f"{r['physics_steps_per_s']:,.0f} | {f'{alone:,.0f}' if alone else '-'} | "
                     f"{f'{over:.2f}x' if over else '-'} | {r['compile_cold_s']:.1f} | "
                     f"{r['compile_warm_s']:.2f} | {r['warm_over_cold']:.2f} | "
                     f"{r['xla_warm_over_cold']:.2f} |")
    return "\n".join(lines) + "\n"

if __name__ == "__main__":
    main()
