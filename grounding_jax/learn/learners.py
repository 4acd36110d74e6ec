"""The learner seam: what the AL trainer needs from a learner, and the learners it knows.

A `Learner` is a bundle of pure functions over the learner's own state (a
``flax.struct`` pytree), with a static config dataclass (network sizes: anything that changes
compiled code) and a traced hyperparameter dataclass (rates, noise, schedules: a sweep over
them compiles once). `grounding_jax.learn.al` drives any of them; CACLA
(`grounding_jax.learn.cacla.LEARNER`) is the paper's and the default. Another learner is
registered with `register` and chosen by passing its config to
``ALConfig(learner=...)`` and its hyperparameters to ``ALHyper(learner=...)``.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Mapping
from typing import Any

import jax
from flax import struct

from grounding_jax.core.checks import Rule


@struct.dataclass
class Transition:
    """One step: ``obs`` -> explored ``action`` -> ``reward`` (r_{t+1}) and ``next_obs``.

    ``prev_reward`` is r_t (CACLA's phase-1 rule compares the two); ``done`` cuts the
    bootstrap.
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array
    done: jax.Array
    prev_reward: jax.Array


@dataclasses.dataclass(frozen=True)
class Learner:
    """What the AL trainer calls.

    Attributes:
        name: registry name.
        config_type: the static config dataclass (frozen, JSON-able fields; it must have a
            ``task_set`` field naming the `TaskSet` whose
            observation and action it takes and gives).
        hyper_type: the traced hyperparameter ``flax.struct`` dataclass.
        state_type: the learner's state, a ``flax.struct`` dataclass (evaluation finds the
            learner of an agent by it).
        hyper_rules: what each field of ``hyper_type`` accepts (``validate`` and the sweep
            runner read it; the sweep's fields for this learner are its keys).
        init: ``(key, config, hyper) -> state`` -- a fresh learner.
        act: ``(state, obs, key, hyper) -> (explored action, greedy action)``.
        update: ``(state, transition, hyper, config) -> (state, info)``; ``info["delta"]`` is
            the TD error (the trainer records its RMS per episode).
        policy: ``(state, obs) -> (greedy action, hidden features)`` -- evaluation, the
            action namer's input and ``Robot.perform`` use it.
        at_episode: ``(hyper, phase1, progress) -> hyper`` -- the hyperparameters one episode
            trains with: ``phase1`` is 1.0 during the schedule's first phase, ``progress``
            runs 0 -> 1 over training (decays hang here).
    """

    name: str
    config_type: type
    hyper_type: type
    state_type: type
    hyper_rules: Mapping[str, Rule]
    init: Callable[[jax.Array, Any, Any], Any]
    act: Callable[[Any, jax.Array, jax.Array, Any], tuple[jax.Array, jax.Array]]
    update: Callable[[Any, Transition, Any, Any], tuple[Any, dict[str, jax.Array]]]
    policy: Callable[[Any, jax.Array], tuple[jax.Array, jax.Array]]
    at_episode: Callable[[Any, jax.Array, jax.Array], Any]


_REGISTRY: dict[str, Learner] = {}
#: learners that ship with the package, imported on first use
_BUILTIN = {"cacla": "grounding_jax.learn.cacla"}


def ordered_sum(x: jax.Array) -> jax.Array:
    """The sum of ``x`` over its first axis, its terms added one by one in index order.

    XLA lowers a ``dot`` or a ``sum`` to different kernels for one agent and for a batch
    under ``vmap``, and they add in different orders, so their last bits differ. Chained
    elementwise additions round the same way in both: a learner whose sums go through this
    trains bit for bit the same alone or in any batch (CACLA's do).
    """
    acc = x[0]
    for i in range(1, x.shape[0]):
        acc = acc + x[i]
    return acc


def register(learner: Learner) -> Learner:
    """Make ``learner`` known by its name and by its config and hyperparameter types.

    Raises:
        ValueError: another learner already holds the name.
    """
    old = _REGISTRY.get(learner.name)
    if old is not None and old is not learner:
        raise ValueError(f"name: a learner named {learner.name!r} is already registered")
    _REGISTRY[learner.name] = learner
    return learner


def _load_builtins() -> None:
    for module in _BUILTIN.values():
        importlib.import_module(module)


def get(name: str) -> Learner:
    """The registered learner called ``name`` (ValueError naming the known ones)."""
    _load_builtins()
    if name not in _REGISTRY:
        raise ValueError(f"learner: unknown value {name!r}; accepted values: "
                         f"{tuple(_REGISTRY)}")
    return _REGISTRY[name]


def _by_type(obj: Any, attr: str, what: str) -> Learner:
    _load_builtins()
    for learner in _REGISTRY.values():
        if isinstance(obj, getattr(learner, attr)):
            return learner
    accepted = tuple(getattr(lr, attr).__name__ for lr in _REGISTRY.values())
    raise ValueError(f"{what}: {type(obj).__name__} belongs to no registered learner; "
                     f"accepted types: {accepted}")


def for_config(config: Any, field: str = "learner") -> Learner:
    """The learner whose static config ``config`` is (ValueError naming ``field``)."""
    return _by_type(config, "config_type", field)


def for_hyper(hyper: Any, field: str = "learner") -> Learner:
    """The learner whose traced hyperparameters ``hyper`` are (ValueError naming ``field``)."""
    return _by_type(hyper, "hyper_type", field)


def for_state(state: Any, field: str = "agent") -> Learner:
    """The learner whose state ``state`` is (ValueError naming ``field``)."""
    return _by_type(state, "state_type", field)
