"""The pictures of the robot acting: the README's, and each committed run's strips.

Writes, from the committed paper modules, ``docs/images/actions.png`` (point, touch and push,
four third-person frames each) and ``docs/images/push_red.gif``; then, for every run folder
given, ``<run>/robot/<action>.png`` from that run's own modules, and rebuilds its REPORT.md
from its metrics.json (``train.py --report-only``) so that the report shows them. A fresh
``python train.py`` writes its strips itself.

Usage:  python benchmarks/robot_images.py [--runs results/paper results/quick]
"""

from __future__ import annotations

import argparse
import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import grounding_jax as gj  # noqa: E402
from grounding_jax.paper.strips import COMMANDS, LAYOUT, write_strips  # noqa: E402
from grounding_jax.sim import render  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python benchmarks/robot_images.py")
    ap.add_argument("--runs", nargs="*", default=["results/paper", "results/quick"])
    ap.add_argument("--modules", default=str(ROOT / "results" / "paper" / "modules"))
    args = ap.parse_args(argv)
    gj.enable_compilation_cache()
    robot = gj.load(args.modules)
    images = ROOT / "docs" / "images"
    images.mkdir(parents=True, exist_ok=True)
    rows = []
    for action, word in COMMANDS:
        res = robot.perform(action, word, layout=LAYOUT)
        named = " ".join(res["named"])
        caption = f"heard: {action} {word}   named: {named}"
        frames = render.frames(res, width=240, height=168, every=33, caption=caption)
        rows.append(render.strip(frames))
        if (action, word) == ("push", "red"):
            clip = render.frames(res, width=240, height=168, every=3, caption=caption)
            render.write_video(images / "push_red.gif", clip, fps=12)
    render.write_png(images / "actions.png", np.concatenate(rows))
    print(f"wrote {images / 'actions.png'}, {images / 'push_red.gif'}")
    import train

    for run in map(pathlib.Path, args.runs):
        written = write_strips(gj.load(run / "modules"), run)
        print(f"wrote {run}/" + ", ".join(written.values()))
        if train.main(["--out", str(run), "--report-only"]) != 0:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
