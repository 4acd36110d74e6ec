"""The AL trainer's episode loop on an env of the ecosystem's shape (Brax, Playground, ours).

Any object with ``reset(rng) -> state`` and ``step(state, action) -> state``, whose state
has ``obs``, ``reward`` and ``done`` (a Brax ``State``, a `grounding_jax.envs.EnvState`),
can be trained on by `grounding_jax.learn.al.make_train` with ``env=``: each episode starts
with ``reset`` and runs ``length`` steps side by side (lockstep, steps after ``done`` masked:
the learner sees nothing of them), the learner acting, stepping and updating as on the
project's own env. The env's reward and its ``done`` are all the trainer reads.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from grounding_jax.learn import learners


def check_env(env: Any, config: Any) -> int:
    """The episode length to train with; ValueError if ``env`` lacks the shape or its sizes
    differ from the learner's (naming the field)."""
    for attr in ("reset", "step", "observation_size", "action_size"):
        if not hasattr(env, attr):
            raise ValueError(f"env: {type(env).__name__} has no {attr!r}; accepted: an env "
                             f"with reset(rng), step(state, action), observation_size and "
                             f"action_size (Brax's, grounding_jax.envs.load(name))")
    sizes = (("obs_dim", env.observation_size, config.obs_size),
             ("act_dim", env.action_size, config.action_size))
    for field, want, got in sizes:
        if int(want) != int(got):
            raise ValueError(f"learner.{field}: the env has {int(want)} units, the learner "
                             f"{int(got)}; set learner={type(config).__name__}({field}="
                             f"{int(want)}, ...)")
    return int(getattr(env, "episode_length", 0) or 0)


def make_episodes(env: Any, learner_config: Any, length: int):
    """Build ``run(agent, keys, plan, hp) -> (agent, metrics)`` like the AL trainer's
    lockstep loop, on ``env``: one episode of ``length`` steps per key. ``hp`` is an
    `grounding_jax.learn.al.ALHyper` (only its ``learner`` part is read here).

    Returns:
        ``metrics`` per episode: ``return`` (the rewards' sum over the steps taken),
        ``final_reward``, ``td_error`` (RMS) and ``steps``.
    """
    lrn = learners.for_config(learner_config)

    def episode(agent, xs, hp):
        key, plan = xs
        k_reset, k_steps = jax.random.split(key)
        lhp = lrn.at_episode(hp.learner, plan["phase1"], plan["progress"])
        state = env.reset(k_reset)

        def step(carry, k):
            agent, state, live = carry
            a, _ = lrn.act(agent, state.obs, k, lhp)
            nxt = env.step(state, a)
            done = jnp.asarray(nxt.done, jnp.float32) > 0.5
            tr = learners.Transition(obs=state.obs, action=a, reward=nxt.reward,
                                     next_obs=nxt.obs, done=done, prev_reward=state.reward)
            new, info = lrn.update(agent, tr, lhp, learner_config)
            agent = jax.tree.map(lambda n, o: jnp.where(live, n, o), new, agent)
            record = {"reward": jnp.where(live, nxt.reward, 0.0), "live": live,
                      "delta_sq": jnp.where(live, info["delta"] ** 2, 0.0)}
            return (agent, nxt, live & ~done), record

        carry = (agent, state, jnp.asarray(True))
        (agent, last, _), rec = jax.lax.scan(step, carry, jax.random.split(k_steps, length))
        steps = jnp.sum(rec["live"])
        return agent, {
            "return": learners.ordered_sum(rec["reward"]), "final_reward": last.reward,
            "td_error": jnp.sqrt(learners.ordered_sum(rec["delta_sq"])
                                 / jnp.maximum(steps, 1)),
            "steps": steps}

    def run(agent, keys: jax.Array, plan: dict[str, jax.Array], hp):
        return jax.lax.scan(lambda a, xs: episode(a, xs, hp), agent, (keys, plan))

    return run
