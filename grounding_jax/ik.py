"""Inverse kinematics of the palm site (C MuJoCo, NumPy): for stored poses and scripted paths."""

from __future__ import annotations

import mujoco
import numpy as np

from grounding_jax import scene

ORIENT_GAIN = 0.5  # step on the palm-down error, inside the position task's null space


def palm_down_error(d: mujoco.MjData, site: int) -> np.ndarray:
    """Palm normal (-y of the hand frame) minus world down."""
    normal = -d.site_xmat[site].reshape(3, 3)[:, 1]
    return normal - np.array([0.0, 0.0, -1.0])


def solve(target: np.ndarray, q0: np.ndarray, iters: int = 400) -> tuple[np.ndarray, float]:
    """Place the palm site at ``target`` with the four arm joints, palm down where possible.

    Damped least squares on position; the palm-down objective acts only in the position
    task's null space. Joint limits are the model's.

    Args:
        target: palm position in the world frame (metres).
        q0: start joint angles (radians, 4).
        iters: iterations.

    Returns:
        (joint angles in radians, remaining position error in metres).
    """
    m = scene.model()
    idx = scene.index()
    d = mujoco.MjData(m)
    d.qpos[:] = scene.home_qpos()
    site = m.site("palm").id
    lo, hi = idx.joint_range[:, 0], idx.joint_range[:, 1]
    q = np.clip(np.asarray(q0, float).copy(), lo, hi)
    jacp = np.zeros((3, m.nv))
    jacr = np.zeros((3, m.nv))
    for _ in range(iters):
        d.qpos[idx.arm_qpos] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        err_p = target - d.site_xpos[site]
        err_o = palm_down_error(d, site)
        mujoco.mj_jacSite(m, d, jacp, jacr, site)
        jp = jacp[:, idx.arm_dof]
        normal = -d.site_xmat[site].reshape(3, 3)[:, 1]
        jo = np.cross(jacr[:, idx.arm_dof].T, normal).T  # d(normal)/dq_i = jacr_i x normal
        jpinv = jp.T @ np.linalg.inv(jp @ jp.T + 1e-5 * np.eye(3))
        null = np.eye(4) - jpinv @ jp
        dq = jpinv @ err_p - ORIENT_GAIN * null @ (jo.T @ err_o)
        q = np.clip(q + 0.5 * dq, lo, hi)
    d.qpos[idx.arm_qpos] = q
    mujoco.mj_kinematics(m, d)
    return q, float(np.linalg.norm(target - d.site_xpos[site]))


def palm_position(q: np.ndarray) -> np.ndarray:
    """World position of the palm site for arm joints ``q`` (radians)."""
    m = scene.model()
    d = mujoco.MjData(m)
    d.qpos[:] = scene.home_qpos()
    d.qpos[scene.index().arm_qpos] = q
    mujoco.mj_kinematics(m, d)
    return d.site_xpos[m.site("palm").id].copy()
