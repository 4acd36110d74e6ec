"""Touching and pushing poses over the whole reachable table: write ``touch_map.npz`` and
``push_map.npz``.

The free family's touch reward is the L1 distance of the scaled joints to a pose for the
target (``tasks.FREE``), as point's is to a pointing pose; the same for push was tried and not
kept (docs/beyond.md; ``benchmarks/free_tuning.py --push-reward pose``).

- A *touching* pose puts the palm site ``TOUCH_DEPTH`` below the top face of an object
  standing at (x, y): the palm presses down on the object's top, which the table holds still,
  instead of shoving it sideways (1.25 cm since the tuning rows of docs/beyond.md;
  1 cm before). A scripted arm that moves gently to the 1 cm pose (docs/beyond.md) touches
  94% of the held-out targets without moving them 3 cm.
- A *pushing* pose puts the palm site ``PUSH_BEHIND`` on the robot's side of the object's
  centre, ``PUSH_RISE`` above it: the palm comes to the object's near face and, reaching the
  pose, has pushed it 1.5-2.5 cm away from the robot (``benchmarks/scripted_touch.py --action
  push``: 93% of the held-out pushes). In the region's far-right corner (x <= -0.255 m,
  y >= 0.285 m) neither this point nor the object's centre at mid height is within the
  arm's reach (``reach_error`` up to 7 cm), and no push of 2 cm is.

The nodes are the pointing map's (``pointing_map.npz``: a 1 cm grid over the region and a
1 cm margin). Each is solved with ``ik.solve`` (damped least squares on the palm site's
position, palm down in its null space), from the node's pointing pose and from every solved
neighbour's pose, keeping the result nearest the point (ties: the one nearest the
neighbours, so poses change smoothly from node to node). The nodes are solved outward from
the grid's centre. Where four joints cannot bring the palm there (touch: the near-left edge
by up to 1.6 cm, the far-right corner by up to 7 cm) the pose is the nearest the arm gets, and
``reach_error`` says by how much it misses.

``--smooth W`` re-solves each touch node near a cubic fit of the map (``smooth_map``): a
smoother map that reaches its points better, tried and not shipped. ``--reach-shift R`` moves
an unreached node's point up to R across the top face to where the palm reaches it
(``shift_unreached``; the npz's ``shift`` says how far): tried and not shipped either (the
palm pressing off the top's centre slid off its edge).

Run once, from the repository root: ``python assets/make_touch_map.py [--action push]``
(about 30 s each).
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[3]))  # the checkout

from grounding_jax.sim import (
    ik,
    placement,
    scene,  # noqa: E402
)

OUT = {"touch": placement.TOUCH_MAP, "push": placement.PUSH_MAP}
#: Metres below the object's top face that touch sends the palm site to (it presses on it).
TOUCH_DEPTH = 0.0125
#: Push sends the palm site this far toward the robot (+x) from the object's centre ...
PUSH_BEHIND = 0.01
#: ... and this far above the centre (metres).
PUSH_RISE = 0.005
ITERS = 150  # IK iterations per start pose
#: Touch map smoothing (``smooth_map``): the pull of each node's pose toward a polynomial fit
#: of the map (``ik.solve_near``'s ``weight``; 0 turns smoothing off). Off in the shipped map:
#: with 1e-3 touch pressed its target away more often (docs/beyond.md) ...
SMOOTH_WEIGHT = 0.0
#: ... of this total degree in (x, y).
SMOOTH_DEGREE = 3
#: Where the touching point is out of reach (``reach_error`` above ``SHIFT_FROM``), move it
#: across the top face, at most this far (metres; ``shift_unreached``; 0: off) ...
REACH_SHIFT = 0.0
SHIFT_FROM = 0.003
#: ... in steps of this, toward where the palm got.
SHIFT_STEP = 0.0025


def offset(action: str, depth: float = TOUCH_DEPTH) -> np.ndarray:
    """Where the palm site goes relative to the object's centre (metres, [3])."""
    if action == "touch":
        return np.array([0.0, 0.0, scene.OBJECT_HALF - depth])
    return np.array([PUSH_BEHIND, 0.0, PUSH_RISE])


def centres() -> np.ndarray:
    """The centre of an object standing at each node of the pointing map's grid, ``[nx, ny,
    3]`` (metres)."""
    pm = placement.pointing_map()
    gx, gy = np.meshgrid(pm["x"].astype(np.float64), pm["y"].astype(np.float64), indexing="ij")
    return np.stack([gx, gy, np.full(gx.shape, scene.TABLE_Z + scene.OBJECT_HALF)], axis=-1)


