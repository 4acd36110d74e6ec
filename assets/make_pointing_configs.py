"""Find the pointing configuration of each position by inverse kinematics; write the JSON.

The paper stores, for each object position, the joint angles at which the fingers point at the
object; the point reward is the L1 distance to them. Here: the palm site is placed
``CLEARANCE`` above the top centre of the object, palm facing down as far as the four joints
allow (in the null space of the position task), by damped least squares from many starts,
within the model's joint limits. The hand must not touch any object in that pose (checked).

Run once, from the repository root:  ``python assets/make_pointing_configs.py``
"""

from __future__ import annotations

import json
import pathlib
import sys

import mujoco
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))
from grounding_jax import ik, scene  # noqa: E402

CLEARANCE = 0.01  # metres between the palm site and the object's top


def _nearest_samples(target: np.ndarray, rng: np.random.Generator, n: int = 20) -> np.ndarray:
    """Starts for the local solver: the random joint samples whose palm lands nearest."""
    m = scene.model()
    idx = scene.index()
    d = mujoco.MjData(m)
    d.qpos[:] = scene.home_qpos()
    qs = rng.uniform(idx.joint_range[:, 0], idx.joint_range[:, 1], size=(20000, 4))
    dist = np.empty(len(qs))
    for i, q in enumerate(qs):
        d.qpos[idx.arm_qpos] = q
        mujoco.mj_kinematics(m, d)
        dist[i] = np.linalg.norm(d.site_xpos[m.site("palm").id] - target)
    return qs[np.argsort(dist)[:n]]


def main() -> None:
    m = scene.model()
    idx = scene.index()
    rng = np.random.default_rng(0)
    out = {"clearance_m": CLEARANCE, "site": "palm", "positions": {}}
    d = mujoco.MjData(m)
    for p, name in enumerate(scene.POSITIONS):
        target = scene.object_positions()[p] + np.array([0, 0, scene.OBJECT_HALF + CLEARANCE])
        best = None
        starts = [np.radians(scene.HOME_POSE_DEG)] + list(_nearest_samples(target, rng))
        for q0 in starts:
            q, err = ik.solve(target, q0)
            d.qpos[:] = scene.home_qpos()
            d.qpos[idx.arm_qpos] = q
            mujoco.mj_forward(m, d)
            down = float(-ik.palm_down_error(d, m.site("palm").id)[2] + 1.0)  # cos to down
            touching = int(d.sensordata[idx.sensor_contact].sum())
            score = err + 0.02 * (1.0 - down) + (1.0 if touching else 0.0)
            if best is None or score < best[0]:
                best = (score, q, err, down, touching, d.site_xpos[m.site("palm").id].copy())
        _, q, err, down, touching, palm = best
        print(f"{name}: joints {np.degrees(q).round(2)} deg, palm error {err * 1000:.1f} mm, "
              f"palm-down cosine {down:.2f}, touching {touching}")
        out["positions"][name] = {
            "joints_deg": [round(float(v), 4) for v in np.degrees(q)],
            "palm_xyz_m": [round(float(v), 5) for v in palm],
            "target_xyz_m": [round(float(v), 5) for v in target],
            "palm_error_m": round(err, 5),
            "palm_down_cosine": round(down, 4),
        }
    scene.POINTING_JSON.write_text(json.dumps(out, indent=2) + "\n")
    print("wrote", scene.POINTING_JSON)


if __name__ == "__main__":
    main()
