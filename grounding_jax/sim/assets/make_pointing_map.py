"""Pointing poses over the whole reachable table: write ``pointing_map.npz``.

The paper's point reward is the L1 distance to a stored pointing pose, one per fixed slot
(``make_pointing_configs.py``). With objects placed anywhere (``placement``) a pose is needed
for any (x, y): this script solves one on a grid over the reachable region (a margin beyond it
on every side), and the env interpolates bilinearly between grid nodes inside ``jit``.

A pose here means what it means for the slots (the same cost, ``make_pointing_configs._cost``
with the object moved): the palm faces the object's centre from 8-15 cm, above the table,
every arm capsule at least ``CLEARANCE`` from the object. The clearance on the way from home
is not required here (its neighbours differ from placement to placement); a pull toward home
keeps the path short. The nodes are solved in a serpentine order, each by a local search that
starts from its solved neighbour's pose (the first from the stored pose of the nearest slot).

Four joints for a pointing ray leave a family of poses per node, and the searches land on
different members of it: the solved poses zigzag from node to node (up to 0.84 scaled-joint
L1 between neighbours 1 cm apart, against the 0.1 L1 that point's success allows). An actor
cannot learn such a map, so the shipped map is the least-squares fit of a cubic polynomial
in (x, y) to the solved poses, evaluated at the nodes. It points better than the searches
themselves (aim error at most ~1.4 deg at the nodes, against 3.2 deg), and every node is
checked against the pose's definition (distance, height, clearance) before it is written.

Run once, from the repository root: ``python assets/make_pointing_map.py`` (about 5 min).
"""

from __future__ import annotations

import pathlib
import sys

import mujoco
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[3]))  # the checkout
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import make_pointing_configs as slots  # noqa: E402

from grounding_jax.sim import (
    ik,
    placement,
    scene,  # noqa: E402
)

OUT = scene.ASSETS / "pointing_map.npz"
STEP = 0.01  # metres between grid nodes
MARGIN = 0.01  # metres beyond the region on each side (a moving target's path stays inside)
ITERS = 400  # local-search steps per node
DEGREE = 3  # of the smoothing polynomial (2: aim error up to 1.8 deg, 4: 1.0 deg)


def grid() -> tuple[np.ndarray, np.ndarray]:
    """The node coordinates along x and y (metres)."""
    xs = np.arange(placement.REACH_X[0] - MARGIN, placement.REACH_X[1] + MARGIN + 1e-9, STEP)
    ys = np.arange(placement.REACH_Y[0] - MARGIN, placement.REACH_Y[1] + MARGIN + 1e-9, STEP)
    return xs.round(4), ys.round(4)


def clearance_to(q: np.ndarray, target: np.ndarray) -> float:
    """Smallest distance between an arm capsule and any of the three shapes standing at
    ``target`` (each in turn: the pose must suit whichever shape is there)."""
    m = scene.model()
    d = mujoco.MjData(m)
    d.qpos[:] = scene.home_qpos()
    d.qpos[scene.index().arm_qpos] = q
    for s in range(len(scene.SHAPES)):
        d.qpos[scene.index().object_qpos[s, :3]] = target
    mujoco.mj_kinematics(m, d)
    fromto = np.zeros(6)
    return min(mujoco.mj_geomDistance(m, d, m.geom(a).id, m.geom(f"{s}_geom").id, 1.0, fromto)
               for a in scene.ARM_CAPSULES for s in scene.SHAPES)


def cost(q: np.ndarray, target: np.ndarray) -> float:
    tip, direction = ik.palm_ray(q)
    to_obj = target - tip
    dist = float(np.linalg.norm(to_obj))
    aim = float(np.degrees(np.arccos(np.clip(to_obj @ direction / dist, -1.0, 1.0))))
    home = float(np.abs(ik.scaled(q) - ik.scaled(np.radians(scene.HOME_POSE_DEG))).sum())
    bad = (max(0.0, slots.DISTANCE[0] - dist) + max(0.0, dist - slots.DISTANCE[1])
           + max(0.0, slots.CLEARANCE - clearance_to(q, target))
           + max(0.0, scene.TABLE_Z + slots.TIP_ABOVE_TABLE - tip[2]))
    return aim + slots.HOME_WEIGHT * home + 1e4 * bad


