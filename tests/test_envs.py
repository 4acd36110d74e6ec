"""The env registry and its adapters: the ecosystem's shape, Brax's PPO and SAC trained on it,
gymnasium's env checker, and a base install that needs neither."""

from __future__ import annotations

import subprocess
import sys
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grounding_jax as gj
from grounding_jax import envs
from grounding_jax.learn import al


@pytest.fixture(scope="module")
def paper() -> envs.TaskEnv:
    return envs.load("paper")


@pytest.fixture(scope="module")
def stepped(paper):
    """reset and step, compiled once for the module."""
    return jax.jit(paper.reset), jax.jit(paper.step)


def test_the_registry_names_paper_and_free_and_their_variants():
    names = envs.names()
    assert {"paper", "free", "free_hand", "paper_point", "free_push"} <= set(names)
    for name in names:
        assert envs.describe(name)
        assert isinstance(envs.get_default_config(name), envs.TaskEnvConfig)
    assert envs.get_default_config("paper_touch").sampler.actions == (1,)
    assert envs.get_default_config("free").sampler.placement == "random"


def test_a_loaded_env_has_the_ecosystem_shape(paper, stepped):
    reset, step = stepped
    assert (paper.observation_size, paper.action_size) == (11, 4)
    assert paper.backend == "mujoco" and paper.dt == pytest.approx(0.05)
    s = reset(jax.random.key(0))
    assert s.obs.shape == (11,) and s.done.dtype == jnp.float32 and float(s.done) == 0.0
    s2 = step(s, jnp.ones(4))
    assert jax.tree.structure(s2) == jax.tree.structure(s)
    assert all(a.dtype == b.dtype for a, b in zip(jax.tree.leaves(s), jax.tree.leaves(s2),
                                                   strict=True))
    assert {"point_l1", "invalid"} <= set(s2.metrics) and "palm_pos" in s2.info
    assert int(s2.pipeline_state.step) == 1


def test_reset_draws_the_task_with_the_public_sampler_the_trainer_uses(paper, stepped):
    reset, _ = stepped
    keys = jax.random.split(jax.random.key(5), 16)
    tasks = [paper.sample_task(k) for k in keys]
    drawn = [reset(k).pipeline_state.task for k in keys]
    for t, d in zip(tasks, drawn, strict=True):
        assert (int(t.action), int(t.position), int(t.layout)) == (
            int(d.action), int(d.position), int(d.layout))
    assert len({(int(t.action), int(t.position)) for t in tasks}) > 3  # it does vary
    # the AL trainer draws its episodes' tasks with the same sampler
    assert al.ALConfig().sampler == paper.sampler


def test_an_explicit_task_gives_the_project_env_s_own_state(paper):
    task = gj.make_task("push", "red", layout=7)
    s = paper.reset_task(jax.random.key(1), task)
    want = gj.Env().reset(jax.random.key(1), task)
    np.testing.assert_array_equal(np.asarray(s.obs), np.asarray(want.obs))
    assert int(s.pipeline_state.task.layout) == 7


def test_overrides_are_typed_and_a_misspelt_name_lists_the_accepted_ones():
    env = envs.load("free", config_overrides={"start_noise": 0.2, "episode_length": 30})
    assert env.config.params.start_noise == 0.2 and env.episode_length == 30
    with pytest.raises(ValueError, match="unknown env 'papr'.*'paper'"):
        envs.load("papr")
    with pytest.raises(ValueError, match="unknown field 'bakend'.*'backend'"):
        envs.load("paper", config_overrides={"bakend": "mjx"})
    with pytest.raises(ValueError, match="backend"):
        envs.load("paper", config_overrides={"backend": "gpu"})
    with pytest.raises(ValueError, match="actions"):
        envs.load("paper", config_overrides={"actions": (5,)})


def test_brax_ppo_trains_on_the_env_untouched():
    from brax.training.agents.ppo import train as ppo

    env = envs.to_brax(envs.load("paper_point"))
    seen = []
    _, params, metrics = ppo.train(
        env, num_timesteps=6000, episode_length=env.episode_length, num_envs=16,
        batch_size=16, num_minibatches=2, unroll_length=10, num_updates_per_batch=1,
        num_evals=2, num_eval_envs=8, learning_rate=1e-3, seed=0,
        progress_fn=lambda n, m: seen.append((n, float(m["eval/episode_reward"]))))
    assert seen[-1][0] >= 6000 and np.isfinite(seen[-1][1])
    assert np.isfinite(float(metrics["eval/episode_reward"]))


def test_brax_sac_trains_on_the_env_untouched():
    from brax.training.agents.sac import train as sac

    env = envs.to_brax(envs.load("paper_push"))
    _, _, metrics = sac.train(
        env, num_timesteps=1500, episode_length=env.episode_length, num_envs=8,
        batch_size=32, min_replay_size=200, max_replay_size=4000, num_evals=2,
        num_eval_envs=8, seed=0)
    assert np.isfinite(float(metrics["eval/episode_reward"]))


