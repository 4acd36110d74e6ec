"""The saved robot as a user meets it: ``grounding_jax.load(...).perform(action, word, layout,
placement="random", key=...)`` -- render, the TL's coordinates, act, name -- on placements drawn
from a key that neither training nor train.py's evaluations used (the layouts cycle through all
36; training draws every layout), judged with the action-learning success rule
(``al_experiments.episode_success``).

With ``--all-agents`` every agent train.py trained (saved beside the robot's own,
``Robot.with_free_agent``) performs the same episodes too: the median agent and the spread,
through the user's path.

Usage:  python benchmarks/free_perform_check.py [--modules results/paper/modules]
        [--episodes 36] [--key 500] [--all-agents]
Prints each action's success, how often the namer named action and target, and the TL's
error; writes results/benchmarks/free_perform_check.json.
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
from grounding_jax.core.io import atomic_write_text, library_versions  # noqa: E402
from grounding_jax.paper import al_eval
from grounding_jax.sim import tasks  # noqa: E402

#: the layouts the episodes cycle through: all 36
LAYOUTS = tuple(range(35, -1, -1))


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--modules", default="results/paper/modules")
    ap.add_argument("--episodes", type=int, default=36)
    ap.add_argument("--key", type=int, default=500, help="the placements' and resets' key")
    ap.add_argument("--all-agents", action="store_true",
                    help="every saved agent performs the same episodes too")
    args = ap.parse_args(argv)
    if args.episodes < 1:
        ap.error(f"--episodes: must be >= 1, got {args.episodes}")
    gj.enable_compilation_cache()
    robot = gj.load(args.modules)
    if robot.free is None:
        ap.error(f"--modules: {args.modules} holds no free-family robot")
    if args.all_agents and robot.free.n_agents == 0:
        ap.error(f"--all-agents: {args.modules} holds only the robot's own agent")
    ts = tasks.get(robot.free.env_config.task_set)
    rows = episodes(robot, ts, args.key, args.episodes)
    res = {"modules": args.modules, "episodes": args.episodes, "key": args.key,
           "task_set": ts.name, "saved_agent": robot.free.saved_agent, "rows": rows,
           "libraries": library_versions()}
    for a in ts.action_names:
        mine = [r for r in rows if r["action"] == a]
        res[f"success_{a}"] = float(np.mean([r["success"] for r in mine]))
        print(f"{a}: {sum(r['success'] for r in mine)} of {len(mine)} succeeded", flush=True)
    named = [r["named"] == [r["action"], r["word"]] for r in rows if r["named"]]
    res["named_right"] = float(np.mean(named)) if named else None
    err = np.array([r["tl_error_cm"] for r in rows])
    res["tl_error_cm_median"], res["tl_error_cm_max"] = float(np.median(err)), float(err.max())
    print(f"named action and target right: {sum(named)} of {len(named)}; TL error median "
          f"{res['tl_error_cm_median']:.2f} cm, max {res['tl_error_cm_max']:.2f} cm")
    if args.all_agents:
        per = {a: [] for a in ts.action_names}
        for i in range(robot.free.n_agents):
            mine = episodes(robot.with_free_agent(i), ts, args.key, args.episodes)
            for a in ts.action_names:
                per[a].append(float(np.mean([r["success"] for r in mine if r["action"] == a])))
            print(f"agent {i}: " + ", ".join(f"{a} {per[a][-1]:.0%}" for a in per), flush=True)
        res["per_agent"] = per
        # the median agent per action (the lower middle of an even count, as success_table)
        res["median_agent_success"] = {a: float(np.sort(v)[(len(v) - 1) // 2])
                                       for a, v in per.items()}
        print("median agent: " + ", ".join(
            f"{a} {v:.0%} ({min(per[a]):.0%}-{max(per[a]):.0%})"
            for a, v in res["median_agent_success"].items()))
    out_dir = pathlib.Path("results/benchmarks")
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / "free_perform_check.json", json.dumps(res, indent=2) + "\n")
    return res


def episodes(robot, ts, key: int, n: int) -> list[dict]:
    """``n`` episodes of ``robot.perform`` (actions, words and layouts cycling), judged."""
    rows = []
    for i, k in enumerate(jax.random.split(jax.random.key(key), n)):
        action = ts.action_names[i % ts.n_actions]
        word = tasks.TARGET_WORDS[(i // ts.n_actions) % len(tasks.TARGET_WORDS)]
        layout = LAYOUTS[i % len(LAYOUTS)]
        out = robot.perform(action, word, layout, placement="random", key=k)
        task = gj.make_task(action, word, layout, ts.name, placement=out["placement"])
        judged = jax.device_get(al_eval.episode_success(out["trajectory"], task, task_set=ts))
        rows.append({"action": action, "word": word, "layout": layout,
                     "success": bool(judged["success"]),
                     "named": list(out["named"]) if out["named"] else None,
                     "tl_error_cm": float(100 * np.linalg.norm(out["xy"] - out["true_xy"]))})
    return rows


if __name__ == "__main__":
    main()
