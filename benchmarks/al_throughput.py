"""AL training throughput: the sequential reference vs the vectorized trainer, and the physics
ceiling, all measured in this one process (ratios, not absolute times, are the result).

- sequential reference (``reference_cacla.py``): one agent at a time, NumPy + ``mj_step``;
  its RL steps/s does not depend on how many agents are queued, so it is measured on
  ``--ref-agents`` agents and compared per RL step;
- the vectorized trainer (``al.make_train`` under ``jit(vmap)``), C MuJoCo backend, at each
  batch size, with its default auto-reset loop and with the lockstep loop (the same agents,
  bit for bit), compiled ahead of time (compile time reported apart) and timed on one run;
  where its time goes: physics (inside ``mujoco.rollout``), the trainer's own work
  (networks, updates, env logic: the same trainer timed with pure-JAX stand-in physics) and
  the callback between them (the rest: JAX's transfer to Python and back, our Python around
  ``mujoco.rollout``);
- the ceilings, ``mujoco.rollout`` alone in full batches of the same size:
  *same physics* -- the very scene states and controls the trainer simulated (recorded in an
  untimed second run), replayed batch after batch; *resting arm* -- the home pose held, the
  cheaper physics of a still arm (the ceiling of earlier versions of this table);
- MJX (few episodes on a CPU: it is ~30x slower than C MuJoCo there; the GPU path).

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
import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
import reference_cacla  # noqa: E402
from env_throughput import raw_rollout  # noqa: E402

import grounding_jax as gj  # noqa: E402
from grounding_jax.core.io import library_versions  # noqa: E402
from grounding_jax.learn import al
from grounding_jax.paper import al_experiments
from grounding_jax.sim import (
    physics,
    scene,  # noqa: E402
)
from grounding_jax.sim.env import EnvConfig  # noqa: E402

SUBSTEPS = 10
HP = dict(al_experiments.TUNED)
AL = dict(al_experiments.TUNED_AL)  # the shipped rule and decays, in both trainers


class Meter:
    """Times the process-wide C runner while active: seconds inside ``mujoco.rollout``, seconds
    inside the runner's ``step`` and its calls; with ``record``, keeps a copy of every
    simulated row's (qpos, qvel, ctrl)."""

    def __init__(self, record: bool = False) -> None:
        self.record = record
        self.rollout_s = self.step_s = 0.0
        self.calls = 0
        self.rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def __enter__(self) -> Meter:
        runner = physics.mujoco_runner()
        self._runner, self._pool, self._step = runner, runner.pool, runner.step
        meter, pool, step = self, runner.pool, runner.step

        class TimedPool:
            def rollout(self, *args, **kwargs):
                t = time.perf_counter()
                out = pool.rollout(*args, **kwargs)
                meter.rollout_s += time.perf_counter() - t
                return out

        def timed_step(qpos, qvel, ctrl, substeps, live=None):
            if meter.record:
                rows = slice(None) if live is None else np.ravel(live)
                meter.rows.append(tuple(np.array(np.reshape(a, (-1, np.shape(a)[-1]))[rows])
                                        for a in (qpos, qvel, ctrl)))
            t = time.perf_counter()
            out = step(qpos, qvel, ctrl, substeps, live)
            meter.step_s += time.perf_counter() - t
            meter.calls += 1
            return out

        runner.pool, runner.step = TimedPool(), timed_step
        return self

    def __exit__(self, *exc) -> None:
        self._runner.pool, self._runner.step = self._pool, self._step


class StandInPhysics:
    """While active, envs built for the C backend get pure-JAX stand-in physics (the servo
    target becomes the joints at once; no callback, no MuJoCo): a trainer built then costs
    only its networks, updates and env logic per step."""

    def __enter__(self) -> StandInPhysics:
        idx = scene.index()

        def fns(substeps: int):
            def step(qpos, qvel, ctrl, live=None):
                sens = jnp.zeros(qpos.shape[:-1] + (idx.nsensordata,), jnp.float32)
                return qpos.at[..., idx.arm_qpos].set(ctrl), qvel, sens

            def forward(qpos, qvel, live=None):
                return jnp.zeros(qpos.shape[:-1] + (idx.nsensordata,), jnp.float32)

            return step, forward

        self._fns, physics._mujoco_fns = physics._mujoco_fns, fns
        return self

    def __exit__(self, *exc) -> None:
        physics._mujoco_fns = self._fns


