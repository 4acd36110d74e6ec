"""The C MuJoCo backend's rollout wrapper against a plain mj_step loop."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from grounding_jax.sim import physics, scene


def test_rollout_runner_equals_a_plain_mj_step_loop():
    m = scene.model()
    idx = scene.index()
    rng = np.random.default_rng(0)
    qpos = np.tile(scene.home_qpos(), (5, 1))
    qpos[:, idx.arm_qpos] += rng.uniform(-0.2, 0.2, (5, 4))
    qvel = np.zeros((5, m.nv))
    qvel[:, idx.arm_dof] = rng.uniform(-0.5, 0.5, (5, 4))
    ctrl = qpos[:, idx.arm_qpos] + rng.uniform(-0.1, 0.1, (5, 4))
    q1, v1, s1 = physics.mujoco_runner().step(qpos.astype(np.float32), qvel.astype(np.float32),
                                              ctrl.astype(np.float32), 7)
    d = mujoco.MjData(m)
    for i in range(5):
        d.qpos[:] = qpos[i].astype(np.float32)
        d.qvel[:] = qvel[i].astype(np.float32)
        d.ctrl[:] = ctrl[i].astype(np.float32)
        d.qacc_warmstart[:] = 0.0
        d.time = 0.0
        for _ in range(7):
            mujoco.mj_step(m, d)
        np.testing.assert_allclose(q1[i], d.qpos, atol=1e-6)
        np.testing.assert_allclose(v1[i], d.qvel, atol=1e-5)
        np.testing.assert_allclose(s1[i], d.sensordata, atol=1e-5)
    assert not np.allclose(q1[0], qpos[0])  # it did move


def test_unknown_backend_names_the_accepted_values():
    with pytest.raises(ValueError, match=r"backend: unknown value 'bullet'.*'mujoco', 'mjx'"):
        physics.make_physics("bullet", 10)


def _batch(lead: tuple[int, ...], seed: int = 0):
    m, idx = scene.model(), scene.index()
    rng = np.random.default_rng(seed)
    qpos = np.broadcast_to(scene.home_qpos(), lead + (m.nq,)).astype(np.float32).copy()
    qpos[..., idx.arm_qpos] += rng.uniform(-0.2, 0.2, lead + (4,)).astype(np.float32)
    qvel = np.zeros(lead + (m.nv,), np.float32)
    ctrl = qpos[..., idx.arm_qpos] + rng.uniform(-0.1, 0.1, lead + (4,)).astype(np.float32)
    return qpos, qvel, ctrl


def test_jax_step_through_the_ffi_target_equals_the_runner_and_skips_dead_rows():
    import jax

    step, forward = physics.make_physics("mujoco", 7)
    qpos, qvel, ctrl = _batch((2, 3))
    live = np.array([[True, False, True], [False, True, True]])
    q, v, s = jax.jit(jax.vmap(step))(qpos, qvel, ctrl, live)  # vmap: the batch rule too
    q1, v1, s1 = physics.mujoco_runner().step(qpos, qvel, ctrl, 7, live)
    np.testing.assert_array_equal(np.asarray(q), q1)
    np.testing.assert_array_equal(np.asarray(v), v1)
    np.testing.assert_array_equal(np.asarray(s), s1)
    np.testing.assert_array_equal(np.asarray(q)[~live], qpos[~live])  # dead rows: unchanged
    assert not np.allclose(np.asarray(q)[live], qpos[live])
    sens = jax.jit(forward)(qpos, qvel, live)
    np.testing.assert_array_equal(np.asarray(sens), physics.mujoco_runner().forward(
        qpos, qvel, live))
    text = jax.jit(step).lower(qpos, qvel, ctrl).as_text()
    # a named target, not a host callback: such programs go to JAX's persistent cache
    assert physics.STEP_TARGET in text and "callback" not in text


def test_an_error_inside_an_ffi_handler_reaches_the_caller():
    import jax
    import jax.numpy as jnp

    from grounding_jax.sim import _ffi

    def handler(ins, outs, attrs):
        raise ValueError(f"bad rows: {ins[0].shape}, rows={attrs['rows']}")

    _ffi.register("grounding_jax_test_raise", handler)
    call = jax.ffi.ffi_call("grounding_jax_test_raise", jax.ShapeDtypeStruct((2,), jnp.float32))
    with pytest.raises(Exception, match=r"ValueError: bad rows: \(2, 3\), rows=7"):
        jax.block_until_ready(jax.jit(lambda x: call(x, rows=np.int64(7)))(jnp.ones((2, 3))))


def _compiled_built() -> bool:
    import importlib.util

    return importlib.util.find_spec("grounding_jax.sim._mjstep") is not None


@pytest.mark.skipif(not _compiled_built(), reason="the compiled step was not built here (no "
                    "C++ compiler at install): the ctypes handler runs instead")
def test_the_compiled_step_is_used_where_built_and_its_engine_equals_the_runner():
    assert physics.step_handler() == "compiled"
    native = physics.mujoco_runner().meter.native
    qpos, qvel, ctrl = _batch((6,), seed=3)
    state = np.concatenate([np.zeros((6, 1)), qpos, qvel], axis=1)
    y = native.run(state, ctrl.astype(np.float64), 9)
    q1, v1, s1 = physics.mujoco_runner().step(qpos, qvel, ctrl, 9)
    nq, nv = scene.index().nq, scene.index().nv
    np.testing.assert_array_equal(y[:, :nq], q1)
    np.testing.assert_array_equal(y[:, nq:nq + nv], v1)
    np.testing.assert_array_equal(y[:, nq + nv:], s1)
    # its counters: the live rows each call simulated
    import jax

    step, _ = physics.make_physics("mujoco", 4)
    before = physics.mujoco_runner().meter.totals()[4]
    jax.block_until_ready(jax.jit(step)(qpos, qvel, ctrl, np.arange(6) % 2 == 0))
    assert physics.mujoco_runner().meter.totals()[4] - before == 3


def test_the_ctypes_fallback_gives_the_same_physics_and_a_bad_choice_is_named(tmp_path):
    import subprocess
    import sys

    script = tmp_path / "fallback.py"
    script.write_text(
        "import jax, numpy as np\n"
        "from grounding_jax.sim import physics\n"
        "step, _ = physics.make_physics('mujoco', 7)\n"
        "rng = np.random.default_rng(0)\n"
        "x = [np.load(f) for f in ('q.npy', 'v.npy', 'u.npy')]\n"
        "q, v, s = jax.jit(step)(*x)\n"
        "np.save('out.npy', np.concatenate([q, v, s], axis=-1))\n"
        "print(physics.step_handler())\n")
    qpos, qvel, ctrl = _batch((5,), seed=1)
    for name, a in (("q", qpos), ("v", qvel), ("u", ctrl)):
        np.save(tmp_path / f"{name}.npy", a)
    import os

    env = {**os.environ, "GROUNDING_JAX_PHYSICS_HANDLER": "python"}
    run = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().splitlines()[-1] == "python"
    q1, v1, s1 = physics.mujoco_runner().step(qpos, qvel, ctrl, 7)
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"),
                                  np.concatenate([q1, v1, s1], axis=-1))
    env["GROUNDING_JAX_PHYSICS_HANDLER"] = "fortran"
    bad = subprocess.run([sys.executable, "-c", "from grounding_jax.sim import physics; "
                          "physics.handler_choice()"], env=env, capture_output=True, text=True,
                         timeout=120)
    assert bad.returncode != 0
    assert ("GROUNDING_JAX_PHYSICS_HANDLER: unknown value 'fortran'; accepted values: "
            "('auto', 'compiled', 'python')") in bad.stderr


@pytest.mark.skipif(not _compiled_built(), reason="the compiled step was not built here")
def test_the_compiled_step_still_runs_in_a_forked_child(tmp_path):
    import subprocess
    import sys

    script = tmp_path / "fork.py"
    script.write_text(
        "import os, numpy as np\n"
        "from grounding_jax.sim import physics, scene\n"
        "assert physics.step_handler() == 'compiled'\n"
        "native = physics.mujoco_runner().meter.native\n"
        "q = np.tile(scene.home_qpos(), (4, 1))\n"
        "state = np.concatenate([np.zeros((4, 1)), q, np.zeros((4, scene.index().nv))], 1)\n"
        "ctrl = q[:, scene.index().arm_qpos] + 0.1\n"
        "before = native.run(state, ctrl, 5)\n"
        "pid = os.fork()\n"
        "if pid == 0:\n"
        "    os._exit(0 if np.array_equal(native.run(state, ctrl, 5), before) else 3)\n"
        "_, status = os.waitpid(pid, 0)\n"
        "print('child', os.waitstatus_to_exitcode(status))\n")
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().splitlines()[-1] == "child 0"
