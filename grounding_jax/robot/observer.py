"""Naming an action the robot only watches: motor resonance through its own actor.

The paper's AN names what the robot does itself: it reads the acting actor's hidden layer.
The paper proposes a mirroring mechanism, "based on the motor resonance", so that a robot
could also name what another one does. Here the observer puts itself in the watched arm's
place, step by step:

1. **Resonance.** For each command it knows (action x slot: 3 x 3), at every watched state
   it sets its own observation to that command (the arm's joints and touch sense as watched,
   the command's action and target units), asks its own actor for the move, and imagines
   making it: one env step from the watched state (its body model is the simulator). Two
   mismatches are averaged over the reach -- the episode's first `REACH` /
   ``action_scale`` steps (15 at the paper's scale of 1/3; before the episode ended) --: of
   the joints (squared, scaled units) and of the hand (the palm's position, squared metres)
   between where the imagined step and the watched step lead. The reach says where and how
   the arm goes; after it each agent settles in its own way (agents trained from other seeds
   jitter at rest, or rest in contact where the observer would hover) and says less. The
   command with the smallest product of the two (the sum of their logs: neither's units
   matter) is the one it resonates with. Both are needed: four joints reach one hand
   position in many ways, and agents trained from other seeds touch and push with other joint
   configurations (the paper family's touch and push rewards are distances of the palm),
   while the hand alone misses how an actor that acts in joint space (point, the free
   family's touch) moves.
2. **Naming.** It names that command the way it names its own acts: the AN reads its own
   actor's hidden layer on the watched states (under that command) and the TL's hidden layer
   for a word that names the object in that slot. The observer cannot hear which word the
   watched robot was told ("red" or "sphere"), so it takes the word its own TL places in that
   slot most surely (the paper family) or whose coordinates its continuous TL reads nearest
   that object (the free family); a target word counts as right when it names the target.

What the observer reads of a watched episode: the arm (joints, velocities, touch sense) and
the scene (which layout, where the objects stand and how they move) -- never the watched
robot's command (its task's action and position, its observation's command units, the target
coordinates it was told, its rewards).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.learn import learners
from grounding_jax.sim import tasks, tl_data
from grounding_jax.sim.env import Env, EnvParams, State, Task

N_SLOTS = tasks.N_POSITIONS
#: the reach, in scaled joint units: the resonance weighs the first ``REACH / action_scale``
#: steps (as long as the arm takes to move that far at its full step)
REACH = 5.0


def commands(n_actions: int) -> tuple[np.ndarray, np.ndarray]:
    """Every (action, slot) command, action-major: two int32 arrays ``[n_actions * 3]``."""
    a, p = np.divmod(np.arange(n_actions * N_SLOTS), N_SLOTS)
    return a.astype(np.int32), p.astype(np.int32)


def _command_task(watched: Task, action: jax.Array, slot: jax.Array) -> Task:
    """The observer's own task for a watched state: its command in the watched scene (the
    watched robot's action, position and told coordinates are not carried over)."""
    return Task(action=jnp.broadcast_to(action, watched.layout.shape).astype(jnp.int32),
                position=jnp.broadcast_to(slot, watched.layout.shape).astype(jnp.int32),
                layout=watched.layout, placement=watched.placement,
                velocity=watched.velocity)


def as_command(env: Env, states: State, action: jax.Array, slot: jax.Array) -> State:
    """Watched states ``[T]`` as the observer would see them under its own command."""
    return jax.vmap(env.set_task)(states, _command_task(states.task, action, slot))