def network_s_per_step(cfg: al.ALConfig, loop: str, keys, hp) -> float:
    """Seconds per batched RL step of the trainer's own work (networks, updates, env logic),
    timed with :class:`StandInPhysics`."""
    with StandInPhysics():
        fn = jax.jit(jax.vmap(al.make_train(cfg, loop), in_axes=(0, None)))
        compiled = fn.lower(keys, hp).compile()
    jax.block_until_ready(compiled(keys, hp))
    t = time.perf_counter()
    _, m = jax.block_until_ready(compiled(keys, hp))
    run_s = time.perf_counter() - t
    steps = np.asarray(m["steps"])
    iterations = (steps.sum(axis=1).max() if loop == "auto_reset"
                  else steps.shape[1] * cfg.env.episode_length)
    return run_s / float(iterations)


def replay_ceiling(rows: list, batch: int) -> float:
    """RL steps/s of ``mujoco.rollout`` alone simulating the recorded rows in full batches."""
    q, v, u = (np.concatenate(a) for a in zip(*rows, strict=True))
    n = (len(q) // batch) * batch
    if n == 0:
        return float("nan")
    runner = physics.mujoco_runner()
    t = time.perf_counter()
    for i in range(0, n, batch):
        runner.step(q[i:i + batch], v[i:i + batch], u[i:i + batch], SUBSTEPS)
    return n / (time.perf_counter() - t)


def bench_reference(agents: int, episodes: int) -> dict:
    total = physics_s = steps = 0.0
    for seed in range(agents):
        _, t = reference_cacla.train(seed, phase1_episodes=episodes, phase2_episodes=0,
                                     substeps=SUBSTEPS, **HP, **AL)
        total, physics_s, steps = (total + t["total_s"], physics_s + t["physics_s"],
                                   steps + t["steps"])
    return {"rl_steps_per_s": steps / total, "physics_share": physics_s / total, "steps": steps}


def bench_trainer(backend: str, batch: int, episodes: int, loop: str) -> dict:
    cfg = al.ALConfig(env=EnvConfig(backend=backend, substeps=SUBSTEPS),
                      phase1_episodes=episodes, phase2_episodes=0)
    fn = jax.jit(jax.vmap(al.make_train(cfg, loop), in_axes=(0, None)))
    keys = jax.random.split(jax.random.key(0), batch)
    hp = al.hyper(**HP, **AL)
    t = time.perf_counter()
    compiled = fn.lower(keys, hp).compile()
    compile_s = time.perf_counter() - t
    native = (physics.mujoco_runner().meter.native
              if backend == "mujoco" and physics.step_handler() == "compiled" else None)
    if native is not None:
        native.reset()
    with Meter() as meter:
        t = time.perf_counter()
        _, m = compiled(keys, hp)
        steps = float(np.asarray(m["steps"]).sum())
        run_s = time.perf_counter() - t
    # RL steps count the steps episodes really took (a wrong move ends one early), as the
    # reference counts them.
    row = {"backend": backend, "loop": loop, "batch": batch, "episodes": episodes,
           "compile_s": compile_s, "run_s": run_s, "rl_steps": steps,
           "rl_steps_per_s": steps / run_s}
    if backend == "mujoco" and native is not None:
        # the compiled handler: its own timer (physics and its threads) and row sample
        meta, _, (state, ctrl, subs) = native.read(samples=True)
        net = meta["calls"] * network_s_per_step(cfg, loop, keys, hp)
        row["handler"] = "compiled"
        row["split"] = {"physics": meta["seconds"] / run_s,
                        "callback": (run_s - meta["seconds"] - net) / run_s,
                        "network_update_env": net / run_s}
        row["physics_calls"] = meta["calls"]
        # the physics alone on the step's sample of the run's rows, in full batches: the
        # faster of mujoco.rollout and the compiled step, best of three (a sample is small)
        row["ceiling_same_physics_rl_steps_per_s"] = physics.ceiling(
            physics.mujoco_runner(), state, ctrl, subs, batch, repeats=3, native=native)
    elif backend == "mujoco":
        net = meter.calls * network_s_per_step(cfg, loop, keys, hp)
        row["handler"] = "python"
        row["split"] = {"physics": meter.rollout_s / run_s,
                        "callback": (run_s - meter.rollout_s - net) / run_s,
                        "network_update_env": net / run_s}
        row["physics_calls"] = meter.calls
        with Meter(record=True) as rec:  # the same run again, untimed: its physics rows
            jax.block_until_ready(compiled(keys, hp))
        row["ceiling_same_physics_rl_steps_per_s"] = replay_ceiling(rec.rows, batch)
        del rec
    print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in row.items()}),
          flush=True)
    return row


