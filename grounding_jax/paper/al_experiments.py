"""The paper's AL figures (10, 11, 13, 14) and the AL experiment, from trained agents
(success rates: `grounding_jax.paper.al_eval`)."""

from __future__ import annotations

import json
import pathlib
import sys
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core import xla
from grounding_jax.core.io import atomic_write_text, pyplot, write_figure
from grounding_jax.learn import al, cacla
from grounding_jax.paper.al_eval import (
    ALL_LAYOUTS,
    DEFAULT_ENV,
    EVAL_STEPS,
    POINT_L1,
    POINT_STILL,
    RANDOM_START_NOISE,
    STILL_LAST,
    all_tasks,
    episode_success,
    make_success,
    make_switch_eval,
    make_switch_success,
    success_table,
)
from grounding_jax.paper.al_eval import take as take_agent
from grounding_jax.sim import rollout, scene, scripted
from grounding_jax.sim.env import (
    DEFAULT_PARAMS,
    Env,
    EnvConfig,
    EnvParams,
    as_env,
    make_task,
    scale_joints,
)


def success_curve(success: dict, out, phase1_episodes: int = 0,
                  paper_episodes: int = 450) -> dict:
    """Success of the median agent (and the min-max over agents) against training episodes,
    per action from home, point from random starts and the goal switch, from the success
    measured at each stop of `run` (``success[str(episode)]``)."""
    plt = pyplot()
    eps = sorted(int(e) for e in success)
    series = {f"{a} (home)": [success[str(e)]["home"]["spread"][a] for e in eps]
              for a in scene.ACTIONS}
    series["point (random starts)"] = [success[str(e)]["random_starts"]["spread"]["point"]
                                       for e in eps]
    if all("switch" in success[str(e)] for e in eps):
        series["goal switch"] = [np.quantile(success[str(e)]["switch"]["per_agent"],
                                             [0, 0.25, 0.5, 0.75, 1]).tolist() for e in eps]
    fig, ax = plt.subplots(figsize=(7, 4))
    for label, rows in series.items():
        r = np.asarray(rows)
        line, = ax.plot(eps, r[:, 2], marker="o", label=label)
        ax.fill_between(eps, r[:, 0], r[:, 4], color=line.get_color(), alpha=0.12)
    ax.axvline(paper_episodes, color="grey", ls=":", lw=0.8)
    if phase1_episodes:
        ax.axvline(phase1_episodes, color="grey", ls="--", lw=0.8)
    ax.set(xlabel="training episodes", ylabel="success (median agent; band: min-max)",
           ylim=(-0.02, 1.02), title="AL success against training episodes")
    ax.legend(fontsize=7)
    fig.tight_layout()
    data = {"episodes": eps, "series": series}
    write_figure(out, "success_curve", data, fig)
    return data


def fig10(agents, key: jax.Array, env: Env | EnvConfig, out) -> dict:
    """Fig 10: reward per step of the greedy actor for the 9 action-position pairs (layout 0);
    agent 0 drawn, all agents' rewards in the JSON."""
    plt = pyplot()
    evaluate = al.make_eval(env)
    batch = all_tasks((0,))
    run = xla.physics_jit(jax.vmap(jax.vmap(lambda ag, t: evaluate(ag, key, t)[1].reward,
                                            in_axes=(None, 0)), in_axes=(0, None)), env)
    r = np.asarray(run(agents, batch))  # [agents, 9, steps]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.2), sharey=False)
    for i, ax in enumerate(axes):
        for j, p in enumerate(scene.POSITIONS):
            ax.plot(np.arange(1, r.shape[2] + 1), r[0, 3 * i + j], label=p)
        ax.set_title(scene.ACTIONS[i])
        ax.set_xlabel("step")
    axes[0].set_ylabel("reward")
    axes[0].legend(fontsize=8)
    fig.suptitle("Fig 10: reward per step of the trained actions (agent 0, layout 0)")
    fig.tight_layout()
    data = {"tasks": [f"{a} {p}" for a in scene.ACTIONS for p in scene.POSITIONS],
            "reward_agent0": r[0].tolist(), "reward_mean": r.mean(0).tolist(),
            "final_reward_per_agent": r[:, :, -1].tolist()}
    write_figure(out, "fig10", data, fig)
    return data


