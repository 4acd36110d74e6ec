"""``Robot.perform`` latency: the first command (compiles), later commands (reuse the compile),
and, as the baseline in the same process, a command on a fresh copy of the robot (what every
command cost when ``perform`` compiled again on each call).

Usage:  python benchmarks/perform_latency.py [--modules results/paper/modules] [--repeats 6]
Writes results/benchmarks/perform_latency.json and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pathlib
import platform
import statistics
import sys
import time

import jax

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
import grounding_jax as gj  # noqa: E402

COMMANDS = [("point", "red"), ("touch", "box"), ("push", "sphere"), ("point", "blue"),
            ("touch", "green"), ("push", "cylinder")]


def _timed(robot: gj.Robot, action: str, word: str, layout: int) -> float:
    t = time.perf_counter()
    jax.block_until_ready(robot.perform(action, word, layout)["trajectory"])
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--modules", default=str(HERE.parent / "results" / "paper" / "modules"))
    ap.add_argument("--repeats", type=int, default=6, help="commands timed per way (>= 1)")
    args = ap.parse_args()
    if args.repeats < 1:
        ap.error(f"--repeats: {args.repeats} is not accepted; accepted: an int >= 1")
    # no persistent cache here: the first command's compile is measured as users first meet it
    robot = gj.load(args.modules)
    cmds = [(a, w, (7 * i + 1) % 36) for i, (a, w) in
            enumerate(COMMANDS * (args.repeats // len(COMMANDS) + 1))][:args.repeats]
    first = _timed(robot, *cmds[0])
    later = [_timed(robot, *c) for c in cmds]
    fresh = [_timed(dataclasses.replace(robot), *c) for c in cmds]  # empty compile cache
    res = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
           "first_s": first, "later_median_s": statistics.median(later),
           "fresh_robot_median_s": statistics.median(fresh),
           "speedup_later_vs_fresh": statistics.median(fresh) / statistics.median(later)}
    out = HERE.parent / "results" / "benchmarks" / "perform_latency.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=2) + "\n")
    print("| command | seconds (median) | × later commands |\n|---|---|---|")
    print(f"| first (compiles) | {first:.2f} | {first / res['later_median_s']:.1f} |")
    print(f"| later ({len(later)}) | {res['later_median_s']:.3f} | 1.0 |")
    print(f"| on a fresh robot, the baseline ({len(fresh)}) | {res['fresh_robot_median_s']:.2f} "
          f"| {res['speedup_later_vs_fresh']:.1f} |")


if __name__ == "__main__":
    main()
