"""Touch trained by Brax PPO, the paper's reward and the one that holds still, judged as
CACLA's agents are: is the paper's touch reward the limit, or the trainer?

PPO (``brax.training.agents.ppo``, untouched) trains on the registered ``paper_touch`` env
(only touch commands, every layout and slot), through `grounding_jax.envs.to_brax`, with
touch's reward either the paper's (minus the palm's distance to the target, -0.3 while
touching it) or the touching pose that holds still (task set ``paper_touch_pose``,
``touch_still_penalty`` 3: the ``touch_memory`` stage's variant). Its greedy policy is then
judged by the AL judge's rule (`grounding_jax.paper.al_eval.episode_success`: an arm capsule
touches the target in the second half of a 100-step episode, the target moved < 3 cm, no
wrong object moved) on all 108 touch tasks from home, on the judge's key. CACLA's agents
train all three actions in 1200 episodes (90,000 steps, about a third of them touch): PPO is
given touch alone, and more steps.

Usage:  python benchmarks/trainers.py [--steps 500000] [--seeds 2] [--rewards paper,still]
        [--ppo small|reacher] [--tag touch]
Writes results/benchmarks/trainers_<tag>.json and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import jax
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from brax.training.agents.ppo import train as ppo  # noqa: E402

from grounding_jax import envs  # noqa: E402
from grounding_jax.core.io import atomic_write_text, library_versions  # noqa: E402
from grounding_jax.paper import al_eval  # noqa: E402
from grounding_jax.sim import rollout  # noqa: E402
from grounding_jax.sim.env import Env, EnvConfig, EnvParams  # noqa: E402

OUT = pathlib.Path(__file__).resolve().parents[1] / "results" / "benchmarks"
#: the rewards compared: (task set, env params)
REWARDS = {"paper": ("paper", {}),
           "still": ("paper_touch_pose", {"touch_still_penalty": 3.0})}
TOUCH = 1
#: PPO's settings: ``small`` (Brax's small continuous-control choices, 32 envs) and ``reacher``
#: (Brax's reacher settings scaled to a CPU: longer unrolls, rewards scaled by 5); untuned
PPO = {"small": {"num_envs": 32, "batch_size": 32, "num_minibatches": 4, "unroll_length": 10,
                 "num_updates_per_batch": 4, "learning_rate": 3e-4, "entropy_cost": 1e-3,
                 "discounting": 0.95, "normalize_observations": True, "num_evals": 2,
                 "num_eval_envs": 16},
       "reacher": {"num_envs": 64, "batch_size": 64, "num_minibatches": 4, "unroll_length": 20,
                   "num_updates_per_batch": 8, "learning_rate": 3e-4, "entropy_cost": 1e-3,
                   "discounting": 0.95, "reward_scaling": 5.0, "normalize_observations": True,
                   "num_evals": 2, "num_eval_envs": 16}}


def judge(policy, task_set: str, params: EnvParams, key: jax.Array) -> dict:
    """Touch success of a greedy ``policy(obs) -> action`` on every touch task from home."""
    env = Env(EnvConfig(task_set=task_set))
    batch = al_eval.all_tasks(actions=(TOUCH,))

    def one(k, task):
        first = env.reset(k, task, params)
        traj, _ = rollout.rollout(env, first, lambda s, _: (policy(s.obs), 0.0),
                                  al_eval.EVAL_STEPS, params)
        return al_eval.episode_success(traj, task, task_set=env.tasks)

    keys = jax.random.split(key, int(batch.action.shape[0]))
    out = jax.device_get(jax.jit(jax.vmap(one))(keys, batch))
    moved = np.asarray(out["target_moved"])
    return {"touch": float(np.mean(out["success"])),
            "final_reward_median": float(np.median(out["final_reward"])),
            "no_late_contact": float(np.mean(np.asarray(out["touched_late"]) <= 0)),
            "target_moved_3cm": float(np.mean(moved >= al_eval.TOUCH_MOVED))}


def run_ppo(reward: str, steps: int, seed: int, judge_key: jax.Array, settings: str) -> dict:
    """One PPO run on touch with ``reward``, judged."""
    task_set, fields = REWARDS[reward]
    overrides = {"task_set": task_set, **fields}
    env = envs.to_brax(envs.load("paper_touch", config_overrides=overrides))
    t0 = time.perf_counter()
    make_policy, params, metrics = ppo.train(env, num_timesteps=steps,
                                             episode_length=env.episode_length, seed=seed,
                                             **PPO[settings])
    wall = time.perf_counter() - t0
    act = make_policy(params, deterministic=True)
    key = jax.random.key(0)  # unused by a deterministic policy, which Brax still asks for

    def policy(obs):
        return act(obs, key)[0]

    params_env = EnvParams(**fields)
    res = judge(policy, task_set, params_env, judge_key)
    print(f"PPO {reward} seed {seed}: touch {res['touch']:.2f} ({wall:.0f} s)", flush=True)
    return {"reward": reward, "settings": settings, "seed": seed, "env_steps": steps, **res,
            "eval_episode_reward": float(metrics["eval/episode_reward"]),
            "wall_s_with_compile": round(wall, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=500_000)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--rewards", default="paper,still")
    ap.add_argument("--eval-key", type=int, default=999)
    ap.add_argument("--ppo", default="small", choices=list(PPO))
    ap.add_argument("--tag", default="touch")
    args = ap.parse_args()
    rewards = args.rewards.split(",")
    bad = [r for r in rewards if r not in REWARDS]
    if bad:
        raise SystemExit(f"--rewards: {bad} not accepted; accepted: {list(REWARDS)}")
    key = jax.random.key(args.eval_key)
    rows = [run_ppo(r, args.steps, s, key, args.ppo) for r in rewards
            for s in range(args.seeds)]
    OUT.mkdir(parents=True, exist_ok=True)
    out = {"env": "paper_touch", "ppo": PPO[args.ppo], "eval_key": args.eval_key, "rows": rows,
           "device": jax.devices()[0].device_kind, "libraries": library_versions()}
    atomic_write_text(OUT / f"trainers_{args.tag}.json", json.dumps(out, indent=1) + "\n")
    print("| reward | seed | env steps | touch | no late contact / target moved >= 3 cm | "
          "final reward (median) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['reward']} | {r['seed']} | {r['env_steps']:,} | {100 * r['touch']:.0f}% | "
              f"{100 * r['no_late_contact']:.0f}% / {100 * r['target_moved_3cm']:.0f}% | "
              f"{r['final_reward_median']:.3f} |")


if __name__ == "__main__":
    main()