def fig11(agent, key: jax.Array, env: Env | EnvConfig, out,
          starts: int = 5, start_noise: float = 0.5) -> dict:
    """Fig 11: "point left" from ``starts`` random start poses: joints and reward per step."""
    plt = pyplot()
    evaluate = al.make_eval(env)
    params = EnvParams(start_noise=start_noise)
    task = make_task("point", "left")
    first, traj, _ = xla.physics_jit(jax.vmap(lambda k: evaluate(agent, k, task, params)),
                                     env)(jax.random.split(key, starts))
    j0 = np.asarray(first.obs[:, :4])[:, None]
    joints = np.concatenate([j0, np.asarray(traj.obs[..., :4])], axis=1)  # [starts, T+1, 4]
    reward = np.concatenate([np.asarray(first.reward)[:, None], np.asarray(traj.reward)], 1)
    target = np.asarray(scale_pointing()[0])
    fig, axes = plt.subplots(1, 5, figsize=(16, 3.2))
    names = ("shoulder pitch", "shoulder roll", "shoulder yaw", "elbow")
    for k in range(4):
        axes[k].plot(joints[..., k].T, lw=1)
        axes[k].axhline(target[k], color="k", ls=":", lw=0.8)
        axes[k].set_title(names[k])
        axes[k].set_xlabel("step")
    axes[0].set_ylabel("scaled joint")
    axes[4].plot(reward.T, lw=1)
    axes[4].set_title("reward (-L1)")
    axes[4].set_xlabel("step")
    fig.suptitle(f'Fig 11: "point left" from {starts} random starts (dotted: stored pose)')
    fig.tight_layout()
    l1 = np.asarray(traj.metrics["point_l1"][:, -1])
    data = {"start_noise": start_noise, "joints": joints.tolist(), "reward": reward.tolist(),
            "final_point_l1": l1.tolist(), "success": (l1 < POINT_L1).tolist()}
    write_figure(out, "fig11", data, fig)
    return data


def scale_pointing() -> jax.Array:
    """The stored pointing poses in scaled joint units, ``[3 positions, 4]``."""
    return scale_joints(jnp.asarray(scene.pointing_configs(), jnp.float32))


#: Fig 13's goal switches (first task -> second task at step 20).
SWITCHES = (("point", "left", "point", "right"), ("point", "middle", "push", "middle"),
            ("push", "right", "touch", "left"), ("touch", "middle", "point", "left"))


def fig13(agent, key: jax.Array, env: Env | EnvConfig, out,
          steps: int = 100, switch_at: int = 20) -> dict:
    """Fig 13: 100-step runs where the action or the target changes at step 20."""
    plt = pyplot()
    run = xla.physics_jit(make_switch_eval(env, steps, switch_at), env)
    fig, axes = plt.subplots(1, len(SWITCHES), figsize=(4 * len(SWITCHES), 3.2))
    rows = []
    for ax, (a1, p1, a2, p2) in zip(axes, SWITCHES, strict=True):
        traj = run(agent, key, make_task(a1, p1), make_task(a2, p2),
                   DEFAULT_PARAMS.replace(wrong_move_extra_steps=steps + 1))
        r = np.asarray(traj.reward)
        ax.plot(np.arange(1, steps + 1), r)
        ax.axvline(switch_at, color="grey", ls=":")
        ax.set_title(f"{a1} {p1} -> {a2} {p2}", fontsize=9)
        ax.set_xlabel("step")
        ok = episode_success(traj, make_task(a2, p2), since=switch_at)
        rows.append({"first": f"{a1} {p1}", "second": f"{a2} {p2}",
                     "reward_before_switch": float(r[switch_at - 1]),
                     "reward_after_switch": float(r[switch_at]),
                     "final_reward": float(r[-1]), "second_task_success": float(ok["success"]),
                     "reward": r.tolist()})
    axes[0].set_ylabel("reward")
    fig.suptitle(f"Fig 13: goal switched at step {switch_at} (agent 0)")
    fig.tight_layout()
    data = {"switch_at": switch_at, "runs": rows}
    write_figure(out, "fig13", data, fig)
    return data


