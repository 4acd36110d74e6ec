"""Action learner (AL) training: learners acting in the env, the whole loop compiled.

``make_train(config) -> train(key, hp) -> (agent, metrics)``; ``vmap`` ``train`` over keys and
hyperparameters for a batch of agents (on the C MuJoCo backend the batch's physics goes to
``mujoco.rollout`` in one call per step). By default each agent steps through its episodes
with auto-reset (`make_steps`: a finished episode's slot starts the agent's next episode
at the next step); the lockstep loop (`make_episodes`: episodes side by side, each
``episode_length`` steps long) gives the same result, bit for bit, more slowly. An agent
trains bit for bit the same alone or in any batch. The trainer drives any
`Learner` through its ``init``/``act``/``update``; the learner
is the one whose config ``ALConfig.learner`` holds (CACLA, the paper's, by default). The
paper's schedule (150 phase-1 + 300 phase-2 episodes) and the no-tricks schedule (plain CACLA
from the start, ~2000 episodes) are configs.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from grounding_jax.core import trees, xla
from grounding_jax.core.checks import (
    FLAG,
    NON_NEGATIVE,
    UNIT_CLOSED,
    Rule,
    check_config,
    check_rules,
    integer_at_least,
)
from grounding_jax.learn import cacla, learners, on_env
from grounding_jax.sim import rollout, sampler, scene, tasks
from grounding_jax.sim.env import (
    DEFAULT_PARAMS,
    Env,
    EnvConfig,
    EnvParams,
    Task,
    as_env,
    scale_joints,
)

#: (phase-1 episodes, phase-2 episodes)
SCHEDULES = {"paper": (150, 300), "no_tricks": (0, 2000)}


#: Where training episodes put the objects: the paper's slots, or anywhere
#: (`placement.sample`, one placement per episode).
PLACEMENTS = sampler.PLACEMENTS

#: What each count of `ALConfig` accepts (its ``__post_init__`` and the sweep runner
#: read it).
CONFIG_RULES: dict[str, Rule] = {"phase1_episodes": integer_at_least(0),
                                 "phase2_episodes": integer_at_least(0)}


@dataclasses.dataclass(frozen=True)
class ALConfig:
    """Static configuration of AL training.

    Attributes:
        env: the env's static config (backend, substeps, episode length).
        learner: the learner's static config (network sizes, ...); its type names the
            learner (default: CACLA's `cacla.CaclaConfig`).
        phase1_episodes: episodes with the phase-1 actor rule (reward rose).
        phase2_episodes: episodes of plain CACLA after them.
        actions: action indices to draw tasks from (None, the default: every action of the
            env's task set).
        positions: position indices to draw tasks from (default all three).
        random_layout: draw the layout per episode (else layout 0 always).
        placement: ``"fixed"`` (the paper's three slots) or ``"random"`` (each episode
            places the objects anywhere on the reachable table; the ``"free"`` task set
            tells the actor the target's coordinates).
    """

    env: EnvConfig = EnvConfig()
    learner: Any = cacla.CaclaConfig()
    phase1_episodes: int = 150
    phase2_episodes: int = 300
    actions: tuple[int, ...] | None = None
    positions: tuple[int, ...] = (0, 1, 2)
    random_layout: bool = True
    placement: str = "fixed"

    def __post_init__(self) -> None:
        check_config(self, CONFIG_RULES)
        if self.placement not in PLACEMENTS:
            raise ValueError(f"placement: unknown value {self.placement!r}; accepted values: "
                             f"{PLACEMENTS}")
        if self.phase1_episodes + self.phase2_episodes < 1:
            raise ValueError("phase1_episodes + phase2_episodes: must be >= 1")
        n_actions = self.env.tasks.n_actions
        if self.actions is None:
            object.__setattr__(self, "actions", tuple(range(n_actions)))
        learners.for_config(self.learner)
        if self.learner.task_set != self.env.task_set:
            raise ValueError(f"learner.task_set: must be the env's task set "
                             f"{self.env.task_set!r}, got {self.learner.task_set!r}")
        for name, n in (("actions", n_actions), ("positions", tasks.N_POSITIONS)):
            v = getattr(self, name)
            if not v or any(not 0 <= int(i) < n for i in v):
                raise ValueError(f"{name}: must be a non-empty tuple of indices in 0..{n - 1}, "
                                 f"got {v!r}")

    @classmethod
    def from_schedule(cls, schedule: str, **kwargs: Any) -> ALConfig:
        """A config with one of the named `SCHEDULES` (``"paper"``, ``"no_tricks"``)."""
        if schedule not in SCHEDULES:
            raise ValueError(f"schedule: unknown value {schedule!r}; accepted values: "
                             f"{tuple(SCHEDULES)}")
        p1, p2 = SCHEDULES[schedule]
        return cls(phase1_episodes=p1, phase2_episodes=p2, **kwargs)

    @property
    def episodes(self) -> int:
        return self.phase1_episodes + self.phase2_episodes

    @property
    def sampler(self) -> sampler.TaskSampler:
        """The `sampler.TaskSampler` its episodes' tasks are drawn by."""
        return sampler.TaskSampler(actions=self.actions, positions=self.positions,
                                   random_layout=self.random_layout, placement=self.placement)

    @property
    def learning(self) -> learners.Learner:
        """The `Learner` that ``learner`` configures."""
        return learners.for_config(self.learner)


@struct.dataclass
class ALHyper:
    """Traced hyperparameters: the learner's, the env's, and the trainer's own.

    ``learner``: the learner's traced hyperparameters (their type must match the learner of
    ``ALConfig.learner``; default CACLA's `cacla.CaclaHyper`).

    ``executed_target``: 1.0 -- the learner is given the action the arm executed (the
    explored action after the servo target is clipped at the joint limits, and limited to the
    actor's range [-1, 1]); 0.0 -- the explored action itself (the paper). At a joint limit
    the explored action has no effect, so the paper's rule can drive the actor's output into
    the limit and saturate it there, where its tanh gradient is too small to come back.

    ``told``: ``None`` (the paper: the actor is told the target's true position) or the
    units the actor is told instead, per layout, position and the word that names the
    target, float32 ``[36, 3, 2, 3]`` (word 0 its shape, 1 its colour; e.g. a TL's current
    estimates, `grounding_jax.learn.together.told_table`): each episode draws one of the two
    words. The reward still follows the true position.

    ``start_ramp``: 0.0 -- every training episode starts within ``env.start_noise`` of home;
    in (0, 1] -- a curriculum: the start's range grows from 0 (home) to ``env.start_noise``
    over that fraction of the run, linearly in the episode's progress, and stays there.

    ``start_by_action``: ``None`` -- every action's episodes start within ``env.start_noise``
    of home; float32 ``[n_actions]`` -- each action's start noise is ``env.start_noise``
    times its entry (e.g. ``[0, 0, 1]``: only push trains from random starts).
    """

    learner: Any = cacla.CaclaHyper()
    env: EnvParams = EnvParams()
    executed_target: Any = 0.0
    told: Any = None
    start_ramp: Any = 0.0
    start_by_action: Any = None


#: What each of `ALHyper`'s own fields accepts (``validate`` and the sweep runner read
#: it; the learner's and the env's fields have their own tables).
HYPER_RULES: dict[str, Rule] = {"executed_target": FLAG, "start_ramp": UNIT_CLOSED}


def hyper(learner: learners.Learner | None = None, **fields: Any) -> ALHyper:
    """An `ALHyper` from flat field names: each goes to the learner's hyperparameters
    (default CACLA's), the env's `EnvParams` or `ALHyper` itself, by name.

    Raises:
        ValueError: a name that none of the three has (naming it and the accepted ones).
    """
    learner = learner or cacla.LEARNER
    owners = {"learner": learner.hyper_type, "env": EnvParams, "al": ALHyper}
    # the fields each owner takes by name (ALHyper's parts are not flat fields)
    names = {o: set(t.__dataclass_fields__) - {"learner", "env"} for o, t in owners.items()}
    parts: dict[str, dict[str, Any]] = {o: {} for o in owners}
    for name, value in fields.items():
        owner = next((o for o, ns in names.items() if name in ns), None)
        if owner is None:
            raise ValueError(f"{name}: not a field of the learner, the env or the trainer; "
                             f"accepted fields: {sorted(set().union(*names.values()))}")
        parts[owner][name] = value
    return ALHyper(learner=learner.hyper_type(**parts["learner"]),
                   env=EnvParams(**parts["env"]), **parts["al"])


def validate(hp: ALHyper) -> ALHyper:
    """ValueError naming the field for bad concrete values (before any compile)."""
    check_rules(hp.learner, learners.for_hyper(hp.learner).hyper_rules)
    hp.env.validate()
    check_rules(hp, HYPER_RULES)
    _check_told(hp.told)
    _check_start_by_action(hp.start_by_action)
    return hp


def _check_start_by_action(scale: Any, n_actions: int | None = None) -> None:
    """ValueError naming ``start_by_action`` unless it is None or numbers >= 0 of shape
    ``[..., n_actions]`` (any last axis when ``n_actions`` is None; traced values: the shape)."""
    if scale is None:
        return
    concrete = not any(isinstance(v, jax.core.Tracer) for v in jax.tree.leaves(scale))
    shape = np.shape(scale) if concrete else jnp.shape(jnp.asarray(scale))
    ok = len(shape) >= 1 and (n_actions is None or shape[-1] == n_actions)
    if ok and concrete:
        ok = NON_NEGATIVE.holds(scale)
    if not ok:
        want = "n_actions" if n_actions is None else str(n_actions)
        raise ValueError(f"start_by_action: got {scale!r}; accepted: None or numbers >= 0 of "
                         f"shape [..., {want}] (one per action)")


#: the trailing shape of `ALHyper.told`: layouts, positions, words, units
TOLD_SHAPE = (len(scene.LAYOUTS), len(scene.POSITIONS), 2, 3)


def _check_told(told: Any) -> None:
    """ValueError naming ``told`` unless it is None or finite numbers ``[..., *TOLD_SHAPE]``
    (a traced table's shape is checked, its values where they are concrete)."""
    if told is None:
        return
    traced = isinstance(told, jax.core.Tracer)
    shape, dtype = tuple(jnp.shape(told)), jnp.result_type(told)
    if len(shape) < 4 or shape[-4:] != TOLD_SHAPE or not jnp.issubdtype(dtype, jnp.number) \
            or not (traced or np.isfinite(np.asarray(told)).all()):
        raise ValueError(f"told: got {dtype} of shape {shape}; accepted: None or finite "
                         f"numbers of shape [..., {', '.join(map(str, TOLD_SHAPE))}] (layouts, "
                         "positions, words, units)")


def _check_learner(config: ALConfig, hp: ALHyper) -> learners.Learner:
    """The config's learner; ValueError if ``hp.learner`` is another learner's, or
    ``hp.start_by_action`` has not one entry per action of the config's task set (at trace
    time, before anything runs)."""
    lrn = config.learning
    _check_start_by_action(hp.start_by_action, config.env.tasks.n_actions)
    if not isinstance(hp.learner, lrn.hyper_type):
        raise ValueError(f"learner: hyperparameters {type(hp.learner).__name__} do not belong "
                         f"to the config's learner {lrn.name!r} (accepted: "
                         f"{lrn.hyper_type.__name__})")
    return lrn


def executed_action(q: jax.Array, ctrl: jax.Array, action_scale) -> jax.Array:
    """The action the arm executed: the servo target ``ctrl`` (radians, after clipping at the
    joint limits) relative to the joints ``q``, in action units, limited to [-1, 1]."""
    return jnp.clip((scale_joints(ctrl) - scale_joints(q)) / action_scale, -1.0, 1.0)


#: The trainer's loops (`make_episodes` and `make_steps`).
LOOPS = ("auto_reset", "lockstep")


def _check_loop(loop: str) -> str:
    if loop not in LOOPS:
        raise ValueError(f"loop: unknown value {loop!r}; accepted values: {LOOPS}")
    return loop


class _Parts:
    """What both loops share: the episode's draw, one learning step, the episode's metrics."""

    def __init__(self, config: ALConfig) -> None:
        self.config = config
        self.env = Env(config.env)
        self.lrn = config.learning
        self.length = config.env.episode_length
        self.sampler = config.sampler

    def draw(self, key: jax.Array, hp: ALHyper | None = None
             ) -> tuple[Task, jax.Array, jax.Array]:
        """An episode's key -> (task, reset key, one exploration key per step); with
        ``hp.told`` the task carries the units told for one of the target's two words."""
        k_task, k_reset, k_steps = jax.random.split(key, 3)
        task = self.sampler.sample(k_task)
        # a key of its own: the other draws stay as without it
        if hp is not None and hp.told is not None:
            _check_told(hp.told)
            word = jax.random.bernoulli(jax.random.fold_in(k_task, 2)).astype(jnp.int32)
            task = task.replace(target_units=hp.told[task.layout, task.position, word])
        return task, k_reset, jax.random.split(k_steps, self.length)

    def learn(self, agent, state, k: jax.Array, lhp, hp: ALHyper):
        """Act, step the env, update the learner (not where the episode has ended).

        Returns:
            (agent, next state, this step's record: reward, live, touched, delta²).
        """
        env, lrn = self.env, self.lrn
        a, _ = lrn.act(agent, state.obs, k, lhp)
        nxt = env.step(state, a, hp.env)
        target = jnp.where(hp.executed_target > 0.5,
                           executed_action(state.qpos[env.arm_qpos], nxt.info["ctrl"],
                                           hp.env.action_scale), a)
        tr = learners.Transition(obs=state.obs, action=target, reward=nxt.reward,
                                 next_obs=nxt.obs, done=nxt.done, prev_reward=state.reward)
        new, info = lrn.update(agent, tr, lhp, self.config.learner)
        live = ~state.done  # steps after the episode ended change nothing
        agent = jax.tree.map(lambda n, o: jnp.where(live, n, o), new, agent)
        record = {"reward": jnp.where(live, nxt.reward, 0.0), "live": live,
                  "touched": nxt.metrics["touched_target"],
                  "delta_sq": jnp.where(live, info["delta"] ** 2, 0.0)}
        return agent, nxt, record

    def metrics(self, last, task: Task, record: dict[str, jax.Array]) -> dict[str, jax.Array]:
        """The episode's metrics from its last state and its steps' records ``[length]``."""
        live = record["live"]
        steps = jnp.sum(live)
        late = (jnp.arange(self.length) >= steps - 10) & live
        return {
            "return": learners.ordered_sum(record["reward"]), "final_reward": last.reward,
            "td_error": jnp.sqrt(learners.ordered_sum(record["delta_sq"]) / jnp.maximum(steps, 1)),
            "final_point_l1": last.metrics["point_l1"],
            "final_palm_target_dist": last.metrics["palm_target_dist"],
            "touched_target_late": jnp.any((record["touched"] > 0) & late).astype(jnp.float32),
            "wrong_moved": (last.wrong_since >= 0).astype(jnp.float32),
            "target_moved": last.metrics["target_moved"],
            "steps": steps, "action": task.action, "position": task.position,
        }


def make_episodes(config: ALConfig):
    """Build ``run(agent, keys, plan, hp) -> (agent, metrics)``: one episode per key, in
    order, under ``lax.scan`` -- the lockstep loop: every episode runs ``episode_length`` steps,
    those after its end masked (batched, a finished episode's slot idles until the longest
    episode of the batch is done). ``plan`` (from `schedule`) holds per-episode arrays:
    ``phase1`` (1.0 where the phase-1 rule applies) and ``progress`` (0 -> 1 over the run).

    Training in chunks of episodes (a host loop with progress and checkpoints) calls this on
    consecutive slices of the keys; the result equals one `make_train` call.
    """
    parts = _Parts(config)
    env, lrn = parts.env, parts.lrn

    def episode(agent, xs, hp: ALHyper):
        key, plan = xs
        task, k_reset, step_keys = parts.draw(key, hp)
        lhp = lrn.at_episode(hp.learner, plan["phase1"], plan["progress"])
        state = env.reset(k_reset, task, env_at(hp, plan["progress"], task.action))

        def step(carry, k):
            agent, state = carry
            agent, nxt, record = parts.learn(agent, state, k, lhp, hp)
            return (agent, nxt), record

        (agent, last), record = jax.lax.scan(step, (agent, state), step_keys)
        return agent, parts.metrics(last, task, record)

    def run(agent, keys: jax.Array, plan: dict[str, jax.Array], hp: ALHyper):
        _check_learner(config, hp)
        return jax.lax.scan(lambda a, xs: episode(a, xs, hp), agent, (keys, plan))

    return run


def make_steps(config: ALConfig):
    """Build ``run(agent, keys, plan, hp) -> (agent, metrics)`` like `make_episodes`,
    step by step with auto-reset: a ``lax.while_loop`` over RL steps in which an episode that
    ends is followed, at the next step, by the agent's next episode.

    Batched with ``vmap``, each agent runs its own episodes at its own pace (its own episode
    counter picks its phase and decays), so every physics call carries every agent that still
    has episodes to run. The result is the same as `make_episodes`' -- the same draws,
    the same exploration keys, the same steps -- only the idle steps are gone.
    """
    parts = _Parts(config)
    env, lrn, length = parts.env, parts.lrn, parts.length

    def run(agent, keys: jax.Array, plan: dict[str, jax.Array], hp: ALHyper):
        _check_learner(config, hp)
        n = keys.shape[0]
        tasks_, k_resets, step_keys = jax.vmap(lambda k: parts.draw(k, hp))(keys)

        def task_at(e):
            return jax.tree.map(lambda x: x[e], tasks_)

        # every reset of the chunk at once (one batched physics call; resets do not depend
        # on earlier episodes), so the loop restarts an episode by picking its first state
        firsts = jax.vmap(lambda k, t, p: env.reset(k, t, env_at(hp, p, t.action)))(
            k_resets, tasks_, plan["progress"])
        state = jax.tree.map(lambda x: x[0], firsts)
        lhp0 = lrn.at_episode(hp.learner, plan["phase1"][0], plan["progress"][0])
        _, nxt, record = jax.eval_shape(parts.learn, agent, state, step_keys[0, 0], lhp0, hp)
        blank = jax.tree.map(lambda x: jnp.zeros((length,) + x.shape, x.dtype), record)
        out = jax.tree.map(lambda x: jnp.zeros((n,) + x.shape, x.dtype),
                           jax.eval_shape(parts.metrics, nxt, task_at(0), blank))

        def body(carry):
            agent, state, e, records, out = carry
            t = state.step
            lhp = lrn.at_episode(hp.learner, plan["phase1"][e], plan["progress"][e])
            agent, nxt, record = parts.learn(agent, state, step_keys[e, t], lhp, hp)
            records = jax.tree.map(lambda b, v: b.at[t].set(v), records, record)
            ended = nxt.done
            m = parts.metrics(nxt, task_at(e), records)
            out = jax.tree.map(lambda o, v: o.at[e].set(jnp.where(ended, v, o[e])), out, m)
            e_next = e + ended.astype(e.dtype)
            first = jax.tree.map(lambda x: x[jnp.minimum(e_next, n - 1)], firsts)
            state = jax.tree.map(lambda f, x: jnp.where(ended & (e_next < n), f, x), first, nxt)
            records = jax.tree.map(lambda b, z: jnp.where(ended, z, b), records, blank)
            return agent, state, e_next, records, out

        carry = (agent, state, jnp.zeros((), jnp.int32), blank, out)
        agent, _, _, _, out = jax.lax.while_loop(lambda c: c[2] < n, body, carry)
        return agent, out

    return run


def env_at(hp: ALHyper, progress: jax.Array, action: jax.Array | None = None) -> EnvParams:
    """``hp.env`` for an episode of ``action`` at ``progress`` (0 -> 1 over the run): its start
    noise grown by the ``start_ramp`` curriculum (unchanged where the ramp is 0) and scaled
    by the action's ``start_by_action`` entry (where it is set)."""
    ramp = jnp.asarray(hp.start_ramp, jnp.float32)
    grown = jnp.where(ramp > 0, jnp.clip(progress / jnp.maximum(ramp, 1e-6), 0.0, 1.0), 1.0)
    if hp.start_by_action is not None:
        if action is None:  # scaling nothing would silently give every action the same starts
            raise ValueError("action: None, but start_by_action is set; accepted: the "
                             "episode's action (an int32 index)")
        grown = grown * jnp.asarray(hp.start_by_action, jnp.float32)[action]
    return hp.env.replace(start_noise=hp.env.start_noise * grown)


def schedule(key: jax.Array, config: ALConfig, hp: ALHyper | None = None
             ) -> tuple[Any, jax.Array, dict[str, jax.Array]]:
    """The key split once: (initial learner state -- the learner's ``init`` with ``hp`` --,
    one key per episode, the per-episode plan: ``phase1`` flags and ``progress`` 0 -> 1)."""
    k_init, k_eps = jax.random.split(key)
    plan = _plan(config, jnp.arange(config.episodes))
    hp = ALHyper(learner=config.learning.hyper_type()) if hp is None else hp
    agent = _check_learner(config, hp).init(k_init, config.learner, hp.learner)
    return agent, jax.random.split(k_eps, config.episodes), plan


def _plan(config: ALConfig, e: jax.Array) -> dict[str, jax.Array]:
    """The plan of episodes ``e``: ``phase1`` flags and ``progress`` 0 -> 1 over the run."""
    return {"phase1": (e < config.phase1_episodes).astype(jnp.float32),
            "progress": e.astype(jnp.float32) / max(config.episodes - 1, 1)}


def make_pieces(config: ALConfig, loop: str = "auto_reset"):
    """Build ``(start, advance)``: a batch of agents trained piece by piece, each agent at its
    own episode -- what a search needs to stop a run, start another in its place, or copy an
    agent into another run at a chunk's end without compiling again.

    ``start(keys, hp) -> state`` splits each key as `make_train` does: ``state`` is
    ``{"agent": [agents], "keys": one key per episode [agents, episodes], "done": episodes
    trained [agents]}``. ``advance(state, hp, episodes) -> (state, metrics)`` trains every
    agent ``episodes`` more of its own episodes (its phase and decays follow its own count;
    ``hp`` per agent) and returns the metrics ``[agents, episodes]`` of `make_train`.
    An agent trained to the end this way has seen the same episodes as one trained by
    `make_train` with its key.
    """
    _check_loop(loop)

    def start(keys: jax.Array, hp: ALHyper) -> dict[str, Any]:
        axes, treedef = _hp_layout(hp)
        agent, ep_keys, _ = _batched_schedule(config, axes, treedef)(keys, hp)
        return {"agent": agent, "keys": ep_keys,
                "done": jnp.zeros(keys.shape[:1], jnp.int32)}

    def advance(state: dict[str, Any], hp: ALHyper, episodes: int):
        axes, treedef = _hp_layout(hp)
        agent, metrics = _batched_pieces(config, axes, treedef, int(episodes), loop)(
            state["agent"], state["keys"], state["done"], hp)
        return {**state, "agent": agent, "done": state["done"] + episodes}, metrics

    return start, advance


def _hp_layout(hp: ALHyper) -> tuple[tuple, Any]:
    axes, treedef = jax.tree.flatten(jax.tree.map(lambda x: 0 if jnp.ndim(x) else None, hp),
                                     is_leaf=lambda x: x is None)
    return tuple(axes), treedef


@functools.lru_cache(maxsize=16)
def _batched_pieces(config: ALConfig, hp_axes: tuple, hp_treedef, episodes: int, loop: str):
    """``jit(vmap(...))`` of ``episodes`` episodes of each agent from its own count,
    cached like `_batched_episodes`."""
    run = _loop_maker(loop)(config)

    def one(agent, keys, done, hp):
        plan = _plan(config, done + jnp.arange(episodes))
        return run(agent, jax.lax.dynamic_slice_in_dim(keys, done, episodes), plan, hp)

    axes = jax.tree.unflatten(hp_treedef, hp_axes)
    return xla.physics_jit(jax.vmap(one, in_axes=(0, 0, 0, axes)), config.env.backend)


def _loop_maker(loop: str):
    return make_steps if _check_loop(loop) == "auto_reset" else make_episodes


def make_train(config: ALConfig, loop: str = "auto_reset", env: Any = None):
    """Build ``train(key, hp) -> (agent, metrics)`` for one agent (vmap it for a batch).

    The key is split once into the agent's initial weights and one key per episode (task draw,
    reset, exploration noise).

    Args:
        config: static config.
        loop: ``"auto_reset"`` (`make_steps`, the default) or ``"lockstep"``
            (`make_episodes`); both give the same agent and metrics, bit for bit.
        env: train on this env instead of ``config.env``'s: any env with ``reset(rng)``,
            ``step(state, action)``, ``observation_size`` and ``action_size`` (a Brax env,
            `grounding_jax.envs.load`); the learner's sizes must match it
            (``CaclaConfig(obs_dim=..., act_dim=...)``). Episodes last the env's
            ``episode_length`` if it has one, else ``config.env.episode_length``, and run in
            lockstep (`grounding_jax.learn.on_env`); ``metrics`` then hold ``return``,
            ``final_reward``, ``td_error`` and ``steps``.

    Returns:
        ``metrics``: per-episode arrays ``[episodes]``: ``return`` (sum of rewards over the
        steps taken), ``final_reward``, ``td_error`` (the critic's RMS TD error over the
        episode's steps), ``final_point_l1``, ``final_palm_target_dist``,
        ``touched_target_late`` (touched the target in one of the last 10 steps),
        ``wrong_moved``, ``target_moved``, ``steps``, ``action``, ``position``.
    """
    if env is None:
        run = _loop_maker(loop)(config)
    else:
        length = on_env.check_env(env, config.learner) or config.env.episode_length
        run = on_env.make_episodes(env, config.learner, length)

    def train(key: jax.Array, hp: ALHyper) -> tuple[Any, dict[str, jax.Array]]:
        agent, keys, plan = schedule(key, config, hp)
        return run(agent, keys, plan, hp)

    return train


@functools.lru_cache(maxsize=16)
def _batched_episodes(config: ALConfig, hp_axes: tuple, hp_treedef, loop: str = "auto_reset"):
    """``jit(vmap(...))`` of the loop's runner, kept per static config, loop and batched-hp
    layout: a later batch with the same config and shapes (another sweep, another chunk)
    reuses the compiled code instead of compiling it again (host-callback code is not in
    JAX's persistent cache)."""
    axes = jax.tree.unflatten(hp_treedef, hp_axes)
    return xla.physics_jit(jax.vmap(_loop_maker(loop)(config), in_axes=(0, 0, None, axes)),
                           config.env.backend)


@functools.lru_cache(maxsize=16)
def _batched_schedule(config: ALConfig, hp_axes: tuple, hp_treedef):
    """``jit(vmap(schedule))``, cached like `_batched_episodes`. Run eagerly instead,
    its random draws would compile one small XLA program per op and shape (~20 s of a quick
    profile)."""
    axes = jax.tree.unflatten(hp_treedef, hp_axes)
    return jax.jit(jax.vmap(lambda k, h: schedule(k, config, h), in_axes=(0, axes)))


def train_in_chunks(config: ALConfig, keys: jax.Array, hp: ALHyper, stops: list[int],
                    on_stop=None, start: tuple | None = None, sharding=None,
                    loop: str = "auto_reset", progress_fn=None):
    """Train a batch of agents (``keys`` [agents], ``hp`` batched or shared) in a host loop
    over chunks of episodes ending at each of ``stops`` (the last must be
    ``config.episodes``).

    Args:
        config: static config.
        keys: one key per agent (split once, as in `make_train`).
        hp: hyperparameters; leaves with a leading axis are per agent.
        stops: episode counts at which a chunk ends.
        on_stop: ``on_stop(episode, agents, metrics)`` after each chunk, with the metrics so
            far (``[agents, config.episodes]``, zeros after ``episode``) -- where progress
            bars and checkpoints hang.
        start: ``(episode, agents, metrics)`` saved by ``on_stop``: training resumes after
            ``episode`` (the result is bit-identical to an uninterrupted run).
        sharding: a ``jax.sharding.Sharding`` of the agent axis (e.g. over local devices);
            None keeps the default device.
        loop: ``"auto_reset"`` (default) or ``"lockstep"``, as in `make_train`.
        progress_fn: ``progress_fn(num_steps, metrics)`` after each chunk, as Brax's trainers
            call it: ``num_steps`` the env steps taken so far by all agents together,
            ``metrics`` floats (see `progress_metrics`).

    Returns:
        (agents, metrics [agents, episodes]) -- equal to ``vmap(make_train(config))``.
    """
    _check_loop(loop)
    if not stops or sorted(stops) != list(stops) or stops[-1] != config.episodes or stops[0] < 1:
        raise ValueError(f"stops: must be increasing, >= 1 and end at {config.episodes}, "
                         f"got {stops!r}")
    axes, treedef = jax.tree.flatten(jax.tree.map(lambda x: 0 if jnp.ndim(x) else None, hp),
                                     is_leaf=lambda x: x is None)
    run = _batched_episodes(config, tuple(axes), treedef, loop)
    agents, ep_keys, plan = _batched_schedule(config, tuple(axes), treedef)(keys, hp)
    plan = jax.tree.map(np.asarray, trees.take(plan, 0))  # the same for every agent
    done = 0
    metrics = None
    if start is not None:
        done, agents, metrics = start
    if sharding is not None:
        agents, ep_keys, metrics = jax.device_put((agents, ep_keys, metrics), sharding)
        hp = jax.tree.map(lambda x: jax.device_put(x, sharding) if jnp.ndim(x) else x, hp)
    for stop in (s for s in stops if s > done):
        chunk = slice(done, stop)
        agents, m = run(agents, ep_keys[:, chunk], jax.tree.map(lambda x, c=chunk: x[c], plan),
                        hp)
        if metrics is None:
            metrics = trees.zeros_columns(m, config.episodes)
        metrics = trees.put_columns(metrics, m, done)
        done = stop
        if on_stop is not None:
            on_stop(stop, agents, metrics)
        if progress_fn is not None:
            progress_fn(*progress_metrics(metrics, stop))
    return agents, metrics


def progress_metrics(metrics: dict[str, Any], episodes: int) -> tuple[int, dict[str, float]]:
    """``(num_steps, scalars)`` of the first ``episodes`` of ``metrics`` ``[agents,
    episodes]``, on the host (NumPy): the env steps all agents took, and per metric
    ``train/<name>`` its mean over agents and those episodes, plus ``train/episodes``."""
    host = {k: np.asarray(v)[:, :episodes] for k, v in metrics.items()}
    scalars = {f"train/{k}": float(v.mean()) for k, v in host.items()
               if k not in ("action", "position")}
    scalars["train/episodes"] = float(episodes)
    return int(host["steps"].sum()) if "steps" in host else 0, scalars


def make_eval(env: Env | EnvConfig | None = None, steps: int | None = None,
              learner: learners.Learner | None = None):
    """Build ``evaluate(agent, key, task, env_params) -> (first, trajectory, hidden)``: the
    learner's greedy policy (no exploration) for one episode; the trajectory is the env states
    after each step, stacked, and ``hidden`` the policy's hidden features at each step (for
    the namer).

    Args:
        env: the env (or its static config; default ``EnvConfig()``).
        steps: steps per episode (default: the env's episode length).
        learner: the learner whose states are evaluated (default: the one the agent's type
            belongs to).
    """
    env = as_env(env)
    n = env.config.episode_length if steps is None else steps

    def evaluate(agent, key: jax.Array, task: Task, env_params: EnvParams = DEFAULT_PARAMS):
        lrn = learner or learners.for_state(agent)

        def policy(state, _):
            return lrn.policy(agent, state.obs)

        first = env.reset(key, task, env_params)
        traj, hidden = rollout.rollout(env, first, policy, n, env_params)
        return first, traj, hidden

    return evaluate
