"""Find the pointing configuration of each position; write ``pointing_configs.json``.

The paper stores, for each object position, the joint angles at which the hand points at the
object; the point reward is the L1 distance to them. Here a pointing pose is an open-hand
pointing gesture from a distance: the palm faces the object with its normal aimed at the
object's centre, ``DISTANCE`` (8-15 cm) away, above the table, with every arm capsule at least
``CLEARANCE`` from all three objects (so pointing never touches anything), also on the way
there from home (``PATH_CLEARANCE``), and a small pull toward the home pose keeps that path
short.

Why the palm and not the fingers: the iCub's fingers extend along its forearm and the arm has
no wrist joint in this task, so with four joints no pose 8-15 cm from these objects aims the
finger ray at them (the best found here miss by 47-93 degrees); the palm's normal can be aimed
exactly. The JSON records both angles (``aim_deg`` for the palm, ``finger_aim_deg``).

Search: random joint samples within the model's limits, then a local random search from the
best ones (deterministic: fixed seed). Run once, from the repository root:
``python assets/make_pointing_configs.py [--distance 0.08 0.15] [--clearance 0.04]
[--path-clearance 0.03]`` (the values are checked before the search starts).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[3]))  # the checkout
from grounding_jax.sim import (
    ik,
    scene,  # noqa: E402
)

DISTANCE = (0.08, 0.15)  # metres from the palm site to the object's centre
CLEARANCE = 0.04  # metres between every arm capsule and every object
PATH_CLEARANCE = 0.03  # the same, along the paths from home (see _paths)
TIP_ABOVE_TABLE = 0.06  # metres: the palm site stays this far above the table top
HOME_WEIGHT = 2.0  # degrees of aim traded for one scaled-joint unit (L1) nearer home


def _paths(q: np.ndarray) -> list[np.ndarray]:
    """Joint-space paths from home to ``q``: the straight line, and the path of an arm whose
    joints each move at most 1/3 scaled unit a step (joints arrive at different times)."""
    home = np.radians(scene.HOME_POSE_DEG)
    straight = [home + (q - home) * t for t in np.linspace(0.0, 1.0, 11)[1:]]
    lim = np.radians(scene.PAPER_LIMITS_DEG)
    step = (lim[:, 1] - lim[:, 0]) / 6.0  # 1/3 of a scaled unit (range 2) per joint
    cur, clipped = home.copy(), []
    while not np.allclose(cur, q):
        cur = cur + np.clip(q - cur, -step, step)
        for t in (0.5, 1.0):
            clipped.append(clipped[-1] + (cur - clipped[-1]) * t if clipped else cur)
    return straight + clipped


#: accepted ranges (metres) of the command-line settings
LIMITS = {"distance": (0.03, 0.30), "clearance": (0.0, 0.10), "path_clearance": (0.0, 0.10)}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The settings, checked: a bad one exits naming the option and its accepted range."""
    ap = argparse.ArgumentParser(prog="python assets/make_pointing_configs.py")
    ap.add_argument("--distance", type=float, nargs=2, default=DISTANCE, metavar=("MIN", "MAX"),
                    help="palm-to-object distance range, metres")
    ap.add_argument("--clearance", type=float, default=CLEARANCE,
                    help="arm-to-object clearance at the pose, metres")
    ap.add_argument("--path-clearance", type=float, default=PATH_CLEARANCE,
                    help="arm-to-object clearance on the way from home, metres")
    args = ap.parse_args(argv)
    for name, (lo, hi) in LIMITS.items():
        values = getattr(args, name)
        for v in np.atleast_1d(values):
            if not (np.isfinite(v) and lo <= v <= hi):
                ap.error(f"--{name.replace('_', '-')}: {float(v)} is outside the accepted range "
                         f"[{lo}, {hi}] m")
    if args.distance[0] >= args.distance[1]:
        ap.error(f"--distance: MIN must be below MAX, got {list(args.distance)}")
    return args