def _pct(x: float | None) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.0%}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batches", type=int, nargs="+", default=[8, 32, 256])
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--ref-agents", type=int, default=4)
    ap.add_argument("--loops", nargs="+", default=list(al.LOOPS), choices=al.LOOPS)
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
        resting = raw_rollout(batch, max(3, 20000 // batch)) / SUBSTEPS
        for loop in args.loops:
            row = bench_trainer("mujoco", batch, args.episodes, loop)
            row["ceiling_resting_rl_steps_per_s"] = resting
            rows.append(row)
    if args.mjx_batch:
        rows.append(bench_trainer("mjx", args.mjx_batch, args.mjx_episodes, args.loops[0]))

    for r in rows:
        r["over_reference"] = r["rl_steps_per_s"] / ref["rl_steps_per_s"]
        for kind in ("same_physics", "resting"):
            ceil = r.get(f"ceiling_{kind}_rl_steps_per_s")
            if ceil:
                r[f"of_ceiling_{kind}"] = r["rl_steps_per_s"] / ceil
    print("\n" + table({"reference": {**ref, "episodes": args.episodes}, "rows": rows}), end="")
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"substeps": SUBSTEPS, "cpu_count": os.cpu_count(), "platform": platform.platform(),
            **library_versions(),
            "devices": [str(d) for d in jax.devices()], "hyperparameters": HP}
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps({"meta": meta, "reference": {**ref, "episodes": args.episodes},
                               "rows": rows}, indent=2) + "\n")
    tmp.replace(out)
    print("wrote", out)



def table(result: dict) -> str:
    """The Markdown table of a run (``results/benchmarks/al_throughput.json``)."""
    ref = result["reference"]
    lines = ["| trainer | agents | episodes | RL steps/s | × reference | ceiling: same physics "
             "| % of it | ceiling: resting arm | % of it | time: physics / callback / "
             "networks+env | compile (s) |", "|---|---|---|---|---|---|---|---|---|---|---|",
             f"| sequential reference (NumPy + mj_step) | 1 at a time | "
             f"{ref.get('episodes', '-')} | {ref['rl_steps_per_s']:,.0f} | 1.00 | - | - | - | - | "
             f"{ref['physics_share']:.0%} / - / {1 - ref['physics_share']:.0%} | - |"]
    for r in result["rows"]:
        cells = []
        for kind in ("same_physics", "resting"):
            ceil = r.get(f"ceiling_{kind}_rl_steps_per_s")
            cells.append(f"{ceil:,.0f} | {_pct(r.get(f'of_ceiling_{kind}'))}" if ceil
                         else "- | -")
        split = r.get("split")
        split_txt = " / ".join(_pct(split[k]) for k in split) if split else "-"
        lines.append(f"| vectorized, {r['backend']}, {r['loop']} | {r['batch']} | "
                     f"{r['episodes']} | {r['rl_steps_per_s']:,.0f} | "
                     f"{r['over_reference']:.2f} | {cells[0]} | {cells[1]} | {split_txt} | "
                     f"{r['compile_s']:.1f} |")
    return "\n".join(lines) + "\n"

if __name__ == "__main__":
    jnp.zeros(())  # initialise JAX before timing anything
    main()
