"""CACLA actor-critic (van Hasselt & Wiering 2007) as pure functions over a flax.struct state.

- actor: obs (11) -> ``actor_hidden`` tanh -> 4 tanh (the proposed change of the scaled joints);
- critic: obs (11) -> ``critic_hidden`` tanh -> 1 linear (the state's value);
- ``act``: Gaussian exploration around the actor's output, ``sigma`` traced;
- ``update``: the critic takes a TD step, ``theta_C += lr_C * delta * dV/dtheta`` (paper eq. 3);
  the actor is moved toward the explored action, ``theta_A += lr_A * (a~ - a) * da/dtheta``
  (eq. 5), only when the step was an improvement. What counts as one is a traced switch, so
  one compile serves both of the paper's phases: phase 1 -- the reward rose,
  ``r_{t+1} > r_t``; phase 2 -- plain CACLA, ``delta > 0``. Optional CACLA+Var (static
  ``CaclaConfig.var``): the actor update is repeated ``ceil(delta / sqrt(var_delta))`` times
  (at most ``max_var_repeats``), with ``var_delta`` a running variance of delta.

Actions share one actor and one critic (the paper), or some or all of them learn in their
own (static ``CaclaConfig.heads``: the leaves get an action axis, the observation's action
one-hot picks the slot). Network sizes are static (``CaclaConfig``); learning rates, sigma,
gamma, the phase switch, the decays and the hidden units in use are traced (``CaclaHyper``).
A smaller hidden layer can still be traced: `init` leaves the units past ``*_units`` at
zero weights, where they stay (see there). `LEARNER` is CACLA behind the AL trainer's
learner seam (`grounding_jax.learn.learners`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from grounding_jax.core.checks import (
    FLAG,
    POSITIVE,
    UNIT_CLOSED,
    UNIT_OPEN_LEFT,
    Rule,
    check_config,
    check_rules,
    integer_at_least,
)
from grounding_jax.learn import learners
from grounding_jax.learn.learners import Transition
from grounding_jax.sim import tasks

#: What each size of `CaclaConfig` accepts (its ``__post_init__`` and the sweep
#: runner read it).
CONFIG_RULES: dict[str, Rule] = {name: integer_at_least(1) for name in (
    "actor_hidden", "critic_hidden", "max_var_repeats")} | {
    "obs_dim": integer_at_least(0), "act_dim": integer_at_least(0)}


@dataclasses.dataclass(frozen=True)
class CaclaConfig:
    """Static configuration.

    Attributes:
        actor_hidden: actor hidden units (paper: 40).
        critic_hidden: critic hidden units (paper: 20).
        var: use CACLA+Var (off by default, as in the paper).
        max_var_repeats: cap on the CACLA+Var repetitions of one actor update.
        task_set: name of the `tasks.TaskSet` whose observation and action the
            networks take and give (their input and output sizes follow from it).
        heads: which actions share an actor-critic: ``()`` -- one actor and one critic
            for every action, told the action by its one-hot input (the paper); else one
            network index per action, e.g. ``(0, 1, 1)``: point learns alone, touch and push
            share a second pair. Every action keeps a slot (the leaves get an action axis;
            actions that share a network hold equal copies, updated together) and the
            observation's action one-hot picks it (see `head`).
        obs_dim, act_dim: the networks' input and output units for an env of another shape
            (a Brax env, say); 0, the default, takes them from ``task_set``.
    """

    actor_hidden: int = 40
    critic_hidden: int = 20
    var: bool = False
    max_var_repeats: int = 10
    task_set: str = tasks.PAPER.name
    heads: tuple[int, ...] = ()
    obs_dim: int = 0
    act_dim: int = 0

    def __post_init__(self) -> None:
        check_config(self, CONFIG_RULES)
        if (self.obs_dim or self.act_dim) and self.heads:
            raise ValueError("heads: networks per action need the task set's observation "
                             "(its action one-hot); accepted with obs_dim/act_dim: ()")
        n = tasks.get(self.task_set).n_actions
        heads = self.heads
        try:
            heads = tuple(int(h) for h in heads)
            ok = heads == () or (len(heads) == n and set(heads) == set(range(max(heads) + 1)))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ValueError(
                f"heads: got {self.heads!r}; accepted values: () (one network for every "
                f"action) or one network index per action of {self.task_set!r} ({n} "
                f"integers numbering the networks 0, 1, ... without gaps, e.g. "
                f"{tuple(range(n))} for one network each)")
        object.__setattr__(self, "heads", heads)  # a JSON list becomes a tuple

    @property
    def obs_size(self) -> int:
        """Input units of both networks."""
        return self.obs_dim or tasks.get(self.task_set).obs_size

    @property
    def action_size(self) -> int:
        """Output units of the actor."""
        return self.act_dim or tasks.get(self.task_set).action_size


@struct.dataclass
class CaclaHyper:
    """Traced hyperparameters.

    Attributes:
        actor_lr: actor learning rate (paper: 0.001).
        critic_lr: critic learning rate (paper: 0.01).
        sigma: standard deviation of the Gaussian exploration (scaled joint units).
        gamma: discount factor (paper's best: 0).
        phase1: 1.0 -- update the actor when the reward rose (paper's phase 1);
            0.0 -- when delta > 0 (plain CACLA, phase 2). The AL trainer sets it per episode
            from its schedule (`at_episode`).
        var_beta: rate of the running variance of delta (CACLA+Var only).
        actor_lr_decay, critic_lr_decay, sigma_decay: the value at training progress ``x``
            (0 at the first episode, 1 at the last) is ``v * decay ** x`` -- geometric from
            ``v`` to ``v * decay``; 1.0 keeps it constant (the paper).
        actor_units, critic_units: hidden units in use, at most the config's sizes (0: all of
            them); the rest stay at zero weights (`init`), so a sweep over hidden sizes
            runs as one batch at the largest size.
        actor_init_scale: factor on the actor's initial output weights (1.0: the usual
            +-1/sqrt(fan-in)); smaller values start from near-zero actions -- the paper's
            suggestion for a smoother approach to the goal.
    """

    actor_lr: Any = 0.001
    critic_lr: Any = 0.01
    sigma: Any = 0.1
    gamma: Any = 0.0
    phase1: Any = 0.0
    var_beta: Any = 0.001
    actor_lr_decay: Any = 1.0
    critic_lr_decay: Any = 1.0
    sigma_decay: Any = 1.0
    actor_units: Any = 0
    critic_units: Any = 0
    actor_init_scale: Any = 1.0


#: What each field of `CaclaHyper` accepts (``validate`` and the sweep runner read it).
HYPER_RULES: dict[str, Rule] = {
    "actor_lr": POSITIVE, "critic_lr": POSITIVE, "sigma": POSITIVE, "gamma": UNIT_CLOSED,
    "phase1": FLAG, "var_beta": UNIT_OPEN_LEFT,
    "actor_lr_decay": UNIT_OPEN_LEFT, "critic_lr_decay": UNIT_OPEN_LEFT,
    "sigma_decay": UNIT_OPEN_LEFT, "actor_init_scale": POSITIVE,
    "actor_units": integer_at_least(0, "an integer >= 0 (0: all units)"),
    "critic_units": integer_at_least(0, "an integer >= 0 (0: all units)"),
}


def validate(hp: CaclaHyper) -> CaclaHyper:
    """Raise ValueError naming the field for bad concrete values; returns ``hp``."""
    check_rules(hp, HYPER_RULES)
    return hp


@struct.dataclass
class MLP:
    w1: jax.Array
    b1: jax.Array
    w2: jax.Array
    b2: jax.Array


@struct.dataclass
class Agent:
    """The learner's state: actor and critic parameters, CACLA+Var's running variance of
    delta (a scalar; one slot per action when ``CaclaConfig.var`` and ``heads`` are both set,
    so each network keeps its own)."""

    actor: MLP
    critic: MLP
    var_delta: jax.Array


def _mlp_init(key: jax.Array, n_in: int, n_hidden: int, n_out: int, units=None) -> MLP:
    """Uniform weights in +-1/sqrt(fan-in), each hidden unit from its own ``fold_in`` of the
    key (so a unit's weights do not depend on ``n_hidden``); units from ``units`` on (traced
    or None: all) get zero weights in and out."""
    k1, k2 = jax.random.split(key)
    j = jnp.arange(n_hidden)
    w1 = jax.vmap(lambda i: jax.random.uniform(jax.random.fold_in(k1, i), (n_in,), jnp.float32,
                                               -1, 1), out_axes=1)(j)
    w2 = jax.vmap(lambda i: jax.random.uniform(jax.random.fold_in(k2, i), (n_out,),
                                               jnp.float32, -1, 1))(j)
    used = jnp.asarray(n_hidden if units is None else units, jnp.float32)
    mask = (j < used).astype(jnp.float32)
    return MLP(w1=w1 * mask / np.sqrt(n_in), b1=jnp.zeros(n_hidden),
               w2=w2 * mask[:, None] / jnp.sqrt(used), b2=jnp.zeros(n_out))


def init(key: jax.Array, config: CaclaConfig = CaclaConfig(), actor_units=None,
         critic_units=None) -> Agent:
    """Fresh agent: uniform weights in +-1/sqrt(fan-in), zero biases.

    A hidden unit whose weights in and out are all zero stays so under every update (tanh(0)
    = 0, so it outputs 0 and all its gradients are 0): an agent built at the config's sizes
    with fewer ``*_units`` in use computes exactly what the smaller network does. That makes
    the hidden sizes traceable (a sweep over them needs one compile, at the largest size).

    Args:
        key: PRNG key.
        config: static sizes (the padded sizes when ``*_units`` are given).
        actor_units: actor hidden units in use (int, traced or None: ``config.actor_hidden``).
        critic_units: critic hidden units in use (likewise).

    Returns:
        The agent state.
    """
    ka, kc = jax.random.split(key)
    n_obs = config.obs_size
    actor = _mlp_init(ka, n_obs, config.actor_hidden, config.action_size, actor_units)
    critic = _mlp_init(kc, n_obs, config.critic_hidden, 1, critic_units)
    if config.heads:  # a slot per action: network h from its own fold of the key
        net = jnp.asarray(config.heads, jnp.int32)

        def per_action(k, n_out, hidden, units):
            return jax.vmap(lambda h: _mlp_init(jax.random.fold_in(k, h), n_obs, hidden,
                                                n_out, units))(net)

        actor = per_action(ka, config.action_size, config.actor_hidden, actor_units)
        critic = per_action(kc, 1, config.critic_hidden, critic_units)
    # CACLA+Var with networks per action: each network keeps its own running variance (a
    # slot per action, like the networks' leaves); otherwise one scalar
    var_shape = (len(config.heads),) if config.var and config.heads else ()
    return Agent(actor=actor, critic=critic, var_delta=jnp.ones(var_shape, jnp.float32))


def start(key: jax.Array, config: CaclaConfig, hp: CaclaHyper) -> Agent:
    """A fresh agent for training: `init` with ``hp``'s hidden units in use and the
    actor's output weights times ``hp.actor_init_scale``."""
    agent = init(key, config,
                 jnp.where(hp.actor_units > 0, hp.actor_units, config.actor_hidden),
                 jnp.where(hp.critic_units > 0, hp.critic_units, config.critic_hidden))
    return agent.replace(actor=agent.actor.replace(w2=agent.actor.w2 * hp.actor_init_scale))


