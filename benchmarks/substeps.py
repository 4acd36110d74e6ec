"""Physics substeps per RL step: is fewer still faithful? Measured at each count in one process:

- servo settling: from home, one RL step commanding +1 (times ``action_scale``) on every
  joint; the share of the commanded change reached after that step, per joint (the next
  step's command is relative to where the arm is, so what is not reached is lost);
- push outcomes: the scripted push of each position (``scripted.push_waypoints``): how far
  the target and the other objects moved;
- the trained robot: ``--seeds`` agents trained with the shipped settings at each count (the
  same key; 150 + ``--phase2`` episodes), then the success table from home, random-start
  point and the goal switch (median agent, and the spread over agents);
- the physics time of one RL step (``mujoco.rollout`` alone, full batch of 32).

Usage:  python benchmarks/substeps.py [--substeps 5 8 10] [--seeds 8] [--key 100] [--phase2 300]
Writes results/benchmarks/substeps.json and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
import grounding_jax as gj  # noqa: E402
from grounding_jax.paper import al_experiments
from grounding_jax.sim import (
    physics,
    rollout,
    scene,
    scripted,  # noqa: E402
)
from grounding_jax.sim.env import EnvConfig, scale_joints  # noqa: E402


def settling(substeps: int) -> list[float]:
    """Share of a +1 command (all joints) reached after one RL step, per joint."""
    env = gj.make_env(substeps=substeps)
    s0 = env.reset(jax.random.key(0), gj.make_task("point", 0, 0))
    s1 = env.step(s0, jnp.ones(4))
    q0, q1 = (scale_joints(s.qpos[env.arm_qpos]) for s in (s0, s1))
    cmd = scale_joints(s1.info["ctrl"]) - q0  # the commanded change after clipping
    return [float(x) for x in (q1 - q0) / cmd]


def pushes(substeps: int) -> list[dict]:
    """The scripted push of each position: target and other objects' displacement (cm)."""
    env = gj.make_env(substeps=substeps)
    rows = []
    for p, name in enumerate(scene.POSITIONS):
        w = scripted.push_waypoints(p)
        first, traj = jax.device_get(rollout.run_episode(
            env, jax.random.key(0), gj.make_task("push", p, 0),
            lambda s, w=w: scripted.tracking_action(w, s.step, s.obs)))
        moved = np.linalg.norm(traj.qpos[-1][scene.index().object_qpos[:, :3]]
                               - first.object_start, axis=1)
        rows.append({"position": name, "target_cm": 100 * float(traj.metrics["target_moved"][-1]),
                     "others_cm": 100 * float(np.sort(moved)[:2].max())})
    return rows


def physics_ms(substeps: int, batch: int = 32, calls: int = 300) -> float:
    runner = physics.mujoco_runner()
    q = np.tile(scene.home_qpos(), (batch, 1)).astype(np.float32)
    v = np.zeros((batch, runner.model.nv), np.float32)
    u = np.tile(np.radians(scene.HOME_POSE_DEG), (batch, 1)).astype(np.float32)
    runner.step(q, v, u, substeps)
    t = time.perf_counter()
    for _ in range(calls):
        runner.step(q, v, u, substeps)
    return 1000 * (time.perf_counter() - t) / calls


def trained(substeps: int, seeds: int, key: int, phase2: int) -> dict:
    with tempfile.TemporaryDirectory() as out:
        res, _ = al_experiments.run(jax.random.key(key), out, seeds, 150, phase2, 0,
                                    env_config=EnvConfig(substeps=substeps))
    final = res["final"]
    return {"home": final["home"], "random_starts": final["random_starts"],
            "switch": final["switch"], "train_s": res["train_s"], "rl_steps": res["rl_steps"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--substeps", type=int, nargs="+", default=[5, 8, 10])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--key", type=int, default=100, help="training key (a tuning key)")
    ap.add_argument("--phase2", type=int, default=300,
                    help="phase-2 episodes (the paper: 300; the shipped robot: 1050)")
    ap.add_argument("--out", default=str(HERE.parent / "results" / "benchmarks" /
                                         "substeps.json"))
    args = ap.parse_args()
    gj.enable_compilation_cache()
    rows = []
    for n in args.substeps:
        row = {"substeps": n, "settling": settling(n), "pushes": pushes(n),
               "physics_ms_batch32": physics_ms(n)}
        if args.seeds:
            row["trained"] = trained(n, args.seeds, args.key, args.phase2)
        rows.append(row)
        print(json.dumps(row), flush=True)
    print("\n| substeps | RL step | physics ms (32 scenes) | servo reached (joints) | push: target "
          "moved (cm, L/M/R) | others (cm, max) | point | touch | push | random-start point "
          "| switch |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        t = r.get("trained")
        succ = ("- | - | - | - | -" if t is None else
                " | ".join(f"{t['home']['by_action'][a]:.0%}" for a in ("point", "touch", "push"))
                + f" | {t['random_starts']['by_action']['point']:.0%} | "
                  f"{t['switch']['overall']:.0%}")
        target = " / ".join(f"{p['target_cm']:.1f}" for p in r["pushes"])
        print(f"| {r['substeps']} | {5 * r['substeps']} ms | {r['physics_ms_batch32']:.2f} | "
              f"{min(r['settling']):.0%}-{max(r['settling']):.0%} | {target} | "
              f"{max(p['others_cm'] for p in r['pushes']):.2f} | {succ} |")
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"key": args.key, "seeds": args.seeds,
                               "episodes": 150 + args.phase2, "rows": rows}, indent=1) + "\n")
    print("wrote", out)


if __name__ == "__main__":
    main()