def fig14(metrics: dict[str, np.ndarray], out, window: int = 50,
          phase1_episodes: int = 0, name: str = "fig14") -> dict:
    """Fig 14: per-episode return by action and by target position over a training run
    (moving average over ``window`` episodes of each kind, mean over agents)."""
    plt = pyplot()
    ret = np.asarray(metrics["return"])  # [agents, episodes]
    window = min(window, max(5, ret.shape[1] // 15))  # short runs: a shorter average
    groups = {"action": (np.asarray(metrics["action"]), scene.ACTIONS),
              "position": (np.asarray(metrics["position"]), scene.POSITIONS)}
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.4))
    data = {"window": window, "episodes": int(ret.shape[1])}
    for ax, (field, (kind, names)) in zip(axes, groups.items(), strict=True):
        curves = {}
        for i, label in enumerate(names):
            per_agent = []
            for a in range(ret.shape[0]):
                sel = np.flatnonzero(kind[a] == i)
                r = ret[a, sel]
                if len(r) < window:
                    continue
                ma = np.convolve(r, np.ones(window) / window, mode="valid")
                per_agent.append(np.interp(np.arange(ret.shape[1]), sel[window - 1:], ma,
                                           left=np.nan))
            if per_agent:
                stacked = np.stack(per_agent)
                seen = np.isfinite(stacked).any(axis=0)  # before any agent's first window: nan
                curve = np.full(stacked.shape[1], np.nan)
                curve[seen] = np.nanmean(stacked[:, seen], axis=0)
                ax.plot(curve, label=label)
                curves[label] = [None if np.isnan(v) else float(v) for v in curve]
        if phase1_episodes:
            ax.axvline(phase1_episodes, color="grey", ls=":")
        ax.set_title(f"return by {field}")
        ax.set_xlabel("episode")
        ax.legend(fontsize=8)
        data[f"by_{field}"] = curves
    axes[0].set_ylabel(f"return (moving average of {window})")
    what = "phase 1 then plain CACLA" if phase1_episodes else "no tricks (plain CACLA)"
    fig.suptitle(f"Fig 14: training run, {what}, {ret.shape[0]} agents")
    fig.tight_layout()
    write_figure(out, name, data, fig)
    return data


#: Hyperparameters tuned here on all 9 tasks (the paper's lr 0.001 barely learns in our env;
#: see docs/al.md): the best of a grid over sigma, both learning rates and gamma
#: (3 seeds x 1500 episodes per cell). sigma 0.3 learned faster per task but its exploration
#: knocks the neighbouring objects, which ends most training episodes early.
TUNED = {"actor_lr": 0.03, "critic_lr": 0.3, "sigma": 0.1, "gamma": 0.0}
#: The learner's other shipped settings (``al.ALHyper`` fields), chosen with
#: ``sweeps/al_tuning.toml`` (8 agents a point, sweep seed 1) and one check of the two best
#: changes together (8 agents, key 100) -- never on the agents train.py reports (seed 0):
#: the actor is pulled toward the action the arm executed (without it, whole agents drove a
#: joint into its limit and stayed there), its learning rate falls to 0.03x and sigma to 0.3x
#: by the last episode (the precision point needs). docs/al.md has the numbers.
TUNED_AL = {"actor_lr_decay": 0.03, "sigma_decay": 0.3, "executed_target": 1.0}


