"""Beyond the paper: a robot that acts on objects anywhere on the table, and follows a target
that moves.

The paper's family (three fixed slots, the actor told the target's slot) stays as it is. This
one uses the ``"free_hand"`` task set: the same actions and success rules, but every training
episode places the objects anywhere on the reachable table (`placement.sample`) and the
actor is told the target's coordinates (as a population code, `placement.population`;
from the simulator while it learns, from the continuous TL `grounding_jax.learn.tl_xy` when the
robot performs) and sees where its palm is relative to them (``TaskSet.hand_obs``). Point's
reward and success use the pointing map (IK poses on a 1 cm grid, smoothed, interpolated
inside ``jit``; `placement.pointing_pose`), and touch's reward the touching map in the
same way (the palm pressed on the target's top; `placement.touch_pose`).

The learner's settings are `FREE_TUNED` (the paper family's but for gamma 0.3 and the
actor's learning rate 0.1), its networks `FREE_LEARNER` (an actor-critic per action);
the target's coordinates reach the actor as a population code, and the rewards are the free
family's (see ``tasks.FREE``: every action is penalised for touching a non-target object,
touch reaches for its touching pose, without the paper's penalty for touching the target).

- `train` / `success`: agents trained on random placements, judged on held-out
  random placements (fresh draws, random layouts) with the action-learning criteria.
- `moving`: the target slides at 0-3 cm/s along a 20-22 cm path; the actor told the
  target's current coordinates every step against the same actor told only where it started
  (the paper's setting). Figure ``moving.png`` (like Fig 13, for motion instead of a switch).
- `train_namer`: an ESN that names the free actor's action and target from its hidden
  layer and the continuous TL's (as the paper's AN does from the paper's actor and TL).
- `strip`: camera frames of one episode of the whole robot (render -> TL -> act ->
  name).
"""

from __future__ import annotations

import functools
import pathlib
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core import xla
from grounding_jax.core.io import pyplot, write_figure
from grounding_jax.learn import al, cacla
from grounding_jax.paper import al_eval
from grounding_jax.paper import al_experiments as alx
from grounding_jax.sim import placement as free
from grounding_jax.sim import scene, tasks, tl_data
from grounding_jax.sim.env import Env, EnvConfig, EnvParams, Task

#: The success goals on held-out placements.
GOALS = {"point": 0.90, "touch": 0.80, "push": 0.85}
#: Speeds (m/s) of the moving-target experiment.
SPEEDS = (0.0, 0.01, 0.02, 0.03)
#: Steps of a moving-target episode (10 s: 1 cm/s covers 10 cm).
MOVING_STEPS = 200


def env_config(backend: str = "mujoco") -> EnvConfig:
    """The free family's env (``task_set="free_hand"``: the actor sees the target's
    coordinates and where its palm is relative to them)."""
    return EnvConfig(backend=backend, task_set=tasks.FREE_HAND.name)


#: The free family's networks: the paper's sizes, one actor-critic per action (one network
#: for all three left some agents that never learned to point; without the hand units touch
#: needed push's network beside it, with them it learns best alone: docs/beyond.md).
FREE_LEARNER = cacla.CaclaConfig(task_set=tasks.FREE_HAND.name, heads=(0, 1, 2))


def config(phase1: int, phase2: int, backend: str = "mujoco") -> al.ALConfig:
    """AL training on random placements with the paper's schedule shape."""
    return al.ALConfig(env=env_config(backend), learner=FREE_LEARNER,
                       phase1_episodes=phase1, phase2_episodes=phase2, placement="random")


#: The free family's learner and env settings: the paper family's shipped ones
#: (``al_experiments.TUNED`` + ``TUNED_AL``) but for gamma, the actor's learning rate and the
#: action's scale (finer steps: an arm that arrives gently touches without shoving), with
#: touch's reward weights, chosen on tuning keys and seeds train.py never reports with
#: (docs/beyond.md; ``sweeps/free_al_tuning.toml``).
FREE_TUNED = {**alx.TUNED, **alx.TUNED_AL, "gamma": 0.3, "actor_lr": 0.1, "action_scale": 0.15,
              "touch_moved_penalty": 10.0, "touch_bonus": 0.0}


def hyper() -> al.ALHyper:
    """The free family's shipped settings (`FREE_TUNED`)."""
    return al.validate(al.hyper(**FREE_TUNED))


