"""The robot acting, for the reports: one PNG strip of four third-person frames per action."""

from __future__ import annotations

import pathlib

import jax

from grounding_jax.robot.trained import Robot
from grounding_jax.sim import render

#: what each strip shows: the command, heard in this layout
COMMANDS = (("point", "box"), ("touch", "green"), ("push", "red"))
LAYOUT = 3
FOLDER = "robot"


def write_strips(robot: Robot, out: pathlib.Path, width: int = 320, height: int = 224,
                 key: jax.Array | None = None) -> dict[str, str]:
    """Perform each of `COMMANDS` on the paper's slots and write its strip.

    Args:
        robot: the trained robot (`grounding_jax.load`).
        out: a run's folder; the strips go to ``out/robot/<action>.png``.
        width, height: one frame's size.
        key: the episodes' key (default ``jax.random.key(0)``, as ``perform``'s).

    Returns:
        ``{action: path relative to out}`` of the strips written.
    """
    (out / FOLDER).mkdir(parents=True, exist_ok=True)
    written = {}
    for action, word in COMMANDS:
        res = robot.perform(action, word, layout=LAYOUT, key=key)
        named = " ".join(res["named"])
        images = render.frames(res, width=width, height=height, every=33,
                               caption=f"heard: {action} {word}   named: {named}")
        render.write_png(out / FOLDER / f"{action}.png", render.strip(images))
        written[action] = f"{FOLDER}/{action}.png"
    return written


def existing_strips(out: pathlib.Path) -> dict[str, str]:
    """The strips `write_strips` left in ``out`` (for a report rebuilt later)."""
    return {a: f"{FOLDER}/{a}.png" for a, _ in COMMANDS
            if (out / FOLDER / f"{a}.png").is_file()}