def exploration_knocks(key: jax.Array, env: Env | EnvConfig = DEFAULT_ENV,
                       sigmas: tuple[float, ...] = (0.1, 0.3), episodes: int = 16) -> dict:
    """How often exploration alone knocks a wrong object: a perfect point policy (tracking the
    stored pose) plus Gaussian noise of each ``sigma``, ``episodes`` per position.

    Returns:
        {sigma: {"wrong_moved_share": ..., "final_point_l1": ...}} over all episodes.
    """
    env = as_env(env)
    length = env.config.episode_length
    poses = jnp.asarray(scene.pointing_configs(), jnp.float32)

    def episode(k, position, sigma):
        task = make_task("point", 0)
        task = task.replace(position=position)
        waypoints = jnp.repeat(poses[position][None], length, axis=0)

        def policy(s, kk):
            a = scripted.tracking_action(waypoints, s.step, s.obs)
            return a + sigma * jax.random.normal(kk, (4,)), None

        traj, _ = rollout.rollout(env, env.reset(k, task), policy, length,
                                  xs=jax.random.split(k, length))
        last = jax.tree.map(lambda x: x[-1], traj)
        return last.wrong_since >= 0, last.metrics["point_l1"]

    run = xla.physics_jit(jax.vmap(episode, in_axes=(0, 0, None)), env)
    keys = jax.random.split(key, 3 * episodes)
    positions = jnp.repeat(jnp.arange(3, dtype=jnp.int32), episodes)
    out = {}
    for sigma in sigmas:
        wrong, l1 = run(keys, positions, jnp.float32(sigma))
        out[str(sigma)] = {"wrong_moved_share": float(np.mean(wrong)),
                           "final_point_l1": float(np.mean(l1))}
    return out


def _tail(metrics: dict, frac: float = 0.1) -> dict:
    """Means over the last ``frac`` of a run's episodes: return per action, wrong-move share,
    steps per episode."""
    n = np.asarray(metrics["return"]).shape[1]
    sl = slice(n - max(1, int(frac * n)), None)
    act = np.asarray(metrics["action"])[:, sl]
    ret = np.asarray(metrics["return"])[:, sl]
    return {"episodes": [int(sl.start), n],
            "return_by_action": {a: float(ret[act == i].mean()) if np.any(act == i) else None
                                 for i, a in enumerate(scene.ACTIONS)},
            "wrong_moved_share": float(np.asarray(metrics["wrong_moved"])[:, sl].mean()),
            "mean_steps": float(np.asarray(metrics["steps"])[:, sl].mean())}


def _summary(table: dict, out: dict) -> dict:
    l1 = np.asarray(out["final_point_l1"])[..., np.asarray(out["action"]) == 0]
    return {**table, "point_l1_median": float(np.median(l1)),
            "point_l1_p90": float(np.quantile(l1, 0.9))}


