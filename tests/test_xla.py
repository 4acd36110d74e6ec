"""The physics programs' compiler options: CPU C MuJoCo only, and the same numbers bit for bit."""

import jax
import numpy as np

import grounding_jax as gj
from grounding_jax.core import xla
from grounding_jax.paper import al_eval
from grounding_jax.sim import rollout, scripted


def test_options_only_for_c_mujoco_on_the_cpu(env_c, env_mjx):
    on_cpu = jax.default_backend() == "cpu"
    expected = xla.CPU_PHYSICS_OPTIONS if on_cpu else None
    assert xla.physics_options(env_c) == expected
    assert xla.physics_options(env_c.config) == expected
    assert xla.physics_options("mujoco") == expected
    assert xla.physics_options(env_mjx) is None
    assert xla.physics_options("mjx") is None
    # a copy: a caller editing its options cannot change the package's
    got = xla.physics_options("mujoco")
    if got is not None:
        got["xla_backend_optimization_level"] = 3
        assert xla.CPU_PHYSICS_OPTIONS["xla_backend_optimization_level"] == 1


def test_physics_jit_gives_the_default_programs_numbers(env_c, run_c, push_waypoints):
    """A whole scripted push episode, compiled with and without the options, bit for bit."""

    def run(waypoints, task, params):
        policy = lambda s: scripted.tracking_action(waypoints, s.step, s.obs)  # noqa: E731
        return rollout.run_episode(env_c, jax.random.key(0), task, policy, params)

    task, params = gj.make_task("push", "left", 0), gj.EnvParams()
    fast = xla.physics_jit(run, env_c)(push_waypoints[0], task, params)
    plain = run_c(push_waypoints[0], task, params)
    for a, b in zip(jax.tree.leaves(fast), jax.tree.leaves(plain), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_success_functions_of_one_env_share_a_program(env_c):
    al_eval.make_success(env_c, layouts=(0,))
    built = len(al_eval._PROGRAMS)
    al_eval.make_success(env_c, layouts=(1, 2))
    al_eval.make_success(gj.make_env("mujoco"), layouts=(0,), actions=(1,))
    assert len(al_eval._PROGRAMS) == built
    al_eval.make_success(env_c, starts=2)
    assert len(al_eval._PROGRAMS) == built + 1
