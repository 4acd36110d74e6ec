"""Inverse kinematics of the palm site (C MuJoCo, NumPy): for stored poses and scripted paths."""

from __future__ import annotations

import mujoco
import numpy as np

from grounding_jax.sim import scene

ORIENT_GAIN = 0.5  # step on the palm-down error, inside the position task's null space


def palm_down_error(d: mujoco.MjData, site: int) -> np.ndarray:
    """Palm normal (-y of the hand frame) minus world down."""
    normal = -d.site_xmat[site].reshape(3, 3)[:, 1]
    return normal - np.array([0.0, 0.0, -1.0])


class _Palm:
    """The scene at home, for IK on the palm site: position and palm-down errors, Jacobians."""

    def __init__(self) -> None:
        self.m, self.idx = scene.model(), scene.index()
        self.d = mujoco.MjData(self.m)
        self.d.qpos[:] = scene.home_qpos()
        self.site = self.m.site("palm").id
        self.lo, self.hi = self.idx.joint_range[:, 0], self.idx.joint_range[:, 1]
        self.jacp = np.zeros((3, self.m.nv))
        self.jacr = np.zeros((3, self.m.nv))

    def terms(self, q: np.ndarray, target: np.ndarray):
        """(position error, palm-down error, position Jacobian, palm-normal Jacobian) at
        ``q``, all over the four arm joints."""
        m, d, idx = self.m, self.d, self.idx
        d.qpos[idx.arm_qpos] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        err_p = target - d.site_xpos[self.site]
        err_o = palm_down_error(d, self.site)
        mujoco.mj_jacSite(m, d, self.jacp, self.jacr, self.site)
        jp = self.jacp[:, idx.arm_dof]
        normal = -d.site_xmat[self.site].reshape(3, 3)[:, 1]
        jo = np.cross(self.jacr[:, idx.arm_dof].T, normal).T  # d(normal)/dq_i = jacr_i x normal
        return err_p, err_o, jp, jo

    def error(self, q: np.ndarray, target: np.ndarray) -> float:
        """Distance (metres) from the palm site at ``q`` to ``target``."""
        self.d.qpos[self.idx.arm_qpos] = q
        mujoco.mj_kinematics(self.m, self.d)
        return float(np.linalg.norm(target - self.d.site_xpos[self.site]))


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
    arm = _Palm()
    q = np.clip(np.asarray(q0, float).copy(), arm.lo, arm.hi)
    for _ in range(iters):
        err_p, err_o, jp, jo = arm.terms(q, target)
        jpinv = jp.T @ np.linalg.inv(jp @ jp.T + 1e-5 * np.eye(3))
        null = np.eye(4) - jpinv @ jp
        dq = jpinv @ err_p - ORIENT_GAIN * null @ (jo.T @ err_o)
        q = np.clip(q + 0.5 * dq, arm.lo, arm.hi)
    return q, arm.error(q, target)


def solve_near(target: np.ndarray, prior: np.ndarray, weight: float,
               orient_weight: float = 1e-5, iters: int = 200) -> tuple[np.ndarray, float]:
    """Place the palm site at ``target`` while staying near the pose ``prior``.

    Gauss-Newton on ``|target - palm(q)|^2 + orient_weight |palm-down error|^2
    + weight |scaled(q) - scaled(prior)|^2`` (metres; joints in the paper's scaled units),
    from ``prior``, within the model's joint limits. Where the arm can reach the target in
    several ways, the pull toward ``prior`` picks the one near it: a map of such poses is as
    smooth as its priors.

    Args:
        target: palm position in the world frame (metres).
        prior: the pose to stay near (radians, 4); also the start.
        weight: the pull toward ``prior`` (per scaled-joint unit squared).
        orient_weight: the pull toward palm down.
        iters: iterations.

    Returns:
        (joint angles in radians, remaining position error in metres).
    """
    arm = _Palm()
    lim = np.radians(scene.PAPER_LIMITS_DEG)
    s2 = (2.0 / (lim[:, 1] - lim[:, 0])) ** 2  # d(scaled)/dq, squared
    prior = np.clip(np.asarray(prior, float), arm.lo, arm.hi)
    q = prior.copy()
    for _ in range(iters):
        err_p, err_o, jp, jo = arm.terms(q, target)
        hess = jp.T @ jp + orient_weight * jo.T @ jo + np.diag(weight * s2 + 1e-9)
        grad = jp.T @ err_p - orient_weight * jo.T @ err_o + weight * s2 * (prior - q)
        q = np.clip(q + np.linalg.solve(hess, grad), arm.lo, arm.hi)
    return q, arm.error(q, target)


def _posed(q: np.ndarray, forward: bool = False) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The scene at home with the arm at joints ``q``: kinematics only, or a full forward
    pass (collision geometry for distances) when ``forward``."""
    m = scene.model()
    d = mujoco.MjData(m)
    d.qpos[:] = scene.home_qpos()
    d.qpos[scene.index().arm_qpos] = q
    (mujoco.mj_forward if forward else mujoco.mj_kinematics)(m, d)
    return m, d


def palm_position(q: np.ndarray) -> np.ndarray:
    """World position of the palm site for arm joints ``q`` (radians)."""
    m, d = _posed(q)
    return d.site_xpos[m.site("palm").id].copy()


def finger_ray(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fingertip position and the unit direction the fingers point in, for arm joints ``q``.

    The fingers are the ``fingers_col`` capsule; its end away from the palm is the tip.
    """
    m, d = _posed(q)
    g = m.geom("fingers_col").id
    axis = d.geom_xmat[g].reshape(3, 3)[:, 2] * m.geom_size[g][1]
    ends = d.geom_xpos[g] + axis, d.geom_xpos[g] - axis
    palm = d.geom_xpos[m.geom("palm_col").id]
    far = int(np.linalg.norm(ends[1] - palm) > np.linalg.norm(ends[0] - palm))
    direction = ends[far] - ends[1 - far]
    direction /= np.linalg.norm(direction)
    return ends[far] + direction * m.geom_size[g][0], direction


def clearance(q: np.ndarray) -> float:
    """Smallest distance (metres) between any arm capsule and any object, objects of layout
    0 at rest, for arm joints ``q``."""
    m, d = _posed(q, forward=True)
    fromto = np.zeros(6)
    return min(mujoco.mj_geomDistance(m, d, m.geom(a).id, m.geom(f"{s}_geom").id, 1.0, fromto)
               for a in scene.ARM_CAPSULES for s in scene.SHAPES)


def scaled(q: np.ndarray) -> np.ndarray:
    """Joint angles (radians) scaled to [-1, 1] by the paper's eq. 1 (NumPy)."""
    lim = np.radians(scene.PAPER_LIMITS_DEG)
    return 2.0 * (q - lim[:, 0]) / (lim[:, 1] - lim[:, 0]) - 1.0


def palm_ray(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Palm site position and the palm's normal (the way the open palm faces), for ``q``."""
    m, d = _posed(q)
    site = m.site("palm").id
    return d.site_xpos[site].copy(), -d.site_xmat[site].reshape(3, 3)[:, 1].copy()