def params() -> EnvParams:
    """The env parameters the free family's robot acts with (`FREE_TUNED`'s)."""
    return hyper().env


def make_success(env: Env, key: jax.Array, placements: int):
    """``success(agents, key) -> out``: every action at every slot of ``placements``
    held-out random placements (drawn from ``key``), as ``al_eval.make_success``."""
    return al_eval.make_success(env, batch=al_eval.free_tasks(key, placements))


def success(out: dict) -> dict:
    """The success table of `make_success`'s output (median agent and spread)."""
    table = al_eval.success_table(out)
    table["goals"] = GOALS
    table["met"] = {a: table["by_action"][a] >= g for a, g in GOALS.items()}
    return table


#: How `choose` picks the agent to save, in words (REPORT, metrics).
SELECTION = ("the agent whose worst margin over the goals (success minus goal, per action) is "
             "largest on validation placements, ties broken by the overall rate")


def choose(table: dict) -> int:
    """The agent to save, from a `success` table on validation placements: the one
    whose worst margin over `GOALS` is largest (ties: the higher overall rate)."""
    per = table["per_agent_by_action"]
    worst = np.min([np.asarray(per[a]) - g for a, g in GOALS.items()], axis=0)
    return int(np.lexsort((-np.asarray(table["per_agent"]), -worst))[0])