def _cost(q: np.ndarray, target: np.ndarray) -> tuple[float, dict]:
    tip, direction = ik.palm_ray(q)
    to_obj = target - tip
    dist = float(np.linalg.norm(to_obj))
    aim = float(np.degrees(np.arccos(np.clip(to_obj @ direction / dist, -1.0, 1.0))))
    clear = ik.clearance(q)
    path_clear = min(ik.clearance(x) for x in _paths(q))
    home = float(np.abs(ik.scaled(q) - ik.scaled(np.radians(scene.HOME_POSE_DEG))).sum())
    bad = (max(0.0, DISTANCE[0] - dist) + max(0.0, dist - DISTANCE[1])
           + max(0.0, CLEARANCE - clear) + max(0.0, PATH_CLEARANCE - path_clear)
           + max(0.0, scene.TABLE_Z + TIP_ABOVE_TABLE - tip[2]))
    ftip, fdir = ik.finger_ray(q)
    fvec = target - ftip
    finger_aim = float(np.degrees(np.arccos(np.clip(fvec @ fdir / np.linalg.norm(fvec), -1, 1))))
    info = {"aim_deg": aim, "palm_distance_m": dist, "clearance_m": clear,
            "path_clearance_m": path_clear,
            "palm_xyz_m": tip.tolist(), "finger_aim_deg": finger_aim}
    return aim + HOME_WEIGHT * home + 1e4 * bad, info


def main(argv: list[str] | None = None) -> None:
    global DISTANCE, CLEARANCE, PATH_CLEARANCE
    args = parse_args(argv)
    DISTANCE, CLEARANCE = tuple(args.distance), args.clearance
    PATH_CLEARANCE = args.path_clearance
    idx = scene.index()
    lo, hi = idx.joint_range[:, 0], idx.joint_range[:, 1]
    rng = np.random.default_rng(0)
    samples = rng.uniform(lo, hi, size=(3000, 4))
    out = {"distance_m": list(DISTANCE), "clearance_m": CLEARANCE,
           "path_clearance_m": PATH_CLEARANCE,
           "tip_above_table_m": TIP_ABOVE_TABLE, "positions": {}}
    for p, name in enumerate(scene.POSITIONS):
        target = scene.object_positions()[p]
        costs = np.array([_cost(q, target)[0] for q in samples])
        best = []
        for q in samples[np.argsort(costs)[:8]]:  # local random search from the best samples
            c, step = _cost(q, target)[0], np.radians(4.0)
            for _ in range(300):
                trial = np.clip(q + rng.normal(0.0, step, 4), lo, hi)
                ct = _cost(trial, target)[0]
                if ct < c:
                    q, c = trial, ct
                else:
                    step = max(step * 0.98, np.radians(0.05))
            best.append((c, q))
        c, q = min(best, key=lambda t: t[0])
        _, info = _cost(q, target)
        if c >= 1e3:
            raise SystemExit(f"{name}: no pose meets the distance/clearance constraints")
        print(f"{name}: joints {np.degrees(q).round(2)} deg, aim {info['aim_deg']:.1f} deg, "
              f"palm {info['palm_distance_m'] * 100:.1f} cm from the object (fingers off by "
              f"{info['finger_aim_deg']:.0f} deg), "
              f"clearance {info['clearance_m'] * 100:.1f} cm "
              f"({info['path_clearance_m'] * 100:.1f} cm on the way from home)")
        out["positions"][name] = {
            "joints_deg": [round(float(v), 4) for v in np.degrees(q)],
            "target_xyz_m": [round(float(v), 5) for v in target],
            **{k: (round(v, 5) if isinstance(v, float) else [round(x, 5) for x in v])
               for k, v in info.items()},
        }
    scene.POINTING_JSON.write_text(json.dumps(out, indent=2) + "\n")
    print("wrote", scene.POINTING_JSON)


if __name__ == "__main__":
    main()