def make_resonance(env: Env, learner: learners.Learner):
    """Build ``resonance(agent, states, params) -> errors [2, n_actions, 3]`` for one watched
    episode (``states``: the env states after each step, stacked ``[T >= 2]``): per command,
    the mean squared mismatch of the joints (scaled units; ``errors[0]``) and of the palm
    (metres; ``errors[1]``) between the watched next state and the one the observer's own move
    would reach, over the reach (see the module doc; `score` combines them). Pure;
    ``vmap`` it for batches."""
    n_actions = env.tasks.n_actions
    act_a, act_p = commands(n_actions)
    joints = tasks.OBS_JOINTS

    def one(agent, cur: State, nxt: State, live: jax.Array, params: EnvParams, a, p):
        mine = as_command(env, cur, a, p)
        move = jax.vmap(lambda o: learner.policy(agent, o)[0])(mine.obs)
        imagined = jax.vmap(lambda s, u: env.step(s, u, params))(mine, move)
        err = jnp.stack([
            jnp.sum((imagined.obs[:, joints] - nxt.obs[:, joints]) ** 2, axis=-1),
            jnp.sum((imagined.info["palm_pos"] - nxt.info["palm_pos"]) ** 2, axis=-1)])
        return jnp.sum(err * live, axis=-1) / jnp.maximum(jnp.sum(live), 1.0)

    def resonance(agent, states: State, params: EnvParams) -> jax.Array:
        cur = jax.tree.map(lambda x: x[:-1], states)
        nxt = jax.tree.map(lambda x: x[1:], states)
        reach = jnp.arange(cur.done.shape[0]) < REACH / params.action_scale
        live = jnp.where(reach & ~cur.done, 1.0, 0.0)
        errs = jax.vmap(one, in_axes=(None, None, None, None, None, 0, 0))(
            agent, cur, nxt, live, params, jnp.asarray(act_a), jnp.asarray(act_p))
        return errs.T.reshape(2, n_actions, N_SLOTS)

    return resonance


#: added to each mismatch before its log: an exact match (an episode it made itself) scores
#: finitely
TINY = 1e-12


def score(errors: jax.Array) -> jax.Array:
    """The resonance score ``[n_actions, 3]`` of `make_resonance`'s mismatches: the
    sum of the logs of the joint and hand mismatches (smaller is better)."""
    return jnp.sum(jnp.log(errors + TINY), axis=0)


def hidden_under(env: Env, learner: learners.Learner, agent, states: State, action, slot
                 ) -> jax.Array:
    """The observer's actor hidden layer ``[T, hidden]`` on watched states under a command
    (the AN's "how" input)."""
    mine = as_command(env, states, action, slot)
    return jax.vmap(lambda o: learner.policy(agent, o)[1])(mine.obs)


def best(scores: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(action, slot) of the smallest resonance score ``[n_actions, 3]`` (`score`)."""
    i = jnp.argmin(scores.reshape(-1))
    return i // N_SLOTS, i % N_SLOTS


def paper_word(tl_probs: jax.Array, slot: jax.Array) -> jax.Array:
    """The target word the paper family's TL places in ``slot`` most surely: the argmax over
    the 6 words of its output for that slot (``tl_probs``: ``[6 words, 3 slots]``)."""
    return jnp.argmax(tl_probs[:, slot])


def free_word(estimates: jax.Array, slot_xy: jax.Array) -> jax.Array:
    """The target word whose continuous-TL estimate (``[6, 2]`` metres) lies nearest the
    object in the chosen slot (``slot_xy``: its coordinates)."""
    return jnp.argmin(jnp.linalg.norm(estimates - slot_xy, axis=1))


def names_target(layout: int, word: int, slot: int) -> bool:
    """Whether ``TARGET_WORDS[word]`` names the object standing in ``slot`` of ``layout``."""
    return tl_data.label_of(int(layout), int(word)) == int(slot)


def check_states(states: Any, obs_size: int, field: str = "trajectory") -> State:
    """A watched trajectory as env states stacked on a leading time axis (optionally with a
    batch axis before it); ValueError naming ``field`` and what is accepted otherwise.
    Accepts `Robot.perform`'s output dict (its ``"trajectory"``) too."""
    if isinstance(states, dict) and "trajectory" in states:
        states = states["trajectory"]
    if not isinstance(states, State):
        raise ValueError(f"{field}: expected env states stacked over time (an env State, as "
                         f"perform returns in 'trajectory'), got {type(states).__name__}")
    shape = tuple(np.shape(states.obs))
    if len(shape) not in (2, 3) or shape[-1] != obs_size or shape[-2] < 2:
        raise ValueError(f"{field}: observations of shape {shape}; accepted: [T, {obs_size}] "
                         f"or [N, T, {obs_size}] with T >= 2 steps (this robot's observation "
                         f"has {obs_size} units)")
    return states