def train(key: jax.Array, seeds: int, phase1: int, phase2: int, eval_placements: int,
          checkpoints: tuple[int, ...] = (), backend: str = "mujoco") -> tuple[dict, Any]:
    """Train ``seeds`` agents on random placements; judge them on held-out placements at each
    of ``checkpoints`` episodes and at the end.

    The agent to save is chosen on validation placements (another draw than the held-out
    ones the tables report): `choose`.

    Returns:
        (results: ``success`` {episode: table}, ``final``, ``train_s``, ``rl_steps``,
        ``median_agent`` -- the index of the agent with the median overall rate on the
        held-out placements --, ``validation`` (the table on the validation placements) and
        ``saved_agent`` (`choose`'s pick on them); the trained agents ``[seeds]``).
    """
    cfg = config(phase1, phase2, backend)
    env = Env(cfg.env)
    hp = hyper()
    # (split is prefix-stable: the first three keys are those of the runs before validation)
    k_train, k_place, k_eval, k_val = jax.random.split(key, 4)
    judge = make_success(env, k_place, eval_placements)
    tables: dict[str, dict] = {}

    def measure(episode: int, agents, _metrics) -> None:
        tables[str(episode)] = success(judge(agents, k_eval, hp.env))
        ba = tables[str(episode)]["by_action"]
        print(f"free  episode {episode}: success of the median agent on held-out placements: "
              f"point {ba['point']:.2f} touch {ba['touch']:.2f} push {ba['push']:.2f}",
              flush=True)

    stops = sorted({c for c in checkpoints if 0 < c < cfg.episodes} | {cfg.episodes})
    t = time.perf_counter()
    agents, metrics = al.train_in_chunks(cfg, jax.random.split(k_train, seeds), hp, stops,
                                         measure)
    final = tables[str(cfg.episodes)]
    per_agent = np.asarray(final["per_agent"])
    median_agent = int(np.argsort(per_agent)[(len(per_agent) - 1) // 2])
    k_val_place, k_val_eval = jax.random.split(k_val)
    validation = success(judge(agents, k_val_eval, hp.env,
                               batch=al_eval.free_tasks(k_val_place, eval_placements)))
    saved = choose(validation)
    print(f"free  saved agent {saved} (chosen on validation placements); on the held-out ones: "
          + " ".join(f"{a} {final['per_agent_by_action'][a][saved]:.2f}" for a in GOALS),
          flush=True)
    res = {"seeds": seeds, "phase1": phase1, "phase2": phase2,
           "eval_placements": eval_placements, "success": tables, "final": final,
           "train_s": time.perf_counter() - t,
           "rl_steps": int(np.asarray(metrics["steps"]).sum()), "median_agent": median_agent,
           "validation": validation, "saved_agent": saved, "selection": SELECTION,
           "hyper": FREE_TUNED, "heads": list(FREE_LEARNER.heads), "touch_reward": "pose",
           "push_reward": "centre", "hand_obs": tasks.get(FREE_LEARNER.task_set).hand_obs}
    return res, agents


# ----------------------------------------------------------------------------- moving target
@functools.partial(jax.jit, static_argnums=1)
def _moving_draw(key: jax.Array, scenes: int, speed: jax.Array):
    k_place, k_layout = jax.random.split(key)
    placed, velocity = jax.vmap(lambda k: free.moving(k, speed))(
        jax.random.split(k_place, scenes))
    layout = jax.random.randint(k_layout, (scenes,), 0, len(scene.LAYOUTS), jnp.int32)
    return placed, velocity, layout


def moving_tasks(key: jax.Array, scenes: int, speed: Any, action: int,
                 told_start: bool) -> Task:
    """``scenes`` tasks whose target (the left slot) slides right at ``speed`` m/s
    (`placement.moving`); ``told_start``: the actor is told only where it started."""
    placed, velocity, layout = _moving_draw(key, scenes, jnp.float32(speed))
    i32 = jnp.int32
    return Task(action=jnp.full((scenes,), action, i32), position=jnp.zeros((scenes,), i32),
                layout=layout, placement=placed, velocity=velocity,
                target_xy=placed[:, 0, :2] if told_start else None)


def make_moving(env: Env, steps: int = MOVING_STEPS):
    """``run(agent, keys, tasks, env_params) -> (palm-target distance [scenes, steps], point
    L1 [scenes, steps], wrong moved [scenes])``: greedy episodes of batched moving tasks."""
    evaluate = al.make_eval(env, steps)

    def run(agent, keys, batch: Task, env_params: EnvParams):
        def one(k, task):
            _, traj, _ = evaluate(agent, k, task, env_params)
            return (traj.metrics["palm_target_dist"], traj.metrics["point_l1"],
                    traj.wrong_since[-1] >= 0)
        return jax.vmap(one)(keys, batch)

    return xla.physics_jit(run, env)


def moving(agent, key: jax.Array, out: pathlib.Path, scenes: int = 16,
           speeds: tuple[float, ...] = SPEEDS, steps: int = MOVING_STEPS,
           backend: str = "mujoco") -> dict:
    """Tracking a sliding target: point and touch, each speed, the actor told the target's
    current coordinates every step ("tracking") or only its start ("start only").

    Measures, over the scenes (median and quartiles): the palm's distance to the target's
    current point on its path, and point's L1 to the pose for it, averaged over the
    episode's second half (the arm has arrived; the target still moves at 1-2 cm/s and
    arrives at 3 cm/s) and at the end. Writes ``moving.png`` / ``moving.json``.
    """
    env = Env(env_config(backend))
    run = make_moving(env, steps)
    acting = params()
    keys = jax.random.split(key, scenes)  # the same scenes for every speed, action and robot
    half = slice(steps // 2, None)
    res: dict[str, Any] = {"scenes": scenes, "steps": steps, "dt_s": env._dt,
                           "speeds_m_s": list(speeds), "rows": []}
    curves: dict[str, np.ndarray] = {}
    for action in ("point", "touch"):
        a = tasks.FREE.action_names.index(action)
        for speed in speeds:
            for told in ("tracking", "start only"):
                batch = moving_tasks(key, scenes, speed, a, told == "start only")
                dist, l1, wrong = (np.asarray(x) for x in run(agent, keys, batch, acting))
                late = dist[:, half].mean(axis=1)
                row = {"action": action, "speed_cm_s": round(100 * speed, 1), "robot": told,
                       "palm_target_cm_late": np.quantile(100 * late, [0.25, 0.5, 0.75]
                                                          ).tolist(),
                       "palm_target_cm_final": float(np.median(100 * dist[:, -1])),
                       "point_l1_late": float(np.median(l1[:, half].mean(axis=1))),
                       "point_l1_final": float(np.median(l1[:, -1])),
                       "wrong_moved": float(wrong.mean())}
                res["rows"].append(row)
                curves[f"{action} {speed} {told}"] = dist
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    t = np.arange(1, steps + 1) * env._dt
    fast = max(speeds)
    for ax, action in zip(axes[:2], ("point", "touch"), strict=True):
        for told, colour in (("tracking", "C0"), ("start only", "C3")):
            d = 100 * curves[f"{action} {fast} {told}"]
            q = np.quantile(d, [0.25, 0.5, 0.75], axis=0)
            ax.plot(t, q[1], color=colour, label=f"{told} (median)")
            ax.fill_between(t, q[0], q[2], color=colour, alpha=0.2, lw=0)
        ax.set(xlabel="time (s)", ylabel="palm - target (cm)",
               title=f"{action}: target slides at {100 * fast:.0f} cm/s")
        ax.legend(fontsize=8)
    for action, style in (("point", "-"), ("touch", "--")):
        for told, colour in (("tracking", "C0"), ("start only", "C3")):
            ys = [r["palm_target_cm_late"][1] for r in res["rows"]
                  if r["action"] == action and r["robot"] == told]
            axes[2].plot(100 * np.asarray(speeds), ys, style, color=colour, marker="o",
                         label=f"{action}, {told}")
    axes[2].set(xlabel="target speed (cm/s)", ylabel="palm - target, 2nd half (cm)",
                title="median over scenes")
    axes[2].legend(fontsize=7)
    fig.suptitle(f"A moving target (like Fig 13, for motion): {scenes} scenes, greedy actor")
    fig.tight_layout()
    write_figure(out, "moving", res, fig)
    return res


# ------------------------------------------------------------------------------- the namer
def namer_data(agent, xy_params, xy_config, key: jax.Array, scenes: int, steps: int = 100,
               start_noise: float = 0.0, env: Env | None = None,
               data: Any = None) -> dict:
    """Sequences for the free family's action namer, as `an.dataset` makes them for the
    paper's: for every rendered scene, every target word and every action, the greedy
    actor's hidden layer at each step beside the continuous TL's hidden layer for that scene
    and word (`tl_xy.hidden`).

    Args:
        agent: the free family's actor.
        xy_params, xy_config: the continuous TL.
        key: PRNG key (scenes, then the episodes' resets).
        scenes: scenes to render (random placements and layouts).
        steps: steps per sequence.
        start_noise: random arm starts (0: home).
        env: the free family's env (default `env_config`).
        data: already rendered scenes (``tl_xy.XYData``) instead of new ones.

    Returns:
        ``inputs`` [N, steps, actor hidden + TL hidden], ``action``, ``word``, ``config`` (the
        scene: the namer splits train and test by scene), ``n_configs``, ``data``.
    """
    from grounding_jax.learn import an, tl_xy

    k_scene, k_run = jax.random.split(key)
    if data is None:
        data = tl_xy.render(*tl_xy.draw_scenes(k_scene, scenes))
    n_words, n_actions = len(tasks.TARGET_WORDS), tasks.FREE.n_actions
    scene_i = np.repeat(np.arange(scenes), n_words * n_actions)
    word = np.tile(np.repeat(np.arange(n_words), n_actions), scenes)
    action = np.tile(np.arange(n_actions), scenes * n_words)
    layout = data.layout[scene_i]
    i32 = jnp.int32
    batch = Task(action=jnp.asarray(action, i32),
                 position=jnp.asarray(tl_xy.WORD_SLOT[layout, word], i32),
                 layout=jnp.asarray(layout, i32), placement=jnp.asarray(data.placement[scene_i]))
    h = an.actor_sequences(agent, k_run, batch, steps, params().replace(start_noise=start_noise),
                           env or Env(env_config()))
    tl_h = np.asarray(tl_xy.hidden(xy_params, jnp.asarray(data.bitmaps[scene_i]),
                                   jnp.asarray(tl_xy.SYMBOLS[layout, word]), xy_config))
    tl_part = np.broadcast_to(tl_h[:, None], (len(scene_i), steps, tl_h.shape[1]))
    return {"inputs": np.concatenate([h, tl_part], axis=2).astype(np.float32),
            "action": action, "word": word, "config": scene_i, "n_configs": scenes,
            "data": data}


#: Reservoir units of the free family's namer. The paper's 50 served its 90 inputs (40 actor
#: + 50 TL hidden units); the continuous TL has 200 hidden units, and 50 reservoir units left
#: the actions inseparable (held-out scenes named right 68%, 88% with 100 units, 97% with 200:
#: docs/beyond.md).
FREE_NAMER_RES = 200


def train_namer(key: jax.Array, agent, xy_params, xy_config, scenes: int, seeds: int,
                steps: int = 100, start_noise: float = 0.5, n_res: int = FREE_NAMER_RES
                ) -> tuple[dict, Any]:
    """The free family's action namer: ESNs (the paper's spectral radius and connectivity,
    ``n_res`` reservoir units) over `namer_data`, ``seeds`` splits 2/3 : 1/3 by scene;
    named at the last step.

    Returns:
        (accuracy {train, test, test_random: mean, per seed}, (ESN of seed 0, its config)).
    """
    from grounding_jax.learn import an, esn

    k_home, k_rand, k_esn = jax.random.split(key, 3)
    env = Env(env_config())
    home = namer_data(agent, xy_params, xy_config, k_home, scenes, steps, 0.0, env)
    # the same scenes from random arm starts (a random initial reservoir state too)
    rand = namer_data(agent, xy_params, xy_config, k_rand, scenes, steps, start_noise, env,
                      data=home["data"])
    cfg = esn.ESNConfig(n_in=home["inputs"].shape[-1], n_res=n_res, task_set=tasks.FREE.name)
    runs = [an.train_namer(k, home, rand, config=cfg) for k in jax.random.split(k_esn, seeds)]
    res: dict[str, Any] = {"scenes": scenes, "seeds": seeds, "sequences": len(home["action"]),
                           "n_res": n_res}
    for name in ("train", "test", "test_random"):
        accs = [r[name]["acc"] for r in runs]
        res[name] = {"acc_mean": float(np.mean(accs)), "acc_per_seed": accs}
    return res, (runs[0]["net"], cfg)


# ----------------------------------------------------------------------- the whole robot's eyes
def eyes_tasks(localize, key: jax.Array, placements: int,
               words: tuple[str, ...] = tasks.COLOURS) -> tuple[Task, np.ndarray]:
    """`al_eval.free_tasks` with ``target_xy`` from the robot's eyes: each scene
    rendered by the eye camera at rest, each target named by the one of ``words`` that names
    it (its colour, or with ``tasks.SHAPES`` its shape), located by ``localize(rgb, layout,
    word) -> xy`` (e.g. ``TrainedFree.localize``).

    Returns:
        (the tasks, the TL's error per task in cm).
    """
    from grounding_jax.sim import vision

    batch = al_eval.free_tasks(key, placements)
    r = vision.eye_renderer()
    placed, layouts = np.asarray(batch.placement), np.asarray(batch.layout)
    slots = np.asarray(batch.position)
    xy = np.zeros((len(slots), 2), np.float32)
    seen: dict[int, np.ndarray] = {}
    for i in range(len(slots)):
        key_i = hash(placed[i].tobytes())  # one render per scene
        if key_i not in seen:
            seen[key_i] = r.render(int(layouts[i]), placed[i])
        word = next(w for w in words
                    if tl_data.label_of(int(layouts[i]), tl_data.word_index(w)) == slots[i])
        xy[i] = localize(seen[key_i], int(layouts[i]), word)
    err = 100 * np.linalg.norm(xy - placed[np.arange(len(slots)), slots, :2], axis=1)
    return batch.replace(target_xy=jnp.asarray(xy)), err


def strip(frames: list[np.ndarray], labels: list[str], out: pathlib.Path,
          name: str = "camera_strip", title: str = "") -> pathlib.Path:
    """Write camera frames side by side as ``out/<name>.png`` (with ``<name>.json``: the
    labels and the title); returns the PNG's path."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(frames), figsize=(2.6 * len(frames), 2.4))
    for ax, img, label in zip(np.atleast_1d(axes), frames, labels, strict=True):
        ax.imshow(img)
        ax.set_title(label, fontsize=8)
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    write_figure(out, name, {"labels": labels, "title": title}, fig)
    return pathlib.Path(out) / f"{name}.png"


def episode_frames(layout: int, placement: np.ndarray, trajectory, every: int
                   ) -> tuple[list[np.ndarray], list[str]]:
    """Camera frames of an episode's states, the arm drawn (every ``every`` steps, and the
    last)."""
    from grounding_jax.sim import vision

    r = vision.eye_renderer()
    qpos = np.asarray(trajectory.qpos)
    n = qpos.shape[0]
    picks = sorted(set(range(0, n, every)) | {n - 1})
    return ([r.render(layout, placement, qpos=qpos[i], arm=True) for i in picks],
            [f"step {i + 1}" for i in picks])


