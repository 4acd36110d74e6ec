"""Seeing the robot act: frames of an episode from the third-person camera, and videos.

`frames` draws a `Robot.perform <grounding_jax.robot.trained.Robot.perform>` result
or any single-episode env trajectory (a `State` stacked over
steps) from the ``observer`` camera, which faces the robot across the table; `write_video`
writes them as MP4 or GIF (through mediapy and an ffmpeg binary: ``imageio-ffmpeg``'s, installed
with the package, or one on ``PATH``); `strip` lays a few frames side by side for a PNG.
The command-line front end is ``python -m grounding_jax.show``.
"""

from __future__ import annotations

import os
import pathlib
import shutil
from collections.abc import Sequence
from typing import Any

import numpy as np

#: the cameras `frames` draws from: a scene camera, or ``"both"`` (the two side by side)
CAMERAS = ("observer", "eye", "both")
#: the views of ``"both"``, left to right
BOTH = ("observer", "eye")

#: the containers write_video writes, by file suffix
VIDEO_SUFFIXES = (".mp4", ".gif")


def trajectory_of(episode: Any) -> tuple[np.ndarray, int]:
    """``(qpos [steps, nq], layout)`` of a `Robot.perform` result or of a one-episode
    env trajectory.

    Raises:
        ValueError: neither, or a batch of episodes.
    """
    traj = episode["trajectory"] if isinstance(episode, dict) else episode
    qpos = getattr(traj, "qpos", None)
    if qpos is None:
        raise ValueError("episode: expected a perform() result or an env trajectory (a State "
                         f"stacked over steps), got {type(episode).__name__}")
    qpos = np.asarray(qpos)
    if qpos.ndim != 2:
        raise ValueError(f"episode: one episode's trajectory has qpos [steps, nq]; got shape "
                         f"{qpos.shape} (take one episode of a batch first, e.g. "
                         "jax.tree.map(lambda x: x[0], trajectory))")
    return qpos, int(np.asarray(traj.task.layout).reshape(-1)[0])


