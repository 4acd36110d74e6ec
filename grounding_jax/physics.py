"""Two physics backends behind one pure functional interface.

Both advance a batch of scenes by ``substeps`` MuJoCo steps with a constant control and return
the new ``(qpos, qvel)`` and the sensor readings of the last substep:

- ``"mjx"``: pure JAX (``mujoco.mjx``), the path for GPUs;
- ``"mujoco"``: C MuJoCo through a persistent ``mujoco.rollout.Rollout`` thread pool, called
  from JAX with ``jax.pure_callback``, the fast path on CPUs.

The physics state carried between RL steps is only ``qpos, qvel`` (float32). The solver's warm
start is reset to zero at each RL step on both backends, so a step depends only on its inputs
(and the two backends see the same problem).
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from grounding_jax import scene

BACKENDS = ("mujoco", "mjx")

StepFn = Callable[..., tuple[jax.Array, jax.Array, jax.Array]]
ForwardFn = Callable[..., jax.Array]


def check_backend(backend: str) -> str:
    """Return ``backend`` or raise a ValueError naming the accepted values."""
    if backend not in BACKENDS:
        raise ValueError(f"backend: unknown value {backend!r}; accepted values: {BACKENDS}")
    return backend


# --------------------------------------------------------------------------- C MuJoCo backend
class _MujocoRunner:
    """Holds the C model, one MjData per thread and the persistent rollout pool."""

    def __init__(self, nthread: int) -> None:
        from mujoco import rollout

        self.model = scene.model()
        self.nthread = nthread
        self.datas = [mujoco.MjData(self.model) for _ in range(nthread)]
        self.pool = rollout.Rollout(nthread=nthread if nthread > 1 else 0)
        self.lock = threading.Lock()  # the pool and the MjData are not re-entrant
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self.nstate = mujoco.mj_stateSize(self.model, spec)
        m = self.model
        # FULLPHYSICS = time, qpos, qvel (+ act, mocap, eq_active, ... which this scene lacks)
        if self.nstate != 1 + m.nq + m.nv:
            raise RuntimeError(f"unexpected physics state size {self.nstate} for this scene")

    def step(self, qpos: np.ndarray, qvel: np.ndarray, ctrl: np.ndarray, substeps: int,
             live: np.ndarray | None = None):
        """Simulate the rows where ``live`` (all if None); other rows come back unchanged
        with zero sensor data (the env discards them: finished episodes cost no physics)."""
        m = self.model
        lead = qpos.shape[:-1]
        qp = np.asarray(qpos, np.float32).reshape(-1, m.nq)
        qv = np.asarray(qvel, np.float32).reshape(-1, m.nv)
        u = np.asarray(ctrl, np.float64).reshape(-1, 1, m.nu)
        rows = np.arange(qp.shape[0]) if live is None else np.flatnonzero(np.ravel(live))
        qp_out, qv_out = qp.copy(), qv.copy()
        sens_out = np.zeros((qp.shape[0], m.nsensordata), np.float32)
        if rows.size:
            n = rows.size
            state0 = np.concatenate([np.zeros((n, 1)), qp[rows], qv[rows]], axis=1)
            with self.lock:
                states, sensors = self.pool.rollout(
                    m, self.datas, state0.astype(np.float64), u[rows], nstep=substeps,
                    initial_warmstart=np.zeros((n, m.nv)),
                )
            last = states[:, -1]
            qp_out[rows] = last[:, 1 : 1 + m.nq]
            qv_out[rows] = last[:, 1 + m.nq :]
            sens_out[rows] = sensors[:, -1]
        return (qp_out.reshape(*lead, m.nq), qv_out.reshape(*lead, m.nv),
                sens_out.reshape(*lead, m.nsensordata))

    def forward(self, qpos: np.ndarray, qvel: np.ndarray,
                live: np.ndarray | None = None) -> np.ndarray:
        """Sensor data of the rows where ``live`` (all if None); other rows are zero."""
        m = self.model
        lead = qpos.shape[:-1]
        qp = np.asarray(qpos, np.float64).reshape(-1, m.nq)
        qv = np.asarray(qvel, np.float64).reshape(-1, m.nv)
        rows = np.arange(qp.shape[0]) if live is None else np.flatnonzero(np.ravel(live))
        out = np.zeros((qp.shape[0], m.nsensordata), np.float32)
        with self.lock:
            d = self.datas[0]
            for i in rows:
                d.qpos[:] = qp[i]
                d.qvel[:] = qv[i]
                d.ctrl[:] = qp[i, scene.index().arm_qpos]
                d.qacc_warmstart[:] = 0.0
                mujoco.mj_forward(m, d)
                out[i] = d.sensordata
        return out.reshape(*lead, m.nsensordata)


@functools.cache
def mujoco_runner(nthread: int | None = None) -> _MujocoRunner:
    """The process-wide C MuJoCo runner (its thread pool is created once and kept)."""
    if nthread is None:
        nthread = int(os.environ.get("GROUNDING_JAX_THREADS", os.cpu_count() or 1))
    return _MujocoRunner(nthread)


def _mujoco_fns(substeps: int) -> tuple[StepFn, ForwardFn]:
    idx = scene.index()
    f32 = jnp.float32
    nq, nv = idx.nq, idx.nv
    # Each callback takes one array and returns one: JAX's callback machinery costs per
    # array (~120 us for one on this CPU, ~240 us for four), which is paid at every RL step.

    def run_step(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x)  # the callback is handed a jax.Array: slice it as NumPy
        q, v, u, live = np.split(x, [nq, nq + nv, x.shape[-1] - 1], axis=-1)
        out = mujoco_runner().step(q, v, u, substeps, live[..., 0] > 0.5)
        return np.concatenate(out, axis=-1)

    def run_forward(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x)
        q, v, live = np.split(x, [nq, nq + nv], axis=-1)
        return mujoco_runner().forward(q, v, live[..., 0] > 0.5)

    def flag(live, lead):
        live = jnp.ones(lead, bool) if live is None else live
        return live.astype(f32)[..., None]

    def step(qpos, qvel, ctrl, live=None):
        lead = qpos.shape[:-1]
        x = jnp.concatenate([qpos, qvel, ctrl.astype(f32), flag(live, lead)], axis=-1)
        shape = jax.ShapeDtypeStruct(lead + (nq + nv + idx.nsensordata,), f32)
        y = jax.pure_callback(run_step, shape, x, vmap_method="broadcast_all")
        return y[..., :nq], y[..., nq:nq + nv], y[..., nq + nv:]

    def forward(qpos, qvel, live=None):
        lead = qpos.shape[:-1]
        x = jnp.concatenate([qpos, qvel, flag(live, lead)], axis=-1)
        shape = jax.ShapeDtypeStruct(lead + (idx.nsensordata,), f32)
        return jax.pure_callback(run_forward, shape, x, vmap_method="broadcast_all")

    return step, forward


# -------------------------------------------------------------------------------- MJX backend
@functools.cache
def mjx_model():
    """The scene as an MJX model (device arrays), made once per process."""
    from mujoco import mjx

    return mjx.put_model(scene.model())


def _mjx_fns(substeps: int) -> tuple[StepFn, ForwardFn]:
    from mujoco import mjx

    mx = mjx_model()
    idx = scene.index()

    def _data(qpos, qvel):
        d = mjx.make_data(mx)
        return d.replace(qpos=qpos, qvel=qvel, ctrl=qpos[idx.arm_qpos])

    def step(qpos, qvel, ctrl, live=None):
        del live  # vectorized: every row is computed anyway; the env discards finished ones
        d = _data(qpos, qvel).replace(ctrl=ctrl)
        d = jax.lax.fori_loop(0, substeps, lambda _, x: mjx.step(mx, x), d)
        return d.qpos, d.qvel, d.sensordata

    def forward(qpos, qvel, live=None):
        del live  # as in step: every row is computed
        return mjx.forward(mx, _data(qpos, qvel)).sensordata

    return step, forward


def make_physics(backend: str, substeps: int) -> tuple[StepFn, ForwardFn]:
    """The backend's ``step(qpos, qvel, ctrl, live=None) -> (qpos, qvel, sensordata)`` and
    ``forward(qpos, qvel, live=None) -> sensordata``, both pure JAX functions
    (jit/vmap/scan-safe). ``live`` (bool per scene) lets the C backend skip scenes whose
    episode has ended (or, for ``forward``, that do not start one); their outputs are then
    meaningless and must be discarded by the caller.

    Args:
        backend: ``"mujoco"`` (C MuJoCo rollouts, CPU) or ``"mjx"`` (pure JAX).
        substeps: MuJoCo steps per call, with the control held constant.

    Returns:
        ``(step, forward)``.
    """
    check_backend(backend)
    if backend == "mujoco":
        return _mujoco_fns(substeps)
    return _mjx_fns(substeps)