def run(key: jax.Array, out, seeds: int, phase1: int, phase2: int, no_tricks_episodes: int,
        env_config: EnvConfig = DEFAULT_ENV, hyper: dict | None = None,
        checkpoints: tuple[int, ...] = (450,), random_starts: int = 1,
        decay: dict | None = None, learner_config: Any = None) -> dict:
    """The AL results: success rates (home and random starts) at each of ``checkpoints``
    episodes and at the end, Figs 10, 11, 13 (agent 0 of the final batch) and Fig 14 (a
    no-tricks run of ``no_tricks_episodes``). Writes PNG + JSON under ``out``.

    Args:
        key: one PRNG key, split once here.
        out: output folder.
        seeds: agents trained (vmapped).
        phase1, phase2: the schedule's episodes.
        no_tricks_episodes: episodes of the no-tricks run (0 skips Fig 14).
        env_config: static env config (backend).
        hyper: CACLA hyperparameters (default `TUNED`).
        decay: the other shipped fields -- decays, executed_target, ... -- by name (see
            `al.hyper`; default `TUNED_AL`).
        checkpoints: extra episode counts at which success is measured.
        random_starts: random start poses per point task and layout (1: 108 starts).
        learner_config: the learner's static config (network sizes; default
            ``CaclaConfig()``).

    Returns:
        (results dict -- what the JSON files hold, the trained agents [seeds]).
    """
    hyper = dict(TUNED if hyper is None else hyper)
    decay = dict(TUNED_AL if decay is None else decay)
    hp = al.validate(al.hyper(**hyper, **decay))
    k_train, k_nt, k_home, k_rand, k10, k11, k13, k_knock = jax.random.split(key, 8)
    cfg = al.ALConfig(env=env_config, learner=learner_config or cacla.CaclaConfig(),
                      phase1_episodes=phase1, phase2_episodes=phase2)
    env = Env(env_config)  # every evaluation below shares it
    home = make_success(env)
    rand = make_success(env, starts=random_starts, actions=(0,))
    switch = make_switch_success(env)
    rand_params = EnvParams(start_noise=RANDOM_START_NOISE)
    success: dict[str, dict] = {}

    def measure(episode: int, agents, _metrics) -> None:
        h = home(agents, k_home)
        r = rand(agents, k_rand, rand_params)
        sw = success_table(switch(agents, k_home))
        success[str(episode)] = {"home": _summary(success_table(h), h),
                                 "random_starts": _summary(success_table(r), r),
                                 "switch": sw}
        ba = success[str(episode)]["home"]["by_action"]
        print(f"al    episode {episode}: success of the median agent from home: point "
              f"{ba['point']:.2f} touch {ba['touch']:.2f} push {ba['push']:.2f}; random-start "
              f"point {success[str(episode)]['random_starts']['by_action']['point']:.2f}; "
              f"goal switch {sw['overall']:.2f}", flush=True)

    stops = sorted({c for c in checkpoints if 0 < c < cfg.episodes} | {cfg.episodes})
    t = time.perf_counter()
    agents, metrics = al.train_in_chunks(cfg, jax.random.split(k_train, seeds), hp, stops,
                                         measure)
    train_s = time.perf_counter() - t
    agent0 = take_agent(agents, 0)
    res = {"seeds": seeds, "phase1": phase1, "phase2": phase2, "hyper": {**hyper, **decay},
           "random_start_noise": RANDOM_START_NOISE, "success": success,
           "final": success[str(cfg.episodes)], "train_s": train_s,
           "rl_steps": int(np.asarray(metrics["steps"]).sum()), "training_tail": _tail(metrics),
           "exploration_knocks": exploration_knocks(k_knock, env)}
    res["success_curve"] = success_curve(success, out, phase1)
    res["fig10"] = fig10(agents, k10, env, out)
    res["fig11"] = fig11(agent0, k11, env, out)
    res["fig13"] = fig13(agent0, k13, env, out)
    if no_tricks_episodes:
        nt = al.ALConfig(env=env_config, learner=cfg.learner, phase1_episodes=0,
                         phase2_episodes=no_tricks_episodes)
        _, m_nt = xla.physics_jit(jax.vmap(al.make_train(nt), in_axes=(0, None)), env)(
            jax.random.split(k_nt, seeds), hp)
        res["fig14"] = fig14(m_nt, out)
        res["no_tricks_tail"] = _tail(m_nt)
        res["fig14_paper_schedule"] = fig14(metrics, out, phase1_episodes=phase1,
                                            name="fig14_paper_schedule")
    out = pathlib.Path(out)
    atomic_write_text(out / "success.json", json.dumps(
        {k: res[k] for k in ("seeds", "phase1", "phase2", "hyper", "random_start_noise",
                             "success")}, indent=1) + "\n")
    return res, agents


# ------------------------------------------------------------------- the point tail (lever)
def point_tail(agents, env_params: EnvParams = DEFAULT_PARAMS,
               env: Env | EnvConfig = DEFAULT_ENV, last: int = 20,
               layouts: tuple[int, ...] = ALL_LAYOUTS) -> np.ndarray:
    """L1 to the pointing pose over the last ``last`` of ``EVAL_STEPS`` greedy steps of every
    point task from home, ``[agents, 3 positions x layouts, last]`` (``env_params`` leaves
    shared or per agent)."""
    evaluate = al.make_eval(as_env(env, EVAL_STEPS))
    batch = all_tasks(layouts, actions=(0,))
    axes = jax.tree.map(lambda x: 0 if jnp.ndim(x) else None, env_params)

    def run(agents, params):
        def one(agent, task, p):
            return evaluate(agent, jax.random.key(0), task, p)[1].metrics["point_l1"][-last:]
        return jax.vmap(jax.vmap(one, in_axes=(None, 0, None)), in_axes=(0, None, axes))(
            agents, batch, params)

    return np.asarray(xla.physics_jit(run, env)(agents, env_params))


