"""Two physics backends behind one pure functional interface.

Both advance a batch of scenes by ``substeps`` MuJoCo steps with a constant control and return
the new ``(qpos, qvel)`` and the sensor readings of the last substep:

- ``"mjx"``: pure JAX (``mujoco.mjx``), the path for GPUs;
- ``"mujoco"``: C MuJoCo through a persistent ``mujoco.rollout.Rollout`` thread pool, called
  from JAX as a named XLA FFI target (``_ffi``), the fast path on CPUs.

The physics state carried between RL steps is only ``qpos, qvel`` (float32). The solver's warm
start is reset to zero at each RL step on both backends, so a step depends only on its inputs
(and the two backends see the same problem).
"""

from __future__ import annotations

import atexit
import collections
import ctypes as C
import functools
import glob
import os
import threading
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from grounding_jax.sim import _ffi, scene

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
        self.meter = PhysicsMeter(m.nq, m.nv, m.nu)

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
                self.meter.sample(state0, u[rows, 0], substeps)
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


class PhysicsMeter:
    """Counts the RL steps the C backend simulates and keeps a uniform sample of them (a
    reservoir of ``keep`` rows drawn from every 16th call), to measure the rollout-alone
    ceiling on the very physics a run simulated (`ceiling`). Its random draws are its
    own: they do not touch any run's keys."""

    EVERY = 16

    def __init__(self, nq: int, nv: int, nu: int, keep: int = 4096) -> None:
        self.rl_steps: collections.Counter[int] = collections.Counter()  # substeps -> steps
        self.calls = 0
        self._state = np.zeros((keep, 1 + nq + nv))
        self._ctrl = np.zeros((keep, nu))
        self._substeps = np.zeros(keep, np.int64)
        self._seen = self._filled = 0
        self._rng = np.random.default_rng(0)
        self.native: _Native | None = None  # the compiled handler's own counters, if in use

    def sample(self, state0: np.ndarray, ctrl: np.ndarray, substeps: int) -> None:
        """Count a call's rows; offer them to the reservoir if it is a sampled call."""
        self.rl_steps[substeps] += len(state0)
        self.calls += 1
        if self.calls % self.EVERY:
            return
        keep = len(self._state)
        for row in range(len(state0)):
            self._seen += 1
            if self._filled < keep:
                i = self._filled
                self._filled += 1
            else:
                i = int(self._rng.integers(self._seen))
                if i >= keep:
                    continue
            self._state[i], self._ctrl[i], self._substeps[i] = state0[row], ctrl[row], substeps

    def totals(self) -> collections.Counter[int]:
        """RL steps simulated so far by substeps, through either handler."""
        out = collections.Counter(self.rl_steps)
        if self.native is not None:
            counts = self.native.read(samples=False)[1]
            out.update({k: int(v) for k, v in counts.items() if v})
        return out

    def _samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self._filled
        state, ctrl, sub = self._state[:n], self._ctrl[:n], self._substeps[:n]
        if self.native is not None:
            _, _, (s2, c2, u2) = self.native.read(samples=True)
            state, ctrl, sub = (np.concatenate(p) for p in ((state, s2), (ctrl, c2),
                                                            (sub, u2)))
        return state, ctrl, sub

    def ceiling(self, runner: _MujocoRunner, batch: int = 256, repeats: int = 2
                ) -> float | None:
        """`ceiling` on the sampled rows (None when nothing was sampled)."""
        return ceiling(runner, *self._samples(), batch=batch, repeats=repeats,
                       native=self.native)


def ceiling(runner: _MujocoRunner, state: np.ndarray, ctrl: np.ndarray, substeps: np.ndarray,
            batch: int = 256, repeats: int = 2, native: _Native | None = None
            ) -> float | None:
    """RL steps per second of the physics alone on rows ``state`` (time, qpos, qvel),
    ``ctrl`` and ``substeps`` (per row), in full batches of ``batch``: ``mujoco.rollout`` on
    the runner's thread pool, or the compiled step ``native`` where given and faster (best of
    ``repeats``); None for no rows."""
    n = len(state)
    if n == 0:
        return None
    m = runner.model

    def rollout(take: np.ndarray, sub: int) -> None:
        with runner.lock:
            runner.pool.rollout(m, runner.datas, state[take], ctrl[take][:, None],
                                nstep=sub, initial_warmstart=np.zeros((len(take), m.nv)))

    engines = [rollout]
    if native is not None:  # the compiled step alone: where it is faster, the floor
        engines.append(lambda take, sub: native.run(state[take], ctrl[take], sub))
    best = np.inf
    for _ in range(repeats):
        for engine in engines:
            t = time.perf_counter()
            for sub in np.unique(substeps):
                rows = np.flatnonzero(substeps == sub)
                for i in range(0, len(rows), batch):
                    engine(rows[i:i + batch], int(sub))
            best = min(best, time.perf_counter() - t)
    return n / best