def at_episode(hp: CaclaHyper, phase1: jax.Array, progress: jax.Array) -> CaclaHyper:
    """The hyperparameters of one training episode: the schedule's phase switch, and the
    rates and sigma decayed to training progress ``progress`` (0 -> 1)."""
    x = progress
    return hp.replace(phase1=phase1, actor_lr=hp.actor_lr * hp.actor_lr_decay ** x,
                      critic_lr=hp.critic_lr * hp.critic_lr_decay ** x,
                      sigma=hp.sigma * hp.sigma_decay ** x)


def _matvec(x: jax.Array, w: jax.Array) -> jax.Array:
    """``x @ w``, its terms added one by one in input order, so an agent trains bit for bit
    the same alone or in any batch (see `learners.ordered_sum`).

    Each product is formed inside the chain (``acc + x[i] * w[i]``) rather than by
    ``ordered_sum(x[:, None] * w)``: XLA may fuse a multiply and an add into one rounding, so
    the two forms differ in the last bits, and the shipped results were made with this one.
    """
    acc = x[0] * w[0]
    for i in range(1, x.shape[0]):
        acc = acc + x[i] * w[i]
    return acc


def _head_index(net: MLP, obs: jax.Array) -> jax.Array | None:
    """The action whose slot ``obs`` asks for (its action one-hot), or None for a network
    shared by every action (no action axis)."""
    if net.w1.ndim == 2:
        return None
    return jnp.argmax(obs[tasks.N_JOINTS + 1:tasks.N_JOINTS + 1 + net.w1.shape[0]])