def frames(episode: Any, camera: str = "observer", width: int = 480, height: int = 320,
           every: int = 1, caption: str | None = None) -> np.ndarray:
    """Render an episode, one frame per RL step.

    Args:
        episode: a `Robot.perform` result (its ``trajectory``) or an env trajectory of
            one episode (``State`` with a leading steps axis, e.g. from ``jax.lax.scan``).
        camera: ``"observer"`` (third person), ``"eye"`` (the robot's view, arm drawn) or
            ``"both"`` (the two side by side, observer left: ``2 * width`` pixels wide).
        width: frame width in pixels (of each view).
        height: frame height in pixels.
        every: draw every ``every``-th step.
        caption: text written on every frame (e.g. the command and what the robot named).

    Returns:
        ``uint8 [frames, height, width, 3]`` (``2 * width`` for ``"both"``).
    """
    for name, v in (("width", width), ("height", height), ("every", every)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ValueError(f"{name}: {v!r} is not accepted; accepted: an int >= 1")
    if camera not in CAMERAS:
        raise ValueError(f"camera: unknown value {camera!r}; accepted values: {CAMERAS}")
    qpos, layout = trajectory_of(episode)
    views = BOTH if camera == "both" else (camera,)
    out = np.concatenate([_render(qpos[::every], layout, c, width, height) for c in views], 2)
    width = out.shape[2]
    if caption:
        import cv2

        font = cv2.FONT_HERSHEY_SIMPLEX
        (text_w, _), _ = cv2.getTextSize(caption, font, 0.45, 1)
        scale = 0.45 * min(1.0, (width - 12) / text_w)  # the caption fits the frame
        for f in out:  # white text on a dark band at the bottom
            cv2.rectangle(f, (0, height - 22), (width, height), (30, 30, 30), -1)
            cv2.putText(f, caption, (6, height - 7), font, scale, (255, 255, 255), 1,
                        cv2.LINE_AA)
    return out


def _render(qpos: np.ndarray, layout: int, camera: str, width: int, height: int
            ) -> np.ndarray:
    """``uint8 [len(qpos), height, width, 3]``: the arm at each ``qpos`` from ``camera``."""
    from grounding_jax.sim import vision

    renderer = vision.EyeRenderer(width, height, camera=camera)
    try:
        return np.stack([renderer.render(layout, qpos=q, arm=True) for q in qpos])
    finally:
        renderer.close()


def ffmpeg_binary() -> str:
    """The ffmpeg that videos are written with: ``$GROUNDING_JAX_FFMPEG``, else the one
    ``imageio-ffmpeg`` ships, else ``ffmpeg`` on ``PATH``.

    Raises:
        RuntimeError: none found (the message says how to get one).
    """
    chosen = os.environ.get("GROUNDING_JAX_FFMPEG")
    if chosen:
        if not (shutil.which(chosen) or pathlib.Path(chosen).is_file()):
            raise RuntimeError(f"GROUNDING_JAX_FFMPEG: {chosen!r} is not an ffmpeg binary")
        return chosen
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        pass
    found = shutil.which("ffmpeg")
    if found is None:
        raise RuntimeError("writing a video needs ffmpeg, and none was found: pip install "
                           "imageio-ffmpeg (it ships one), or install ffmpeg (Debian/Ubuntu: "
                           "apt-get install ffmpeg), or set GROUNDING_JAX_FFMPEG=/path/ffmpeg")
    return found


def write_video(path: str | os.PathLike, images: np.ndarray, fps: int = 25) -> pathlib.Path:
    """Write frames as a video: ``.mp4`` (H.264) or ``.gif``, chosen by the suffix.

    The file appears complete or not at all (written beside it, then renamed).

    Args:
        path: the file to write.
        images: ``uint8 [frames, height, width, 3]``, e.g. from `frames`.
        fps: frames per second.

    Returns:
        The path written.
    """
    path = pathlib.Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(f"out: unknown video type {path.suffix or '(none)'!r} in {path}; "
                         f"accepted suffixes: {VIDEO_SUFFIXES}")
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3 or images.shape[0] < 1:
        raise ValueError(f"images: expected [frames, height, width, 3], got {images.shape}")
    if isinstance(fps, bool) or not isinstance(fps, int) or fps < 1:
        raise ValueError(f"fps: {fps!r} is not accepted; accepted: an int >= 1")
    import mediapy

    mediapy.set_ffmpeg(ffmpeg_binary())
    if path.suffix.lower() == ".mp4":  # H.264 wants even sizes
        h, w = images.shape[1] // 2 * 2, images.shape[2] // 2 * 2
        images = images[:, :h, :w]
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}{path.suffix}")
    try:
        mediapy.write_video(tmp, images, fps=fps,
                            codec="gif" if path.suffix.lower() == ".gif" else "h264")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_png(path: str | os.PathLike, image: np.ndarray) -> pathlib.Path:
    """Write an RGB image (``uint8 [height, width, 3]``, e.g. from `strip`) as a PNG,
    whole or not at all."""
    import cv2

    from grounding_jax.core.io import atomic_write_bytes

    ok, png = cv2.imencode(".png", np.ascontiguousarray(np.asarray(image)[..., ::-1]))
    if not ok:
        raise ValueError(f"image: cannot be encoded as PNG (shape {np.shape(image)})")
    path = pathlib.Path(path)
    atomic_write_bytes(path, png.tobytes())
    return path


def strip(images: np.ndarray, n: int = 4, at: Sequence[float] | None = None) -> np.ndarray:
    """``n`` frames side by side (the first, the last and evenly between, or at the given
    fractions of the episode), for a PNG.

    Returns:
        ``uint8 [height, n * width, 3]``.
    """
    images = np.asarray(images)
    at = np.linspace(0, 1, n) if at is None else np.asarray(at, float)
    idx = np.round(at * (len(images) - 1)).astype(int)
    return np.concatenate(list(images[idx]), axis=1)
