"""Scripted (non-learned) arm motions: for tests, benchmarks and the backend cross-check.

A script is a list of joint-space waypoints, one per RL step, found by IK on a Cartesian path
of the palm; `tracking_action` turns it into env actions by closed-loop tracking.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.sim import ik, scene
from grounding_jax.sim.env import scale_joints


@functools.cache
def push_waypoints(position: int, steps: int = 75) -> np.ndarray:
    """Joint targets ``[steps, 4]`` (radians) that push the object at ``position`` away.

    The palm rises from home, comes down behind the object (on the robot's side) at the
    object's mid height, then sweeps 0.13 m forward (away from the robot) through it.
    """
    centre = scene.object_positions()[position]
    behind = centre + np.array([0.08, 0.0, 0.005])
    through = centre + np.array([-0.05, 0.0, 0.005])
    high = behind + np.array([0.0, 0.0, 0.08])
    q_home = np.radians(scene.HOME_POSE_DEG)
    p_home = ik.palm_position(q_home)
    legs = [(p_home, high, 20), (high, behind, 15), (behind, through, steps - 35)]
    path = [a + (b - a) * (i + 1) / n for a, b, n in legs for i in range(n)]
    q = q_home
    out = []
    for target in path:
        q, _ = ik.solve(target, q, iters=60)
        out.append(q)
    return np.array(out)


def tracking_action(waypoints: jax.Array, step: jax.Array, obs: jax.Array,
                    gain: float = 3.0) -> jax.Array:
    """Action that moves the scaled joints toward ``waypoints[step]`` (clipped to [-1, 1])."""
    target = scale_joints(jnp.asarray(waypoints, jnp.float32))[
        jnp.minimum(step, waypoints.shape[0] - 1)]
    return jnp.clip(gain * (target - obs[:4]), -1.0, 1.0)
