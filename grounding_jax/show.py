"""Watch the trained robot act: ``python -m grounding_jax.show "push red" --out push_red.mp4``.

Loads trained modules (by default the paper profile's, committed in the checkout under
``results/paper/modules``), hears the command, performs it and writes what the third-person
camera saw as MP4 or GIF (``--out``), a PNG strip of four frames (``--strip``), or plays it in
MuJoCo's viewer (``--viewer``, needs a display).

    python -m grounding_jax.show "push red" --layout 3 --out push_red.mp4
    python -m grounding_jax.show "touch sphere" --placement random --seed 4 --out touch.gif
    python -m grounding_jax.show "point box" --modules results/quick/modules --viewer
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

from grounding_jax.sim import tasks
from grounding_jax.sim.render import CAMERAS

#: the committed modules of the paper profile, in a checkout
DEFAULT_MODULES = pathlib.Path(__file__).resolve().parents[1] / "results" / "paper" / "modules"
PLACEMENTS = ("slots", "random")


class ShowError(ValueError):
    """A bad argument; the message names it and the accepted values."""


def parse_command(command: str) -> tuple[str, str]:
    """``"push red"`` -> ``("push", "red")``, checked against the actions and target words."""
    words = command.split()
    if len(words) != 2:
        raise ShowError(f"command: expected '<action> <target>' such as 'push red', got "
                        f"{command!r}")
    action, word = words
    if action not in tasks.ACTIONS:
        raise ShowError(f"command: unknown action {action!r}; accepted values: {tasks.ACTIONS}")
    if word not in tasks.TARGET_WORDS:
        raise ShowError(f"command: unknown target {word!r}; accepted values: "
                        f"{tasks.TARGET_WORDS}")
    return action, word


def _check(args: argparse.Namespace) -> None:
    """Every argument, before anything loads or compiles."""
    from grounding_jax.sim import scene

    n = len(scene.LAYOUTS)
    if not 0 <= args.layout < n:
        raise ShowError(f"--layout: {args.layout} out of range; accepted: 0..{n - 1}")
    if args.placement not in PLACEMENTS:
        raise ShowError(f"--placement: unknown value {args.placement!r}; accepted values: "
                        f"{PLACEMENTS}")
    if args.camera not in CAMERAS:
        raise ShowError(f"--camera: unknown value {args.camera!r}; accepted values: {CAMERAS}")
    for name in ("steps", "width", "height", "fps", "every"):
        if getattr(args, name) < 1:
            raise ShowError(f"--{name}: {getattr(args, name)} is not accepted; accepted: an "
                            "integer >= 1")
    if args.out is None and args.strip is None and not args.viewer:
        raise ShowError("--out: say where to write the video (.mp4 or .gif), or give --strip "
                        "PNG or --viewer")
    if args.out is not None:
        from grounding_jax.sim.render import VIDEO_SUFFIXES

        if pathlib.Path(args.out).suffix.lower() not in VIDEO_SUFFIXES:
            raise ShowError(f"--out: unknown video type in {args.out!r}; accepted suffixes: "
                            f"{VIDEO_SUFFIXES}")
    if args.strip is not None and pathlib.Path(args.strip).suffix.lower() != ".png":
        raise ShowError(f"--strip: {args.strip!r} is not a .png file")
    for name in ("out", "strip"):
        target = getattr(args, name)
        if target is not None and not pathlib.Path(target).resolve().parent.is_dir():
            raise ShowError(f"--{name}: the folder of {target!r} does not exist")
    if args.viewer and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ShowError("--viewer: no display here (DISPLAY is not set); write a video with "
                        "--out instead")
    modules = pathlib.Path(args.modules)
    if not (modules / "config.json").is_file():
        raise ShowError(f"--modules: {modules} holds no saved modules (no config.json); "
                        "accepted: a folder written by train.py (<out>/modules) or "
                        "grounding_jax.robot.trained.save")


def view(episode, fps: int = 25) -> None:
    """Play an episode in MuJoCo's passive viewer (needs a display), at ``fps`` steps/s."""
    import copy

    import mujoco
    import mujoco.viewer

    from grounding_jax.sim import scene
    from grounding_jax.sim.render import trajectory_of

    qpos, layout = trajectory_of(episode)
    m = copy.copy(scene.model())
    scene.paint_layout(m, layout)
    d = mujoco.MjData(m)
    with mujoco.viewer.launch_passive(m, d) as v:
        for q in qpos:
            if not v.is_running():
                break
            d.qpos[:] = q
            mujoco.mj_forward(m, d)
            v.sync()
            time.sleep(1 / fps)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m grounding_jax.show",
                                 description="Perform a command with trained modules and show "
                                             "it: a video, a PNG strip or the viewer.")
    ap.add_argument("command", help="'<action> <target>', e.g. 'push red' or 'point box'")
    ap.add_argument("--layout", type=int, default=0,
                    help="which shape and colour stands in each slot (0..35)")
    ap.add_argument("--placement", default="slots",
                    help=f"one of {PLACEMENTS}: the paper's three slots, or objects anywhere "
                         "(the free family's robot, seen through its eye camera)")
    ap.add_argument("--modules", default=str(DEFAULT_MODULES),
                    help="trained modules (default: the committed paper modules)")
    ap.add_argument("--seed", type=int, default=0, help="the episode's key (and placement)")
    ap.add_argument("--steps", type=int, default=100, help="RL steps to act")
    ap.add_argument("--out", default=None, help="video file to write: .mp4 or .gif")
    ap.add_argument("--strip", default=None, help="also write four frames side by side (.png)")
    ap.add_argument("--viewer", action="store_true", help="play it in MuJoCo's viewer")
    ap.add_argument("--camera", default="observer",
                    help=f"one of {CAMERAS}: third person, the robot's eye (arm drawn), or "
                    "the two side by side")
    ap.add_argument("--width", type=int, default=480)
    ap.add_argument("--height", type=int, default=320)
    ap.add_argument("--fps", type=int, default=25)
    ap.add_argument("--every", type=int, default=1, help="draw every n-th step")
    args = ap.parse_args(argv)
    try:
        action, word = parse_command(args.command)
        _check(args)
    except ShowError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2

    import jax
    import numpy as np

    import grounding_jax as gj
    from grounding_jax.core.checkpoint import CheckpointError
    from grounding_jax.sim import render

    gj.enable_compilation_cache()
    try:
        robot = gj.load(args.modules)
        placement = "random" if args.placement == "random" else None
        result = robot.perform(action, word, layout=args.layout, steps=args.steps,
                               key=jax.random.key(args.seed), placement=placement)
    except (CheckpointError, ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    named = " ".join(result["named"]) if result["named"] else "(no namer)"
    caption = f"heard: {action} {word}   named: {named}"
    if "xy" in result:  # objects anywhere: where, in table coordinates, not slot words
        xy, true = (100 * np.asarray(result[k], float) for k in ("xy", "true_xy"))
        found = (f"objects placed at random (seed {args.seed}): the TL put the {word} object "
                 f"at ({xy[0]:.1f}, {xy[1]:.1f}) cm, truly ({true[0]:.1f}, {true[1]:.1f}) cm "
                 f"({np.linalg.norm(xy - true):.1f} cm off)")
    else:
        found = (f"layout {args.layout} (slots): the TL found the {result['position']} "
                 f"object (truly {result['true_position']})")
    print(f"{action} {word}, {found}; final reward {result['final_reward']:.3f}; the robot "
          f"named it: {named}")
    if args.out or args.strip:
        try:
            images = render.frames(result, camera=args.camera, width=args.width,
                                   height=args.height, every=args.every, caption=caption)
        except ValueError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        if args.out:
            try:
                render.write_video(args.out, images, fps=args.fps)
            except RuntimeError as e:  # no ffmpeg
                print(f"error: {e}", file=sys.stderr)
                return 2
            print(f"wrote {args.out} ({len(images)} frames, {args.width}x{args.height})")
        if args.strip:
            render.write_png(args.strip, render.strip(images))
            print(f"wrote {args.strip}")
    if args.viewer:
        view(result, args.fps)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # nothing is half-written: files appear whole or not at all
        print("\ninterrupted", file=sys.stderr)
        sys.exit(130)
