"""How hard touch is in this scene: a scripted (not learned) arm touches the targets of the
free family's held-out placements, judged by the action-learning criteria.

Each row sends the arm to a touching pose found by IK for the target (the palm site
``--depth`` below the object's top face; ``placement.touch_pose`` is this pose for 1 cm), from
home, for 100 steps. What varies is how it gets there:

- *gain*: the action is ``gain * (pose - joints)`` (scaled joints, clipped to [-1, 1]) at the
  env's action scale of 1/3: gain 3 jumps the servo target to the pose at once (a fast
  arrival), gain 1 closes a third of the gap per step (a gentle one);
- *via*: the first 40 steps go to the pointing pose (above the target), then down;
- *stop*: no action while the touch bit is on (the arm holds where it first touched).

The result (docs/beyond.md): the pose is right (a gentle arrival touches almost
every target), and a fast arrival shoves the target instead -- the reason the free family
acts with a smaller action scale.

``--action push`` sends the arm instead to the pushing pose of ``placement.push_pose`` (the
map the free family's push reward reaches for: the palm at the target's near face), at the
free family's action scale (``beyond.FREE_TUNED``; 0.2 for the docs' table), gains 3 and
1, judged by push's criterion (the target moved >= 2 cm, no wrong object moved).

Usage:  python benchmarks/scripted_touch.py [--placements 12] [--key 999] [--action push]
Writes results/benchmarks/scripted_<action>.json and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from grounding_jax.core.io import atomic_write_text, library_versions  # noqa: E402
from grounding_jax.paper import al_eval, beyond
from grounding_jax.sim import (
    ik,
    scene,  # noqa: E402
)
from grounding_jax.sim import placement as free  # noqa: E402
from grounding_jax.sim.env import Env, EnvParams, scale_joints  # noqa: E402

#: (gain, via the pointing pose, stop on touch)
ROWS = ((3.0, False, False), (1.0, False, False), (1.0, True, False), (3.0, False, True),
        (1.0, False, True))
PUSH_ROWS = ((3.0, False, False), (1.0, False, False))
STEPS = 100
VIA_STEPS = 40


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--placements", type=int, default=12)
    ap.add_argument("--key", type=int, default=999, help="held-out placements' key")
    ap.add_argument("--depth", type=float, default=0.01, help="metres below the top face")
    ap.add_argument("--action", choices=("touch", "push"), default="touch")
    args = ap.parse_args(argv)
    if args.placements < 1:
        ap.error(f"--placements: must be >= 1, got {args.placements}")
    push = args.action == "push"
    env = Env(beyond.env_config()).with_episode_length(STEPS)
    params = beyond.params() if push else EnvParams()
    batch = al_eval.free_tasks(jax.random.key(args.key), args.placements,
                               actions=(2 if push else 1,))
    n = int(batch.action.shape[0])
    xy = np.asarray(batch.placement)[np.arange(n), np.asarray(batch.position), :2]
    shape = np.argsort(scene.layout_shape_slots(), axis=1)[np.asarray(batch.layout),
                                                          np.asarray(batch.position)]
    top = scene.TABLE_Z + 2 * scene.OBJECT_HALF - args.depth
    pointing = np.stack([np.asarray(free.pointing_pose(jnp.asarray(p))) for p in xy])
    if push:
        touching = np.stack([np.asarray(free.push_pose(jnp.asarray(p))) for p in xy])
    else:
        touching = np.stack([ik.solve(np.array([*p, top]), q)[0]
                             for p, q in zip(xy, pointing, strict=True)])
    goal_touch = scale_joints(jnp.asarray(touching, jnp.float32))
    goal_point = scale_joints(jnp.asarray(pointing, jnp.float32))

    @jax.jit
    def run(gain, via, stop):
        def episode(key, task, touch_q, point_q):
            def body(s, t):
                goal = jnp.where(via & (t < VIA_STEPS), point_q, touch_q)
                a = jnp.clip(gain * (goal - s.obs[:4]), -1.0, 1.0)
                a = jnp.where(stop & (s.obs[4] > 0), 0.0, a)
                s = env.step(s, a, params)
                return s, s
            _, traj = jax.lax.scan(body, env.reset(key, task, params), jnp.arange(STEPS))
            return al_eval.episode_success(traj, task, task_set=env.tasks)
        return jax.vmap(episode)(jax.random.split(jax.random.key(0), n), batch, goal_touch,
                                 goal_point)

    rows = []
    print(f"| arrival ({args.action}) | success | box / cylinder / sphere | touched in the 2nd "
          "half | target moved >= 3 cm | left / middle / right | wrong object moved |\n"
          "|---|---|---|---|---|---|---|")
    slot = np.asarray(batch.position)
    for gain, via, stop in PUSH_ROWS if push else ROWS:
        out = jax.device_get(run(gain, via, stop))
        ok = np.asarray(out["success"])
        row = {"gain": gain, "via_pointing_pose": via, "stop_on_touch": stop,
               "success": float(ok.mean()),
               "by_shape": {s: float(ok[shape == i].mean()) for i, s in enumerate(scene.SHAPES)},
               "touched_late": float(np.mean(out["touched_late"])),
               "moved_3cm": float(np.mean(np.asarray(out["target_moved"]) >= 0.03)),
               "by_slot": {p: float(ok[slot == i].mean()) for i, p in enumerate(scene.POSITIONS)},
               "wrong_moved": float(np.mean(out["wrong_moved"]))}
        rows.append(row)
        how = (f"gain {gain:g}" + (", via the pointing pose" if via else "")
               + (", stops on touch" if stop else ""))
        print(f"| {how} | {row['success']:.0%} | "
              + " / ".join(f"{v:.0%}" for v in row["by_shape"].values())
              + f" | {row['touched_late']:.0%} | {row['moved_3cm']:.0%} | "
              + " / ".join(f"{v:.0%}" for v in row["by_slot"].values())
              + f" | {row['wrong_moved']:.0%} |", flush=True)
    res = {"action": args.action, "placements": args.placements, "key": args.key,
           "depth_m": None if push else args.depth, "action_scale": float(params.action_scale),
           "episodes": n, "rows": rows, "libraries": library_versions()}
    out_dir = pathlib.Path("results/benchmarks")
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / f"scripted_{args.action}.json", json.dumps(res, indent=2) + "\n")
    return res


if __name__ == "__main__":
    main()
