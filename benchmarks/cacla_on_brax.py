"""CACLA (the project's AL trainer) beside Brax PPO on Brax's inverted pendulum, same budget.

Each CACLA agent trains a number of episodes (at most 100 steps each; the pendulum's fall
ends one early); PPO gets the env steps the median CACLA agent took, then twice that. Both
are scored by the mean return of their greedy policy over fresh episodes (PPO's own eval:
``eval/episode_reward``; CACLA: the actor's mean action, no exploration), on seeds 0..N-1,
back to back in this process.

Usage:  python benchmarks/cacla_on_brax.py [--episodes 200] [--seeds 4]
Writes results/benchmarks/cacla_on_brax.json and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np
from brax import envs as brax_envs
from brax.envs.wrappers.training import EpisodeWrapper
from brax.training.agents.ppo import train as ppo

import grounding_jax.envs.brax_adapter  # noqa: F401  (Brax 0.14 on JAX 0.10: restores its device_put helpers)
from grounding_jax.learn import al, cacla

LENGTH = 100
OUT = pathlib.Path(__file__).resolve().parents[1] / "results" / "benchmarks"


def greedy_return(env, agent, key: jax.Array) -> jax.Array:
    """Mean return of the actor's mean action over one episode per key."""
    def one(k):
        state = env.reset(k)

        def step(carry, _):
            state, live, total = carry
            _, mean = cacla.actor_apply(agent.actor, state.obs)
            nxt = env.step(state, mean)
            total = total + jnp.where(live, nxt.reward, 0.0)
            return (nxt, live & (nxt.done < 0.5), total), None

        (_, _, total), _ = jax.lax.scan(step, (state, jnp.asarray(True), 0.0), None, LENGTH)
        return total
    return jax.vmap(one)(key)


def run_cacla(env, episodes: int, seeds: int) -> dict:
    learner = cacla.CaclaConfig(actor_hidden=16, critic_hidden=16,
                                obs_dim=env.observation_size, act_dim=env.action_size)
    config = al.ALConfig(learner=learner, phase1_episodes=0, phase2_episodes=episodes)
    hp = al.ALHyper(learner=cacla.CaclaHyper(sigma=0.2, gamma=0.9, actor_lr=0.01,
                                             critic_lr=0.01, actor_init_scale=0.1))
    train = jax.jit(jax.vmap(al.make_train(config, env=env), in_axes=(0, None)))
    t0 = time.perf_counter()
    agents, metrics = train(jax.random.split(jax.random.key(0), seeds), hp)
    jax.block_until_ready(metrics)
    wall = time.perf_counter() - t0
    scores = [float(greedy_return(env, jax.tree.map(lambda x, i=i: x[i], agents),
                                  jax.random.split(jax.random.key(100 + i), 32)).mean())
              for i in range(seeds)]
    steps = np.asarray(metrics["steps"]).sum(1)
    return {"trainer": "CACLA", "episodes": episodes, "env_steps": int(np.median(steps)),
            "returns": scores, "median_return": float(np.median(scores)),
            "wall_s_with_compile": round(wall, 1)}


def run_ppo(env_steps: int, seeds: int) -> dict:
    scores, t0 = [], time.perf_counter()
    for seed in range(seeds):
        env = brax_envs.get_environment("inverted_pendulum")
        _, _, m = ppo.train(env, num_timesteps=env_steps, episode_length=LENGTH, num_envs=8,
                            batch_size=8, num_minibatches=2, unroll_length=10,
                            num_updates_per_batch=4, num_evals=2, num_eval_envs=32,
                            learning_rate=3e-4, entropy_cost=1e-2, discounting=0.97,
                            seed=seed)
        scores.append(float(m["eval/episode_reward"]))
    return {"trainer": "Brax PPO", "env_steps": env_steps, "returns": scores,
            "median_return": float(np.median(scores)),
            "wall_s_with_compile": round(time.perf_counter() - t0, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=200)
    ap.add_argument("--seeds", type=int, default=4)
    args = ap.parse_args()
    env = EpisodeWrapper(brax_envs.get_environment("inverted_pendulum"), LENGTH, 1)
    rows = [run_cacla(env, args.episodes, args.seeds)]
    budget = rows[0]["env_steps"]
    rows += [run_ppo(budget, args.seeds), run_ppo(2 * budget, args.seeds)]
    OUT.mkdir(parents=True, exist_ok=True)
    out = {"env": "brax inverted_pendulum", "episode_length": LENGTH, "rows": rows,
           "device": jax.devices()[0].device_kind}
    (OUT / "cacla_on_brax.json").write_text(json.dumps(out, indent=2) + "\n")
    print("| trainer | env steps | median greedy return (of 100) | returns per seed |")
    print("|---|---|---|---|")
    for r in rows:
        print(f"| {r['trainer']} | {r['env_steps']:,} | {r['median_return']:.1f} | "
              f"{', '.join(f'{x:.1f}' for x in r['returns'])} |")


if __name__ == "__main__":
    main()