@functools.cache
def mujoco_runner(nthread: int | None = None) -> _MujocoRunner:
    """The process-wide C MuJoCo runner (its thread pool is created once and kept)."""
    if nthread is None:
        nthread = int(os.environ.get("GROUNDING_JAX_THREADS", os.cpu_count() or 1))
    return _MujocoRunner(nthread)


class _Native:
    """The compiled step handler (``_mjstep``, built when the package installs), set up on
    its own MjData per thread by `step_handler` where it was built."""

    KEEP = 4096

    def __init__(self, lib: C.CDLL, model: mujoco.MjModel, nthread: int) -> None:
        self.lib, self.model = lib, model
        self.datas = [mujoco.MjData(model) for _ in range(max(nthread, 1))]
        so = glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco.so*"))
        mj = C.CDLL(so[0]) if so else C.CDLL(None)
        warn = self.datas[0].warning.number
        sizes = (C.c_int * 6)(model.nq, model.nv, model.nu, model.nsensordata, len(warn),
                              warn.strides[0] // warn.itemsize)
        st = mujoco.mjtState
        specs = (C.c_uint * 3)(int(st.mjSTATE_FULLPHYSICS), int(st.mjSTATE_CTRL),
                               int(st.mjSTATE_WARMSTART))
        n = len(self.datas)
        datas = (C.c_void_p * n)(*[d._address for d in self.datas])
        sens = (C.c_void_p * n)(*[d.sensordata.ctypes.data for d in self.datas])
        warns = (C.c_void_p * n)(*[d.warning.number.ctypes.data for d in self.datas])
        fn = [C.cast(getattr(mj, f), C.c_void_p) for f in ("mj_step", "mj_setState",
                                                          "mj_getState")]
        lib.gj_setup.restype = C.c_int
        rc = lib.gj_setup(C.c_void_p(model._address), sizes, specs, self.KEEP, *fn, n, datas,
                          sens, warns)
        if rc != 0:
            raise RuntimeError("the compiled physics step could not be set up (a batch was "
                               "in flight)")
        self._keep = (datas, sens, warns)  # the addresses stay valid while these live
        atexit.register(lib.gj_shutdown)

    def run(self, state: np.ndarray, ctrl: np.ndarray, substeps: int) -> np.ndarray:
        """The compiled step alone on rows ``state`` (time, qpos, qvel) and ``ctrl``
        (uncounted): ``[rows, nq + nv + nsensordata]`` float32."""
        m = self.model
        x = np.concatenate([state[:, 1:], ctrl, np.ones((len(state), 1))], axis=1)
        x = np.ascontiguousarray(x, np.float32)
        y = np.zeros((len(x), m.nq + m.nv + m.nsensordata), np.float32)
        rc = self.lib.gj_run(x.ctypes.data_as(C.c_void_p), y.ctypes.data_as(C.c_void_p),
                             C.c_int64(len(x)), C.c_int(substeps))
        if rc != 0:
            raise RuntimeError("the compiled physics step is not set up")
        return y

    def reset(self) -> None:
        """Zero the counters and empty the sample."""
        self.lib.gj_reset_meter()

    def read(self, samples: bool) -> tuple[dict, dict[int, int], tuple]:
        """(calls and seconds, RL steps by substeps, the sampled rows if ``samples``)."""
        m = self.model
        info = np.zeros(3, np.int64)
        counts = np.zeros(64, np.int64)
        ptr = lambda a: a.ctypes.data_as(C.c_void_p)  # noqa: E731
        if samples:
            n = self.KEEP
            state = np.zeros((n, 1 + m.nq + m.nv))
            ctrl = np.zeros((n, m.nu))
            sub = np.zeros(n, np.int32)
            self.lib.gj_meter(ptr(info), ptr(counts), ptr(state), ptr(ctrl), ptr(sub))
            k = int(info[2])
            rows = (state[:k], ctrl[:k], sub[:k].astype(np.int64))
        else:
            self.lib.gj_meter(ptr(info), ptr(counts), None, None, None)
            rows = ()
        meta = {"calls": int(info[0]), "seconds": info[1] / 1e9}
        return meta, {i: int(c) for i, c in enumerate(counts) if c and i}, rows


#: ``GROUNDING_JAX_PHYSICS_HANDLER``: ``auto`` (default: the compiled handler where it was
#: built, else ``ctypes``), ``compiled`` (an error where it was not built) or ``python``.
HANDLERS = ("auto", "compiled", "python")


def handler_choice() -> str:
    """The step handler asked for by ``GROUNDING_JAX_PHYSICS_HANDLER`` (checked)."""
    choice = os.environ.get("GROUNDING_JAX_PHYSICS_HANDLER", "auto").lower() or "auto"
    if choice not in HANDLERS:
        raise ValueError(f"GROUNDING_JAX_PHYSICS_HANDLER: unknown value {choice!r}; accepted "
                         f"values: {HANDLERS}")
    return choice


@functools.cache
def step_handler() -> str:
    """Register the C backend's step target once per process and say which handler it is:
    ``"compiled"`` (``_mjstep``) or ``"python"`` (``ctypes``, the fallback)."""
    choice = handler_choice()
    runner = mujoco_runner()
    if choice != "python":
        try:
            from grounding_jax.sim import _mjstep
        except ImportError:
            if choice == "compiled":
                raise RuntimeError("GROUNDING_JAX_PHYSICS_HANDLER=compiled: the compiled step "
                                   "(grounding_jax/sim/_mjstep.cc) was not built; reinstall "
                                   "with a C++ compiler present") from None
        else:
            lib = C.CDLL(_mjstep.__file__)
            lib.gj_step_handler.restype = C.c_void_p
            runner.meter.native = _Native(lib, runner.model, runner.nthread)
            capsule = jax.ffi.pycapsule(C.cast(lib.gj_step_handler(), C.CFUNCTYPE(C.c_void_p)))
            _ffi.register(STEP_TARGET, capsule=capsule)
            return "compiled"
    _ffi.register(STEP_TARGET, _step_handler)
    return "python"


STEP_TARGET = "grounding_jax_mujoco_step"
FORWARD_TARGET = "grounding_jax_mujoco_forward"


def _split(x: np.ndarray, sizes: list[int]) -> list[np.ndarray]:
    return np.split(x, np.cumsum(sizes)[:-1], axis=-1)


def _step_handler(ins: list[np.ndarray], outs: list[np.ndarray], attrs: dict) -> None:
    idx = scene.index()
    q, v, u, live = _split(ins[0], [idx.nq, idx.nv, idx.nu, 1])
    res = mujoco_runner().step(q, v, u, int(attrs["substeps"]), live[..., 0] > 0.5)
    outs[0][...] = np.concatenate(res, axis=-1)


def _forward_handler(ins: list[np.ndarray], outs: list[np.ndarray], attrs: dict) -> None:
    idx = scene.index()
    q, v, live = _split(ins[0], [idx.nq, idx.nv, 1])
    outs[0][...] = mujoco_runner().forward(q, v, live[..., 0] > 0.5)


def _mujoco_fns(substeps: int) -> tuple[StepFn, ForwardFn]:
    idx = scene.index()
    f32 = jnp.float32
    nq, nv = idx.nq, idx.nv
    # C MuJoCo is called as a named XLA FFI target (``_ffi``), not through
    # ``jax.pure_callback``: those programs go to JAX's persistent cache. Each call takes one
    # array and returns one, so the per-array cost of crossing into Python is paid once.
    step_handler()
    _ffi.register(FORWARD_TARGET, _forward_handler)

    def flag(live, lead):
        live = jnp.ones(lead, bool) if live is None else live
        return live.astype(f32)[..., None]

    def step(qpos, qvel, ctrl, live=None):
        lead = qpos.shape[:-1]
        x = jnp.concatenate([qpos, qvel, ctrl.astype(f32), flag(live, lead)], axis=-1)
        shape = jax.ShapeDtypeStruct(lead + (nq + nv + idx.nsensordata,), f32)
        y = jax.ffi.ffi_call(STEP_TARGET, shape, vmap_method="broadcast_all")(
            x, substeps=np.int32(substeps))
        return y[..., :nq], y[..., nq:nq + nv], y[..., nq + nv:]

    def forward(qpos, qvel, live=None):
        lead = qpos.shape[:-1]
        x = jnp.concatenate([qpos, qvel, flag(live, lead)], axis=-1)
        shape = jax.ShapeDtypeStruct(lead + (idx.nsensordata,), f32)
        return jax.ffi.ffi_call(FORWARD_TARGET, shape, vmap_method="broadcast_all")(x)

    return step, forward


# -------------------------------------------------------------------------------- MJX backend
@functools.cache
def import_mjx():
    """``mujoco.mjx``, without the two "Failed to import warp" lines its import prints when
    the optional Warp backend is not installed (this package does not use it); anything else
    the import prints is passed on."""
    import contextlib
    import io

    heard = io.StringIO()
    with contextlib.redirect_stdout(heard):
        from mujoco import mjx
    for line in heard.getvalue().splitlines():
        if not line.startswith(("Failed to import warp", "Failed to import mujoco_warp")):
            print(line)
    return mjx


@functools.cache
def mjx_model():
    """The scene as an MJX model (device arrays), made once per process."""
    mjx = import_mjx()

    # concrete arrays even when first asked for inside a trace (e.g. ``jax.eval_shape`` of a
    # trainer): a cached tracer would leak into every later use
    with jax.ensure_compile_time_eval():
        return mjx.put_model(scene.model())


def _mjx_fns(substeps: int) -> tuple[StepFn, ForwardFn]:
    mjx = import_mjx()

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