def test_cacla_trains_on_a_standard_brax_env_and_its_return_improves():
    """The project's AL trainer (the one train.py uses), given Brax's inverted pendulum."""
    from brax import envs as brax_envs
    from brax.envs.wrappers.training import EpisodeWrapper

    from grounding_jax.learn import cacla

    env = EpisodeWrapper(brax_envs.get_environment("inverted_pendulum"), 100, 1)
    learner = cacla.CaclaConfig(actor_hidden=16, critic_hidden=16,
                                obs_dim=env.observation_size, act_dim=env.action_size)
    config = al.ALConfig(learner=learner, phase1_episodes=0, phase2_episodes=200)
    hp = al.ALHyper(learner=cacla.CaclaHyper(sigma=0.2, gamma=0.9, actor_lr=0.01,
                                             critic_lr=0.01, actor_init_scale=0.1))
    train = jax.jit(jax.vmap(al.make_train(config, env=env), in_axes=(0, None)))
    _, metrics = train(jax.random.split(jax.random.key(0), 4), hp)
    ret = np.asarray(metrics["return"])
    first, last = ret[:, :40].mean(1), ret[:, -40:].mean(1)
    assert np.all(last > first), (first, last)
    assert np.median(last) > 1.5 * np.median(first), (first, last)


def test_the_learner_s_sizes_must_match_the_env_s():
    from brax import envs as brax_envs

    env = brax_envs.get_environment("inverted_pendulum")
    with pytest.raises(ValueError, match="learner.obs_dim"):
        al.make_train(al.ALConfig(), env=env)


def test_brax_done_is_a_termination_and_the_time_limit_brax_s_truncation():
    from brax.envs.wrappers import training

    env = envs.to_brax(envs.load("paper", config_overrides={"episode_length": 4}))
    wrapped = training.wrap(env, episode_length=env.episode_length)
    s = jax.jit(wrapped.reset)(jax.random.split(jax.random.PRNGKey(0), 3))  # Brax: raw keys
    step = jax.jit(wrapped.step)
    for _ in range(4):
        s = step(s, jnp.zeros((3, 4)))
    np.testing.assert_array_equal(np.asarray(s.done), 1.0)
    np.testing.assert_array_equal(np.asarray(s.info["truncation"]), 1.0)
    assert np.all(np.asarray(s.pipeline_state.step) == 0)  # auto-reset to the first state


def test_the_gymnasium_view_passes_the_env_checker():
    from gymnasium.utils.env_checker import check_env

    from grounding_jax.envs.gym_adapter import to_gymnasium_env

    with pytest.warns(UserWarning):  # gymnasium warns of the unbounded observation box
        check_env(to_gymnasium_env(envs.load("paper")), skip_render_check=True)


def test_the_gymnasium_vector_env_restarts_ended_episodes_with_fresh_tasks():
    import gymnasium

    vec = envs.to_gymnasium(envs.load("paper", config_overrides={"episode_length": 5}),
                            num_envs=3, seed=0)
    assert isinstance(vec, gymnasium.vector.VectorEnv)
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (3, 11) and obs.dtype == np.float32
    ends = []
    for _ in range(6):
        obs, reward, term, trunc, _ = vec.step(np.zeros((3, 4), np.float32))
        ends.append(term | trunc)
    assert np.all(ends[4]) and not np.any(ends[5])  # the time limit, then the next step restarts
    assert np.all(reward == 0.0)  # the restart step returns no reward (NEXT_STEP autoreset)
    again, _ = vec.reset(seed=0)
    np.testing.assert_array_equal(again, vec.reset(seed=0)[0])
    assert gymnasium.make("grounding_jax/free_touch-v0").reset(seed=1)[0].shape == (29,)


def test_the_base_install_does_without_brax_and_gymnasium():
    meta = tomllib.loads(open("pyproject.toml").read())["project"]
    base = " ".join(meta["dependencies"]).lower()
    assert "brax" not in base and "gymnasium" not in base
    assert {"brax", "gym"} <= set(meta["optional-dependencies"])
    code = ("import sys; sys.modules['brax'] = None; sys.modules['gymnasium'] = None\n"
            "from grounding_jax import envs\n"
            "env = envs.load('paper')\n"
            "assert 'brax.envs' not in sys.modules\n"
            "for f, extra in ((envs.to_brax, 'brax'), (envs.to_gymnasium, 'gym')):\n"
            "    try:\n        f(env)\n    except ImportError as e:\n"
            "        assert f\".[{extra}]\" in str(e), e\n    else:\n        raise SystemExit(1)\n"
            "print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]