def head(net: MLP, obs: jax.Array) -> MLP:
    """The plain network that serves ``obs``: ``net`` itself when every action shares it,
    else the slot of the observation's action (`CaclaConfig.heads`)."""
    a = _head_index(net, obs)
    return net if a is None else jax.tree.map(lambda w: w[a], net)


def _put_head(net: MLP, obs: jax.Array, new: MLP, heads: tuple[int, ...]) -> MLP:
    """``net`` with ``new`` written to the slot that serves ``obs`` and to every slot of an
    action sharing its network (``heads``; inverse of `head`)."""
    a = _head_index(net, obs)
    if a is None:
        return new
    same = jnp.asarray(heads) == jnp.asarray(heads)[a]  # [actions]
    return jax.tree.map(lambda w, v: jnp.where(same.reshape((-1,) + (1,) * v.ndim), v, w),
                        net, new)


def actor_apply(actor: MLP, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Actor forward pass: (hidden activations [H], action [4] in (-1, 1))."""
    actor = head(actor, obs)
    h = jnp.tanh(_matvec(obs, actor.w1) + actor.b1)
    return h, jnp.tanh(_matvec(h, actor.w2) + actor.b2)


def policy(agent: Agent, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The greedy action [4] and the actor's hidden activations [H]."""
    hidden, action = actor_apply(agent.actor, obs)
    return action, hidden


def critic_apply(critic: MLP, obs: jax.Array) -> jax.Array:
    """Critic forward pass: the value, a scalar."""
    return _critic(critic, obs)[1]


def _critic(critic: MLP, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    critic = head(critic, obs)
    h = jnp.tanh(_matvec(obs, critic.w1) + critic.b1)
    return h, (_matvec(h, critic.w2) + critic.b2)[0]


def _critic_grad(critic: MLP, obs: jax.Array, h: jax.Array) -> MLP:
    """dV/dtheta at ``obs`` (``h``: the hidden activations there), written out with
    `_matvec` (``jax.grad``'s transposed dots would add in batch-dependent orders)."""
    dz = critic.w2[:, 0] * (1.0 - h * h)
    return MLP(w1=obs[:, None] * dz[None, :], b1=dz, w2=h[:, None],
               b2=jnp.ones_like(critic.b2))


def _actor_grad(actor: MLP, obs: jax.Array, h: jax.Array, mean: jax.Array,
                err: jax.Array) -> MLP:
    """d(a(obs) . err)/dtheta, written out like `_critic_grad`."""
    dz2 = err * (1.0 - mean * mean)
    dz1 = _matvec(dz2, actor.w2.T) * (1.0 - h * h)
    return MLP(w1=obs[:, None] * dz1[None, :], b1=dz1, w2=h[:, None] * dz2[None, :], b2=dz2)


def act(agent: Agent, obs: jax.Array, key: jax.Array, hp: CaclaHyper
        ) -> tuple[jax.Array, jax.Array]:
    """Explored action ``a~ = a(s) + sigma * N(0, 1)`` and the actor's own ``a(s)``."""
    _, mean = actor_apply(agent.actor, obs)
    return mean + hp.sigma * jax.random.normal(key, mean.shape, mean.dtype), mean


def _step(tree, grad, lr):
    return jax.tree.map(lambda p, g: p + lr * g, tree, grad)


def update(agent: Agent, tr: Transition, hp: CaclaHyper,
           config: CaclaConfig = CaclaConfig()) -> tuple[Agent, dict[str, jax.Array]]:
    """One CACLA update from a transition (paper, Algorithm 1).

    Args:
        agent: current state.
        tr: the transition.
        hp: traced hyperparameters.
        config: static config (CACLA+Var on/off).

    Returns:
        (new agent, info with ``delta``, ``actor_updated`` (0/1) and ``value``).
    """
    here = head(agent.critic, tr.obs)  # the action's own head (the network when shared)
    h, v = _critic(here, tr.obs)
    dv = _critic_grad(here, tr.obs, h)
    v_next = critic_apply(agent.critic, tr.next_obs)
    target = tr.reward + hp.gamma * (1.0 - tr.done.astype(jnp.float32)) * v_next
    delta = jax.lax.stop_gradient(target - v)
    critic = _put_head(agent.critic, tr.obs, _step(here, dv, hp.critic_lr * delta),
                       config.heads)

    improved = jnp.where(hp.phase1 > 0.5, tr.reward > tr.prev_reward, delta > 0)

    def pull(actor: MLP) -> MLP:  # one step of the actor toward the explored action
        h, mean = actor_apply(actor, tr.obs)
        return _step(actor, _actor_grad(actor, tr.obs, h, mean, tr.action - mean),
                     hp.actor_lr)

    var_delta = agent.var_delta
    if config.var:
        var_delta = (1 - hp.var_beta) * var_delta + hp.var_beta * delta**2
        a = _head_index(agent.actor, tr.obs)
        if a is not None:  # only the slots of the network that learned from this transition
            same = jnp.asarray(config.heads) == jnp.asarray(config.heads)[a]
            var_delta = jnp.where(same, var_delta, agent.var_delta)
        own = var_delta if a is None else var_delta[a]
        repeats = jnp.clip(jnp.ceil(delta / jnp.sqrt(own)), 1, config.max_var_repeats)
        repeats = jnp.where(hp.phase1 > 0.5, 1, repeats).astype(jnp.int32)
        moved = jax.lax.fori_loop(0, repeats, lambda _, a: pull(a), head(agent.actor, tr.obs))
    else:
        moved = pull(head(agent.actor, tr.obs))
    moved = _put_head(agent.actor, tr.obs, moved, config.heads)
    actor = jax.tree.map(lambda new, old: jnp.where(improved, new, old), moved, agent.actor)
    info = {"delta": delta, "actor_updated": improved.astype(jnp.float32), "value": v}
    return Agent(actor=actor, critic=critic, var_delta=var_delta), info


#: CACLA behind the AL trainer's learner seam (`grounding_jax.learn.learners`).
LEARNER = learners.register(learners.Learner(
    name="cacla", config_type=CaclaConfig, hyper_type=CaclaHyper, state_type=Agent,
    hyper_rules=HYPER_RULES, init=start, act=act, update=update, policy=policy,
    at_episode=at_episode))