def point_tail_figure(tails: dict[str, np.ndarray], out, name: str = "point_tail") -> dict:
    """Figure: L1 over the last steps of the point episodes, one panel per labelled set of
    agents (``tails`` from `point_tail`), median and quartiles over all episodes, and
    the share of episodes that end still (L1 range over the last ``STILL_LAST`` steps <
    ``POINT_STILL``) and close (final L1 < ``POINT_L1``)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(tails), figsize=(4.2 * len(tails), 3.3), sharey=True)
    axes = np.atleast_1d(axes)
    data = {}
    for ax, (label, t) in zip(axes, tails.items(), strict=True):
        flat = t.reshape(-1, t.shape[-1])
        steps = np.arange(EVAL_STEPS - t.shape[-1] + 1, EVAL_STEPS + 1)
        q25, q50, q75 = np.quantile(flat, [0.25, 0.5, 0.75], axis=0)
        ax.fill_between(steps, q25, q75, alpha=0.3)
        ax.plot(steps, q50, lw=2, label="median")
        for row in flat[:: max(1, len(flat) // 12)]:
            ax.plot(steps, row, lw=0.5, color="grey", alpha=0.6)
        ax.axhline(POINT_L1, color="k", ls=":", lw=0.8)
        still = np.ptp(flat[:, -STILL_LAST:], axis=1) < POINT_STILL
        close = flat[:, -1] < POINT_L1
        data[label] = {"episodes": len(flat), "still": float(still.mean()),
                       "close": float(close.mean()), "final_l1_median": float(q50[-1]),
                       "final_l1_q75": float(q75[-1])}
        ax.set(title=f"{label}\nstill {still.mean():.0%}, L1 < {POINT_L1} {close.mean():.0%}",
               xlabel="step", yscale="log")
    axes[0].set_ylabel("L1 to the pointing pose (scaled)")
    fig.suptitle("point from home: the last steps of every greedy episode (band: quartiles; "
                 "grey: some episodes; dotted: the criterion)", fontsize=9)
    fig.tight_layout()
    write_figure(out, name, data, fig)
    return data


def main(argv: list[str] | None = None) -> int:
    """``python -m grounding_jax.paper.al_experiments point-tail SWEEP.toml``: the point-tail figure
    of an AL sweep's base point and the points that change one named field (default:
    ``executed_target``), from the sweep's checkpoints, into the sweep's folder."""
    import argparse

    from grounding_jax import sweep

    ap = argparse.ArgumentParser(prog="python -m grounding_jax.paper.al_experiments")
    ap.add_argument("command", choices=["point-tail"])
    ap.add_argument("file", help="the AL sweep file, e.g. sweeps/al_tuning.toml")
    ap.add_argument("--out", default="results/sweeps", help="where the sweep was run")
    ap.add_argument("--field", default="executed_target",
                    help="the grid field whose points are compared with the base")
    args = ap.parse_args(argv)
    from grounding_jax.core.jaxcache import enable_compilation_cache

    enable_compilation_cache()
    try:
        spec = sweep.load_spec(args.file)
        if args.field not in spec.grid:
            raise sweep.SweepError(f"--field: {args.field!r} is not a grid field of "
                                   f"{args.file}; grid fields: {list(spec.grid)}")
        found = sweep.trained_agents(spec, args.out)
    except (sweep.SweepError, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    pts = spec.points()
    env_config = sweep.module_config(spec, spec.groups()[0][0]).env
    tails = {}
    for i, (episode, agents, hp) in enumerate(found):
        label = sweep.point_label(spec, {k: pts[i][k] for k in spec.grid})
        if i == 0 or label.startswith(f"{args.field}="):
            tails[f"{label} ({episode} episodes)"] = point_tail(agents, hp.env, env_config)
    data = point_tail_figure(tails, pathlib.Path(args.out) / spec.name)
    for label, d in data.items():
        print(f"{label}: still {d['still']:.0%}, final L1 < {POINT_L1} {d['close']:.0%}, "
              f"median final L1 {d['final_l1_median']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
