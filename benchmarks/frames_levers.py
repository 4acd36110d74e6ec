"""The levers of naming from frames, measured: camera (one or both), the starts of the robot's
own episodes, the namer's size and its ensemble.

The paper family's saved robot renders its own episodes (the ``watch_frames`` stage's
`own_features`), the run's other agents' episodes are rendered at `grounding_jax.frames`'
size, every step, and each variant of the namer is fitted on the first and judged on the
second (action and target named right). Each episode is rendered from both cameras once;
a single camera's features are their half of the joined ones (`seeing.features` reads each
view alone). Writes ``results/tuning/frames_levers.json``.

Usage:  python benchmarks/frames_levers.py [--modules results/paper/modules] [--key 31]
        [--own 108] [--others 63]
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

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from grounding_jax.core.io import atomic_write_text  # noqa: E402
from grounding_jax.paper.stages import watch_frames as W  # noqa: E402
from grounding_jax.robot import seeing, trained  # noqa: E402
from grounding_jax.sim import render, scene  # noqa: E402

#: the namer variants: (hidden, l2, members)
NAMERS = {"one network (8 hidden)": (8, 1e-3, 1), "one network (16 hidden)": (16, 1e-3, 1),
          "one network, l2 0.01": (8, 1e-2, 1), "ensemble of 7 (shipped)": (8, 1e-3, 7),
          "ensemble of 7 (16 hidden, l2 0.01)": (16, 1e-2, 7)}


def others_features(key: jax.Array, robot, n: int, camera: str) -> tuple[np.ndarray, ...]:
    """The other agents' episodes as the stage judges them, read from their frames."""
    feats, acts, cols = [], [], []
    for _, cmd, ep, colour in W.other_episodes(key, robot, "paper", n):
        feats.append(seeing.features(render.frames(ep, camera=camera), camera))
        acts.append(cmd[0])
        cols.append(colour)
    return np.stack(feats), np.asarray(acts), np.asarray(cols)


def view(data: tuple[np.ndarray, ...], camera: str) -> tuple[np.ndarray, ...]:
    """(features, actions, colours) of frames of both cameras, cut to ``camera``'s view
    (``"both"``: all; ``"observer"`` the first half of each object's features, ``"eye"`` the
    second) -- what `seeing.features` returns for that camera's frames alone."""
    feats, *rest = data
    n = seeing.N_FEATURES
    if feats.shape[-1] == n:
        return data
    return (feats[..., {"observer": slice(0, n), "eye": slice(n, None),
                        "both": slice(None)}[camera]], *rest)


def table(result: dict) -> str:
    """The Markdown table of a run (``results/tuning/frames_levers.json``): per set of own
    episodes and namer, the other agents' episodes named right (action and target), the
    median of the fit's draws with their range, and the action and target alone."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in result["rows"]:
        groups.setdefault((r["episodes"], r["namer"]), []).append(r["others"])
    lines = ["| own episodes (camera, starts) | namer | named right: action and target, "
             "median draw (range) | action | target |", "|---|---|---|---|---|"]
    for (episodes, namer), got in groups.items():
        both = sorted(g["both"] for g in got)
        mid = got[[g["both"] for g in got].index(both[len(both) // 2])]
        lines.append(f"| {episodes} | {namer} | {100 * mid['both']:.0f}% "
                     f"({100 * both[0]:.0f}-{100 * both[-1]:.0f}%) | "
                     f"{100 * mid['action']:.0f}% | {100 * mid['target']:.0f}% |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modules", default=str(ROOT / "results" / "paper" / "modules"))
    ap.add_argument("--key", type=int, default=31)
    ap.add_argument("--own", type=int, default=108)
    ap.add_argument("--others", type=int, default=63)
    ap.add_argument("--out", default=str(ROOT / "results" / "tuning" / "frames_levers.json"))
    args = ap.parse_args(argv)
    robot = trained.load(args.modules)
    k_own, k_others, k_fit = jax.random.split(jax.random.key(args.key), 3)
    base = W.WatchFramesConfig(own_episodes=args.own, width=240, every=2, camera="both")
    # "both" is rendered once; "observer" and "eye" read their own view of the same frames
    sets = {"observer": (base, "observer"), "observer, own starts within ±0.3":
            (dataclasses.replace(base, start_noise=0.3, camera="observer"), "observer"),
            "eye": (base, "eye"), "both cameras": (base, "both")}
    t = time.perf_counter()
    seen = others_features(k_others, robot, args.others, "both")
    print(f"the other agents' episodes rendered and read in {time.perf_counter() - t:.0f} s")
    rows, own_seen = [], {}
    for name, (cfg, camera) in sets.items():
        t = time.perf_counter()
        if cfg not in own_seen:
            own_seen[cfg] = W.own_features(k_own, robot, "paper", cfg)[:3]
        own, others = view(own_seen[cfg], camera), view(seen, camera)
        print(f"{name}: episodes rendered and read in {time.perf_counter() - t:.0f} s")
        namers = NAMERS if name in ("observer", "both cameras") else {
            "ensemble of 7 (shipped)": (8, 1e-3, 7)}
        for label, (hidden, l2, members) in namers.items():
            for draw in range(3):  # the fit's own draw: how much it alone moves the result
                net = seeing.fit(jax.random.fold_in(k_fit, draw), *own, len(scene.ACTIONS),
                                 hidden, l2, camera=camera, members=members)
                rows.append({"episodes": name, "namer": label, "draw": draw,
                             "own": W.accuracy(net, *own),
                             "others": W.accuracy(net, *others)})
                print(rows[-1])
    atomic_write_text(pathlib.Path(args.out), json.dumps(
        {"key": args.key, "modules": str(pathlib.Path(args.modules).relative_to(ROOT))
         if pathlib.Path(args.modules).resolve().is_relative_to(ROOT) else args.modules,
         "own": args.own, "others": args.others, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