def solve_map(off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IK poses ``[nx, ny, 4]`` (radians) putting the palm site at each node's object centre
    plus ``off`` (``[3]``, or ``[nx, ny, 3]``: one per node), and their reach errors
    ``[nx, ny]`` (metres)."""
    pointing = placement.pointing_map()["joints"].astype(np.float64)
    points = centres() + off
    nx, ny = points.shape[:2]
    poses = np.zeros((nx, ny, 4))
    err = np.full((nx, ny), np.inf)
    solved = np.zeros((nx, ny), bool)
    centre = (nx // 2, ny // 2)
    order = sorted(((i, j) for i in range(nx) for j in range(ny)),
                   key=lambda ij: ((ij[0] - centre[0]) ** 2 + (ij[1] - centre[1]) ** 2, ij))
    for i, j in order:
        near = [(i + a, j + b) for a in (-1, 0, 1) for b in (-1, 0, 1)
                if 0 <= i + a < nx and 0 <= j + b < ny and solved[i + a, j + b]]
        best = None
        for start in [pointing[i, j]] + [poses[n] for n in near]:
            q, e = ik.solve(points[i, j], start, iters=ITERS)
            jump = (np.mean([np.abs(ik.scaled(q) - ik.scaled(poses[n])).sum() for n in near])
                    if near else 0.0)
            rank = (round(e, 3), jump)
            if best is None or rank < best[0]:
                best = (rank, q, e)
        poses[i, j], err[i, j], solved[i, j] = best[1], best[2], True
    return poses, err


def smooth_map(poses: np.ndarray, off: np.ndarray, weight: float = SMOOTH_WEIGHT,
               degree: int = SMOOTH_DEGREE) -> tuple[np.ndarray, np.ndarray]:
    """Re-solve every node near a smooth fit of ``poses``: fewer jumps between neighbours.

    Each joint's scaled angle is fitted by a polynomial of total degree ``degree`` in the
    node's (x, y) (least squares over all nodes); each node is then solved again with
    ``ik.solve_near`` from the fit's pose, pulled toward it by ``weight``. The fit alone
    misses the touching point by ~6 mm (median); the re-solve brings that back under 1 mm
    while keeping the fit's smoothness where the arm has a choice.

    Returns:
        (poses ``[nx, ny, 4]`` in radians, reach errors ``[nx, ny]`` in metres).
    """
    pm = placement.pointing_map()
    xs, ys = pm["x"], pm["y"]
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    u, v = (gx - gx.mean()) / 0.05, (gy - gy.mean()) / 0.05
    feats = np.stack([u**i * v**j for i in range(degree + 1) for j in range(degree + 1 - i)],
                     axis=-1).reshape(-1, (degree + 1) * (degree + 2) // 2)
    coef, *_ = np.linalg.lstsq(feats, poses.reshape(-1, 4), rcond=None)
    fit = (feats @ coef).reshape(poses.shape)
    points = centres() + off
    out, err = np.zeros_like(poses), np.zeros(poses.shape[:2])
    for i, j in np.ndindex(*poses.shape[:2]):
        out[i, j], err[i, j] = ik.solve_near(points[i, j], fit[i, j], weight)
    return out, err


def shift_unreached(poses: np.ndarray, err: np.ndarray, off: np.ndarray,
                    most: float = REACH_SHIFT) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the arm cannot bring the palm site to a node's touching point, press on another
    point of the target's top face, at most ``most`` across from the centre: the nearest one
    (in steps of ``SHIFT_STEP``, toward where the palm got, +-30 degrees) that the palm
    reaches within ``SHIFT_FROM``, else the one it gets nearest to -- if that halves the
    error; otherwise the node keeps its point (where the palm cannot get down to the top
    face, no shift across it helps).

    Returns:
        (poses ``[nx, ny, 4]``, reach errors ``[nx, ny]`` to the node's point, the per-node
        offsets ``[nx, ny, 3]`` from the object's centre).
    """
    centre = centres()
    poses, err = poses.copy(), err.copy()
    offs = np.broadcast_to(off, poses.shape[:2] + (3,)).copy()
    radii = np.arange(SHIFT_STEP, most + 1e-9, SHIFT_STEP)
    for i, j in zip(*np.nonzero(err > SHIFT_FROM), strict=True):
        point = centre[i, j] + offs[i, j]
        got = ik.palm_position(poses[i, j])[:2] - point[:2]
        heading = np.arctan2(got[1], got[0])
        best = (err[i, j], poses[i, j], offs[i, j])
        for r in radii:
            for turn in np.radians((0.0, -30.0, 30.0)):
                shift = r * np.array([np.cos(heading + turn), np.sin(heading + turn), 0.0])
                q, e = ik.solve(point + shift, poses[i, j], iters=ITERS)
                if e < best[0]:
                    best = (e, q, offs[i, j] + shift)
            if best[0] <= SHIFT_FROM:
                break
        if best[0] <= max(SHIFT_FROM, err[i, j] / 2):
            err[i, j], poses[i, j], offs[i, j] = best
    return poses, err, offs


def jumps(poses: np.ndarray) -> np.ndarray:
    """Scaled-joint L1 change between grid neighbours (1 cm apart), all pairs."""
    s = ik.scaled(poses)
    return np.concatenate([np.abs(np.diff(s, axis=0)).sum(-1).ravel(),
                           np.abs(np.diff(s, axis=1)).sum(-1).ravel()])


def main(action: str = "touch", depth: float = TOUCH_DEPTH,
         out: pathlib.Path | None = None, smooth: float = SMOOTH_WEIGHT,
         reach_shift: float = REACH_SHIFT) -> None:
    pm = placement.pointing_map()
    xs, ys = pm["x"], pm["y"]
    off = offset(action, depth)
    poses, err = solve_map(off)
    if action == "touch" and smooth > 0:
        j0 = jumps(poses)
        poses, err = smooth_map(poses, off, smooth)
        j1 = jumps(poses)
        print(f"smoothed (weight {smooth}): neighbour jumps (scaled L1 per cm) median "
              f"{np.median(j0):.3f} -> {np.median(j1):.3f}, 95th {np.percentile(j0, 95):.3f} "
              f"-> {np.percentile(j1, 95):.3f}, max {j0.max():.2f} -> {j1.max():.2f}")
    shift = np.zeros(poses.shape[:2])
    if action == "touch" and reach_shift > 0:
        poses, err, offs = shift_unreached(poses, err, off, reach_shift)
        shift = np.linalg.norm(offs[..., :2] - off[:2], axis=-1)
        print(f"shifted {np.sum(shift > 0)} unreached nodes' points across the top face "
              f"(at most {1000 * reach_shift:.1f} mm; median shift "
              f"{1000 * np.median(shift[shift > 0]) if np.any(shift > 0) else 0:.1f} mm)")
    in_x = (xs >= placement.REACH_X[0] - 1e-6) & (xs <= placement.REACH_X[1] + 1e-6)
    in_y = (ys >= placement.REACH_Y[0] - 1e-6) & (ys <= placement.REACH_Y[1] + 1e-6)
    inside = in_x[:, None] & in_y[None]
    print(f"{action}: palm site to its point in the region: median "
          f"{1000 * np.median(err[inside]):.1f} mm, {np.mean(err[inside] <= 0.005):.0%} of the "
          f"nodes within 5 mm, 95th {1000 * np.percentile(err[inside], 95):.0f} mm, max "
          f"{1000 * err[inside].max():.0f} mm")
    out = OUT[action] if out is None else out
    extra = ({"depth": np.float32(depth), "smooth_weight": np.float32(smooth),
              "reach_shift": np.float32(reach_shift), "shift": shift.astype(np.float32)}
             if action == "touch"
             else {"offset": off.astype(np.float32)})
    np.savez_compressed(out, x=xs.astype(np.float32), y=ys.astype(np.float32),
                        joints=poses.astype(np.float32), reach_error=err.astype(np.float32),
                        **extra)
    print("wrote", out)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--action", choices=tuple(OUT), default="touch")
    ap.add_argument("--depth", type=float, default=TOUCH_DEPTH,
                    help=f"touch: metres below the top face (default {TOUCH_DEPTH})")
    ap.add_argument("--smooth", type=float, default=SMOOTH_WEIGHT,
                    help=f"touch: pull toward a smooth fit of the map (default {SMOOTH_WEIGHT};"
                         " 0: off)")
    ap.add_argument("--reach-shift", type=float, default=REACH_SHIFT,
                    help="touch: metres the point may move across the top face where the "
                    f"palm cannot reach it (default {REACH_SHIFT}; 0: off)")
    ap.add_argument("--out", type=pathlib.Path, default=None,
                    help="default grounding_jax/sim/assets/<action>_map.npz")
    args = ap.parse_args()
    if not 0.0 <= args.depth <= 2 * scene.OBJECT_HALF:
        ap.error(f"--depth: must lie in [0, {2 * scene.OBJECT_HALF}] m (the object's "
                 f"height), got {args.depth}")
    if not (np.isfinite(args.smooth) and args.smooth >= 0):
        ap.error(f"--smooth: must be a finite number >= 0, got {args.smooth}")
    if not 0.0 <= args.reach_shift <= scene.OBJECT_HALF:
        ap.error(f"--reach-shift: must lie in [0, {scene.OBJECT_HALF}] m (the top face's "
                 f"half width), got {args.reach_shift}")
    main(args.action, args.depth, args.out, args.smooth, args.reach_shift)
