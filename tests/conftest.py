"""Shared, compiled-once fixtures: the suite compiles each env function once per session."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest

import grounding_jax as gj
from grounding_jax.sim import rollout, scripted

# share compiles between tests (and runs) as the CLIs do; CI points GROUNDING_JAX_CACHE at an
# empty folder
gj.enable_compilation_cache()


def _scripted_runner(env: gj.Env):
    def run(waypoints, task, params):
        policy = lambda s: scripted.tracking_action(waypoints, s.step, s.obs)  # noqa: E731
        return rollout.run_episode(env, jax.random.key(0), task, policy, params)

    return jax.jit(run)


@pytest.fixture(scope="session")
def renderer():
    """The eye camera's renderer; the test is skipped (and says why) without headless GL."""
    from grounding_jax.sim import vision

    try:
        return vision.eye_renderer()
    except RuntimeError as e:  # no headless GL here: say so, do not fake it
        pytest.skip(f"no headless OpenGL backend: {e}")


@pytest.fixture(scope="session")
def env_c() -> gj.Env:
    return gj.make_env("mujoco")


@pytest.fixture(scope="session")
def env_mjx() -> gj.Env:
    return gj.make_env("mjx")


@pytest.fixture(scope="session")
def run_c(env_c):
    return _scripted_runner(env_c)


@pytest.fixture(scope="session")
def run_mjx(env_mjx):
    return _scripted_runner(env_mjx)


@pytest.fixture(scope="session")
def push_waypoints():
    return {p: jnp.asarray(scripted.push_waypoints(p)) for p in range(3)}


#: the test files that take longest (the quick run, the sweeps): started first, so the
#: workers finish together
_FIRST = ("test_train.py", "test_sweep.py", "test_reliability.py", "test_backends.py")


def pytest_collection_modifyitems(config, items) -> None:
    rank = {name: i for i, name in enumerate(_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(_FIRST)))