def solve(target: np.ndarray, q0: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    idx = scene.index()
    lo, hi = idx.joint_range[:, 0], idx.joint_range[:, 1]
    q, c, step = q0.copy(), cost(q0, target), np.radians(2.0)
    for _ in range(ITERS):
        trial = np.clip(q + rng.normal(0.0, step, 4), lo, hi)
        ct = cost(trial, target)
        if ct < c:
            q, c = trial, ct
        else:
            step = max(step * 0.98, np.radians(0.05))
    if c >= 1e3:
        raise SystemExit(f"no pointing pose meets the constraints at {target[:2]}")
    return q


def smooth(xs: np.ndarray, ys: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """The least-squares cubic (``DEGREE``) in (x, y) through the solved poses, at the nodes."""
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    u = (gx.ravel() - xs.mean()) / np.ptp(xs)
    v = (gy.ravel() - ys.mean()) / np.ptp(ys)
    basis = np.stack([u ** i * v ** j for i in range(DEGREE + 1) for j in range(DEGREE + 1 - i)],
                     axis=1)
    coef, *_ = np.linalg.lstsq(basis, poses.reshape(-1, 4), rcond=None)
    return (basis @ coef).reshape(poses.shape)


def check_pose(q: np.ndarray, target: np.ndarray) -> tuple[float, bool]:
    """The aim error (degrees) of pose ``q`` at ``target``, and whether the pose meets the
    definition (distance, palm height, clearance)."""
    tip, direction = ik.palm_ray(q)
    to_obj = target - tip
    dist = float(np.linalg.norm(to_obj))
    ok = (slots.DISTANCE[0] <= dist <= slots.DISTANCE[1]
          and tip[2] >= scene.TABLE_Z + slots.TIP_ABOVE_TABLE
          and clearance_to(q, target) >= slots.CLEARANCE)
    return float(np.degrees(np.arccos(np.clip(to_obj @ direction / dist, -1.0, 1.0)))), ok


def main() -> None:
    xs, ys = grid()
    z = scene.TABLE_Z + scene.OBJECT_HALF
    stored = scene.pointing_configs()
    rng = np.random.default_rng(0)
    poses = np.zeros((len(xs), len(ys), 4))
    aims = np.zeros((len(xs), len(ys)))
    prev = None
    for j, y in enumerate(ys):  # serpentine: neighbours follow each other
        order = range(len(xs)) if j % 2 == 0 else range(len(xs) - 1, -1, -1)
        for i in order:
            target = np.array([xs[i], y, z])
            if prev is None:
                prev = stored[int(np.argmin(np.abs(np.array(scene.OBJECT_Y) - y)))]
            q = solve(target, prev, rng)
            poses[i, j], prev = q, q
        print(f"y {y:.3f} solved", flush=True)
    raw, poses = poses, smooth(xs, ys, poses)
    in_x = (xs >= placement.REACH_X[0] - 1e-6) & (xs <= placement.REACH_X[1] + 1e-6)
    in_y = (ys >= placement.REACH_Y[0] - 1e-6) & (ys <= placement.REACH_Y[1] + 1e-6)
    inside = in_x[:, None] & in_y[None]
    ok = np.zeros_like(inside)
    for i, x in enumerate(xs):
        for j, y in enumerate(ys):
            aims[i, j], ok[i, j] = check_pose(poses[i, j], np.array([x, y, z]))
    if not np.all(ok[inside]):  # the margin only serves interpolation at the region's border
        raise SystemExit(f"smoothed poses break the definition at x = "
                         f"{xs[np.nonzero(~ok & inside)[0]]}")
    print(f"smoothed: aim error median {np.median(aims[inside]):.2f} deg, max "
          f"{aims[inside].max():.2f} deg in the region ({aims.max():.2f} deg with the margin, "
          f"{np.sum(~ok)} margin nodes past the definition)")
    np.savez_compressed(OUT, x=xs.astype(np.float32), y=ys.astype(np.float32),
                        joints=poses.astype(np.float32), aim_deg=aims.astype(np.float32),
                        raw_joints=raw.astype(np.float32))
    print("wrote", OUT)


if __name__ == "__main__":
    main()
