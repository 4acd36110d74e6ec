"""Tuning runs of the free family's action learner (docs/beyond.md, tuning table):
agents from a tuning key train on random placements with the shipped settings and schedule,
then are judged greedily on every slot of held-out placements from another key.

The keys are never train.py's (0): agents from ``--key`` (11 in the docs' table), held-out
placements from ``--eval-key`` (999). ``--push-reward pose`` trains push to reach for the
pushing pose (minus the L1 distance to ``placement.push_pose``, as touch reaches for its
touching pose) instead of the shipped reward (minus the palm's distance to the target's
centre, the paper's), to compare the two on the same agents.

``--no-hand`` hides from the actor where its palm is relative to the target (the ``"free"``
task set; shipped: ``"free_hand"``, ``TaskSet.hand_obs``); ``--hand`` shows it;
``--hand-scale 0.05`` gives its units another length scale (shipped: ``tasks.HAND_SCALE``).
``--heads 0,1,1`` lets touch and push share a network (shipped: ``0,1,2``, one per
action); ``--checkpoints 1000,1500`` also judges the agents at those episodes (the learning
curve of one run).

Usage:  python benchmarks/free_tuning.py [--agents 8] [--phase1 1000] [--phase2 1000]
        [--placements 12] [--key 11] [--eval-key 999] [--push-reward pose|centre]
        [--heads 0,1,2] [--checkpoints 1000] [--set FIELD=VALUE] [--hand | --no-hand]
        [--hand-scale METRES] [--actor-hidden N] [--critic-hidden N] [--var] [--tag NAME]
Prints the median agent's success per action (min-max over agents), by slot, and the share of
episodes that moved a wrong object, at each checkpoint and at the end; writes
results/tuning/free_tuning_<tag>.json (tag: the push reward unless given).
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
from grounding_jax.core.io import atomic_write_text, library_versions  # noqa: E402
from grounding_jax.learn import al
from grounding_jax.paper import al_eval, beyond
from grounding_jax.sim import (
    placement,
    tasks,  # noqa: E402
)
from grounding_jax.sim.env import Env  # noqa: E402


def _pose_push(t, params):
    """Push reaches for its pushing pose, with the free family's penalty for touching a
    neighbour."""
    return -t["push_l1"] + tasks._avoid(t, params)


POSE = tasks.register(dataclasses.replace(
    tasks.FREE, name="free_pose_push",
    actions=(*tasks.FREE.actions[:2], tasks.Action("push", _pose_push, tasks.FREE.actions[2]
                                                   .success))))


def _ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, got {text!r}") from None


def _report(table: dict, wrong: dict, episode: int) -> None:
    for a in tasks.FREE.action_names:
        lo, *_, hi = table["spread"][a]
        slots = " / ".join(f"{table['by_task'][f'{a} {p}']:.0%}" for p in tasks.POSITIONS)
        print(f"episode {episode} {a}: median agent {table['by_action'][a]:.0%} "
              f"({lo:.0%}-{hi:.0%}); by slot (pooled, left / middle / right) {slots}; wrong "
              f"object moved in {wrong[a]:.0%} of the episodes", flush=True)


#: where touch's episodes are pooled by the target's place: x (toward / away from the robot)
#: and y (left to right) split at these values (metres; the region: placement.REACH_X/_Y)
WHERE_X = (-0.235,)
WHERE_Y = (0.16, 0.23)


def _touch_where(ok: np.ndarray, late: np.ndarray, moved: np.ndarray, xy: np.ndarray) -> dict:
    """Touch's success and failures pooled over agents by where the target stands (cells of
    :data:`WHERE_X` x :data:`WHERE_Y`, named ``near|far y lo-hi``): episodes, success, never
    touched in the second half, target moved >= 3 cm. ``ok``, ``late`` (touched in the second
    half) and ``moved`` (>= 3 cm) are touch's episodes, ``[..., touch tasks]``; ``xy`` is
    their targets' coordinates ``[touch tasks, 2]``."""
    ok, late, moved = (np.reshape(a, (-1, len(xy))) for a in (ok, late, moved))
    ix = np.digitize(xy[:, 0], WHERE_X)  # 0: x below the split (far from the robot)
    iy = np.digitize(xy[:, 1], WHERE_Y)
    ys = (placement.REACH_Y[0], *WHERE_Y, placement.REACH_Y[1])
    cells = {}
    for i, xname in enumerate(("far", "near")):
        for j in range(len(ys) - 1):
            m = (ix == i) & (iy == j)
            if not m.any():
                continue
            cells[f"{xname} y {ys[j]:.2f}-{ys[j + 1]:.2f}"] = {
                "episodes": int(m.sum() * ok.shape[0]), "success": float(ok[:, m].mean()),
                "never_touched_late": float((~late[:, m]).mean()),
                "target_moved_3cm": float(moved[:, m].mean())}
    return cells


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--agents", type=int, default=8)
    ap.add_argument("--phase1", type=int, default=1000)
    ap.add_argument("--phase2", type=int, default=1000)
    ap.add_argument("--placements", type=int, default=12)
    ap.add_argument("--key", type=int, default=11, help="the agents' tuning key")
    ap.add_argument("--eval-key", type=int, default=999, help="held-out placements' key")
    ap.add_argument("--push-reward", choices=("centre", "pose"), default="centre")
    ap.add_argument("--heads", type=_ints, default=beyond.FREE_LEARNER.heads,
                    help="which actions share a network (point,touch,push)")
    ap.add_argument("--checkpoints", type=_ints, default=(),
                    help="episodes at which the agents are also judged")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="a learner / env / trainer field changed from beyond.FREE_TUNED "
                    "(e.g. touch_bonus=0.1); repeatable")
    seen = ap.add_mutually_exclusive_group()
    seen.add_argument("--hand", dest="hand", action="store_true", default=None,
                      help="the actor also sees the palm's offset to the target (hand_obs; "
                      "the shipped family's)")
    seen.add_argument("--no-hand", dest="hand", action="store_false",
                      help="the actor does not see its palm (the 'free' task set)")
    ap.add_argument("--actor-hidden", type=int, default=None, metavar="N",
                    help="each actor's hidden units (shipped: beyond.FREE_LEARNER's)")
    ap.add_argument("--critic-hidden", type=int, default=None, metavar="N",
                    help="each critic's hidden units (shipped: beyond.FREE_LEARNER's)")
    ap.add_argument("--var", action="store_true",
                    help="CACLA+Var: repeat the actor's update by how large delta was "
                    "(shipped: off)")
    ap.add_argument("--hand-scale", type=float, default=None, metavar="METRES",
                    help="the hand units' length scale (shipped: tasks.HAND_SCALE); with "
                    "the hand units only")
    ap.add_argument("--tag", default=None, help="the result file's name (default: the push "
                    "reward)")
    args = ap.parse_args(argv)
    for name in ("agents", "phase1", "placements"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')}: must be >= 1, got {getattr(args, name)}")
    changed = {}
    for item in args.set:
        name, eq, value = item.partition("=")
        try:
            changed[name.strip()] = float(value)
        except ValueError:
            ap.error(f"--set: expected FIELD=NUMBER, got {item!r}")
        if not eq:
            ap.error(f"--set: expected FIELD=NUMBER, got {item!r}")
    try:
        hp = al.validate(al.hyper(**{**beyond.FREE_TUNED, **changed}))
    except ValueError as e:
        ap.error(f"--set: {e}")
    gj.enable_compilation_cache()
    cfg = beyond.config(args.phase1, args.phase2)
    hand = tasks.get(cfg.learner.task_set).hand_obs if args.hand is None else args.hand
    task_set = tasks.FREE_HAND.name if hand else tasks.FREE.name
    if args.push_reward == "pose":
        task_set = POSE.name if not hand else tasks.register(dataclasses.replace(
            POSE, name=f"{POSE.name}_hand", hand_obs=True)).name
    if args.hand_scale is not None:
        if not hand:
            ap.error("--hand-scale: the actor does not see its palm (--no-hand)")
        try:
            task_set = tasks.register(dataclasses.replace(
                tasks.get(task_set), name=f"{task_set}_s{args.hand_scale:g}",
                hand_scale=args.hand_scale)).name
        except ValueError as e:
            ap.error(f"--hand-scale: {e}")
    try:
        learner = dataclasses.replace(cfg.learner, task_set=task_set, heads=args.heads)
    except ValueError as e:
        ap.error(f"--heads: {e}")
    for name in ("actor_hidden", "critic_hidden"):
        if getattr(args, name) is not None:
            try:
                learner = dataclasses.replace(learner, **{name: getattr(args, name)})
            except ValueError as e:
                ap.error(f"--{name.replace('_', '-')}: {e}")
    if args.var:
        learner = dataclasses.replace(learner, var=True)
    cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, task_set=task_set),
                              learner=learner)
    bad = [c for c in args.checkpoints if not 0 < c < cfg.episodes]
    if bad:
        ap.error(f"--checkpoints: must lie in 1..{cfg.episodes - 1}, got {bad}")
    env = Env(cfg.env)
    # beyond.make_success's judge, with its tasks kept here for where the targets stand
    batch = al_eval.free_tasks(jax.random.key(args.eval_key), args.placements)
    judge = al_eval.make_success(env, batch=batch)
    target_xy = np.asarray(batch.placement)[np.arange(len(batch.position)),
                                            np.asarray(batch.position), :2]
    curve: dict[str, dict] = {}

    def measure(episode: int, agents, _metrics) -> None:
        out = jax.device_get(judge(agents, jax.random.key(0), hp.env))
        table = al_eval.success_table(out)
        act = np.asarray(out["action"])
        wrong = {a: float(np.asarray(out["wrong_moved"])[..., act == i].mean())
                 for i, a in enumerate(tasks.FREE.action_names)}
        touch = act == tasks.FREE.action_names.index("touch")
        late = np.asarray(out["touched_late"])[..., touch] > 0
        moved = np.asarray(out["target_moved"])[..., touch] >= tasks.TOUCH_MOVED
        fails = {"never_touched_late": float((~late).mean()),
                 "target_moved_3cm": float(moved.mean())}
        curve[str(episode)] = {"by_action": table["by_action"], "spread": table["spread"],
                               "by_task": table["by_task"], "wrong_moved": wrong,
                               "touch_failures": fails,
                               "touch_where": _touch_where(
                                   np.asarray(out["success"])[..., touch] > 0, late, moved,
                                   target_xy[touch])}
        _report(table, wrong, episode)
        print(f"episode {episode} touch episodes (pooled): never touched in the second half "
              f"{fails['never_touched_late']:.0%}, target moved >= 3 cm "
              f"{fails['target_moved_3cm']:.0%}", flush=True)
        for cell, c in curve[str(episode)]["touch_where"].items():
            print(f"episode {episode} touch, target {cell}: {c['success']:.0%} of "
                  f"{c['episodes']} (never touched late {c['never_touched_late']:.0%}, moved "
                  f">= 3 cm {c['target_moved_3cm']:.0%})", flush=True)

    t = time.perf_counter()
    al.train_in_chunks(cfg, jax.random.split(jax.random.key(args.key), args.agents), hp,
                       sorted({*args.checkpoints, cfg.episodes}), measure)
    train_s = time.perf_counter() - t
    final = curve[str(cfg.episodes)]
    tag = args.tag or args.push_reward
    touch_map = placement.touch_map()  # the map in the package's assets, as trained on
    res = {**vars(args), "changed": changed, "heads": list(args.heads),
           "checkpoints": list(args.checkpoints), "train_s": train_s, **final, "curve": curve,
           # the touching pose's depth into the target's top
           "touch_depth_m": float(touch_map["depth"]),
           # 0: solved node by node, as shipped; > 0: make_touch_map.py --smooth's weight
           "touch_smooth_weight": float(touch_map.get("smooth_weight", 0.0)),
           # > 0: make_touch_map.py --reach-shift's most (metres across the top face)
           "touch_reach_shift": float(touch_map.get("reach_shift", 0.0)),
           "libraries": library_versions()}
    print(f"training and judging {train_s:.0f} s")
    out_dir = pathlib.Path("results/tuning")
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_dir / f"free_tuning_{tag}.json", json.dumps(res, indent=2) + "\n")
    return res


if __name__ == "__main__":
    main()
