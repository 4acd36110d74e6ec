"""The task vocabulary, in one place: actions (with each one's reward and success rule),
positions, target words, and the layout of the actor's observation and action. The env, the
learner's network sizes, the ESN's output size and the AN take their sizes from here.

A `TaskSet` is a tuple of `Action` s. The paper's (``"paper"``: point, touch,
push) is the default everywhere; another one is registered with `register` and chosen
by name (``EnvConfig(task_set=...)``, ``CaclaConfig(task_set=...)``,
``ESNConfig(task_set=...)``), so configs stay plain JSON.

Observation (``obs_size``; 11 for the paper): the 4 arm joints (scaled to [-1, 1]), the touch
bit, the action one-hot, then where the target is: the position one-hot (the paper's,
``target_obs="position"``), or its table coordinates for objects placed anywhere (see
`grounding_jax.sim.placement`) -- (x, y) scaled to [-1, 1] over the reachable region
(``target_obs="xy"``) or as a population code of Gaussian bumps on a 3 x 7 grid over the
region (``target_obs="population"``: the ``"free"`` task set); with ``hand_obs`` (the
``"free_hand"`` task set) three more units say where the palm is relative to the target.
Action (``action_size`` = 4): the change of the 4 scaled joints.

Rewards see the per-step terms the env measures (``point_l1``: L1 distance of the scaled
joints to the position's stored pointing pose; ``touch_l1`` / ``push_l1``: ... to the touching
/ pushing pose of where the target is meant to be (`placement.touch_pose`,
`placement.push_pose`; 0 in the paper's family, whose rewards use neither);
``palm_target_dist``: metres
from the palm to the target's start; ``palm_target_now``: ... to where the target is now;
``palm_over_target`` / ``palm_target_across``: the palm's height over the target's centre
and its distance from it across the table; ``touched_target`` / ``touched_other``: 0/1;
``target_moved``: metres the target has moved; ``arm_moved``: the scaled-joint L1 the arm moved
in this step, 0 at reset) and the env's traced params.
Success rules judge one greedy episode from the quantities ``al_eval.episode_success``
measures (``final_point_l1``, ``point_l1_range``, ``touched_late``, ``target_moved``; an
episode that moved a wrong object fails whatever the rule says).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp

from grounding_jax.core.checks import Rule, check_config, integer_at_least

POSITIONS = ("left", "middle", "right")
SHAPES = ("box", "cylinder", "sphere")
COLOURS = ("red", "green", "blue")
#: the words that name a target: a shape or a colour
TARGET_WORDS = (*SHAPES, *COLOURS)
#: How the observation says where the target is: a position one-hot, its coordinates, or its
#: coordinates as a population code (Gaussian bumps on a grid over the reachable region).
TARGET_OBS = ("position", "xy", "population")
#: The population code's grid: centres along x (depth) and y (across the table).
POPULATION_GRID = (3, 7)
#: The hand units' length scale (metres): ``tanh(offset / HAND_SCALE)`` per axis, fine near the
#: target (1 cm moves a unit by ~0.1) and saturating past ~20 cm.
HAND_SCALE = 0.1
#: What a task set's numeric fields accept.
CONFIG_RULES: dict[str, Rule] = {"hand_scale": Rule("a finite number of metres > 0",
                                                    lambda v: v > 0),
                                 "memory": integer_at_least(0)}
N_JOINTS = 4
N_POSITIONS = len(POSITIONS)
N_WORDS = len(TARGET_WORDS)

# The success criteria (judging only; the paper's rewards train).
POINT_L1 = 0.1  # final L1 to the stored pose (scaled joint units)
POINT_STILL = 0.02  # L1 range over the last STILL_LAST steps: at rest
STILL_LAST = 10
POINT_MOVED = 0.01  # metres the target may move while pointed at
TOUCH_MOVED = 0.03  # ... while touched
PUSH_MOVED = 0.02  # metres a push must move it
PUSH_MOVED_CAP = 0.05  # metres of motion ``push_moved_bonus`` pays for (training only)

Terms = Mapping[str, jax.Array]


@dataclasses.dataclass(frozen=True)
class Action:
    """One action word with its reward and its success rule.

    Attributes:
        name: the word (the command and the AN's output).
        reward: ``reward(terms, params) -> scalar``, per step (see the module doc for terms).
        success: ``success(quantities) -> bool``, judging a whole greedy episode.
    """

    name: str
    reward: Callable[[Terms, Any], jax.Array]
    success: Callable[[Terms], jax.Array]


def _point_reward(t: Terms, params: Any) -> jax.Array:
    return -t["point_l1"]


def _touch_reward(t: Terms, params: Any) -> jax.Array:
    return (-t["palm_target_dist"]
            + jnp.where(t["touched_other"] > 0, params.touch_other_penalty, 0.0)
            + jnp.where(t["touched_target"] > 0, params.touch_target_penalty, 0.0))


def _at_other(t: Terms) -> jax.Array:
    """Whether the arm touches a non-target object or one has moved."""
    return (t["touched_other"] > 0) | t["wrong_moved"]


def _push_reward(t: Terms, params: Any) -> jax.Array:
    # the bonus stops at a cap so that flinging the object away pays no more than a push
    return (-t["palm_target_dist"]
            + params.push_moved_bonus * jnp.minimum(t["target_moved"], PUSH_MOVED_CAP)
            + jnp.where(_at_other(t), params.push_other_penalty, 0.0))


def _point_success(q: Terms) -> jax.Array:
    return ((q["final_point_l1"] < POINT_L1) & (q["point_l1_range"] < POINT_STILL)
            & (q["target_moved"] < POINT_MOVED))


def _touch_success(q: Terms) -> jax.Array:
    return (q["touched_late"] > 0) & (q["target_moved"] < TOUCH_MOVED)


def _push_success(q: Terms) -> jax.Array:
    return q["target_moved"] >= PUSH_MOVED


POINT = Action("point", _point_reward, _point_success)
TOUCH = Action("touch", _touch_reward, _touch_success)
PUSH = Action("push", _push_reward, _push_success)


@dataclasses.dataclass(frozen=True)
class TaskSet:
    """The actions a robot learns, and the sizes and slices that follow from them.

    Attributes:
        name: the key it is registered under.
        actions: the actions, in the order of the observation's and the AN's action units.
        target_obs: ``"position"`` (the paper: a left/middle/right one-hot), ``"xy"`` (the
            target's table coordinates, scaled to [-1, 1] over the reachable region) or
            ``"population"`` (those coordinates as Gaussian bumps on ``POPULATION_GRID``; see
            `placement.population`).
        hand_obs: three more units after the target's: where the palm is relative to the
            target, ``tanh((palm - target) / hand_scale)`` per axis (x, y, z), the target's
            (x, y) being what the actor is told (the TL's estimate when the robot performs)
            and its height the objects' centre. Needs table coordinates (``target_obs``
            ``"xy"`` or ``"population"``).
        hand_scale: the hand units' length scale in metres (default ``HAND_SCALE``).
        memory: a short memory of the past, last in the observation (``obs_memory``): the
            scaled joints of each of the ``memory`` steps before this one, newest first,
            then the actions sent at those steps (0 before the first step; the joints at
            reset stand in for steps before it). 0: none (the paper's).
    """

    name: str
    actions: tuple[Action, ...]
    target_obs: str = "position"
    hand_obs: bool = False
    hand_scale: float = HAND_SCALE
    memory: int = 0

    def __post_init__(self) -> None:
        names = self.action_names
        if not names or len(set(names)) != len(names):
            raise ValueError(f"actions: need at least one action and unique names, got {names}")
        if self.target_obs not in TARGET_OBS:
            raise ValueError(f"target_obs: unknown value {self.target_obs!r}; accepted values: "
                             f"{TARGET_OBS}")
        if self.hand_obs and self.target_obs == "position":
            raise ValueError("hand_obs: needs the target's table coordinates; accepted "
                             "target_obs with it: 'xy', 'population'")
        check_config(self, CONFIG_RULES)

    @property
    def action_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.actions)

    @property
    def n_actions(self) -> int:
        return len(self.actions)

    @property
    def obs_action(self) -> slice:
        """Where the action one-hot lies in the observation."""
        return slice(N_JOINTS + 1, N_JOINTS + 1 + self.n_actions)

    @property
    def obs_target(self) -> slice:
        """Where the target's position (one-hot or coordinates) lies in the observation."""
        n = {"position": N_POSITIONS, "xy": 2,
             "population": POPULATION_GRID[0] * POPULATION_GRID[1]}[self.target_obs]
        return slice(self.obs_action.stop, self.obs_action.stop + n)

    @property
    def obs_position(self) -> slice:
        """Where the position one-hot lies in the observation (``obs_target``)."""
        return self.obs_target

    @property
    def obs_hand(self) -> slice:
        """Where the palm's offset to the target lies in the observation (empty without
        ``hand_obs``)."""
        start = self.obs_target.stop
        return slice(start, start + (3 if self.hand_obs else 0))

    @property
    def obs_memory(self) -> slice:
        """Where the memory of past joints, then past actions, lies in the observation
        (empty without ``memory``)."""
        start = self.obs_hand.stop
        return slice(start, start + 2 * N_JOINTS * self.memory)

    @property
    def obs_size(self) -> int:
        return self.obs_memory.stop

    @property
    def action_size(self) -> int:
        return N_JOINTS

    @property
    def sentence_size(self) -> int:
        """The AN's outputs: one unit per action word, then one per target word."""
        return self.n_actions + N_WORDS

    def reward(self, action: jax.Array, terms: Terms, params: Any) -> jax.Array:
        """The reward of action index ``action`` (may be traced) for one step's terms."""
        return jnp.stack([a.reward(terms, params) for a in self.actions])[action]

    def success(self, action: jax.Array, quantities: Terms) -> jax.Array:
        """The success rule of action index ``action`` (may be traced) on an episode's
        judged quantities (a wrong object moved is checked by the caller)."""
        return jnp.stack([a.success(quantities) for a in self.actions])[action]


PAPER = TaskSet("paper", (POINT, TOUCH, PUSH))


def first_memory(task_set: TaskSet, joints: jax.Array) -> jax.Array:
    """The memory part of the observation at reset: the joints at reset stand in for the
    steps before it, no actions yet."""
    m = task_set.memory
    return jnp.concatenate([jnp.tile(joints, m), jnp.zeros(N_JOINTS * m, jnp.float32)])


def next_memory(task_set: TaskSet, obs: jax.Array, joints: jax.Array, action: jax.Array
                ) -> jax.Array:
    """The memory part of the next observation: this step's joints (before it) and action
    pushed in front of the previous observation's (``obs``), the oldest dropped."""
    n, m = N_JOINTS, task_set.memory
    past = obs[task_set.obs_memory]
    return jnp.concatenate([joints, past[:n * (m - 1)], action, past[n * m:n * (2 * m - 1)]])


def _avoid(t: Terms, params: Any) -> jax.Array:
    """``touch_other_penalty`` while the arm touches a non-target object or one has moved."""
    return jnp.where(_at_other(t), params.touch_other_penalty, 0.0)


def _free_point_reward(t: Terms, params: Any) -> jax.Array:
    return -t["point_l1"] + _avoid(t, params)


def _free_touch_reward(t: Terms, params: Any) -> jax.Array:
    # a pose to reach, as point's: the palm pressed down on the target's top, which the table
    # holds still (a reward on the palm's distance to the target's centre drove it through
    # the object's side); a bonus while touching; a penalty on how far the target moved; one
    # on moving the arm while touching (0 by default: it adds exactly nothing then)
    return (-t["touch_l1"] + jnp.where(t["touched_target"] > 0, params.touch_bonus, 0.0)
            - params.touch_moved_penalty * t["target_moved"] + _avoid(t, params)
            - params.touch_still_penalty * t["touched_target"] * t["arm_moved"])


def _free_push_reward(t: Terms, params: Any) -> jax.Array:
    # (minus the L1 to a pushing pose, ``push_l1``, as touch's, was tried and not kept:
    # docs/beyond.md)
    return -t["palm_target_dist"] + _avoid(t, params)


#: For objects placed anywhere: the actor is told the target's coordinates instead of its slot
#: (the paper's proposed fix for its touch and push troubles), as a population code (the
#: plain scaled (x, y) learned worse: docs/beyond.md). The success rules are the
#: paper family's; the rewards differ in two ways: every action pays ``touch_other_penalty``
#: while the arm touches a non-target object or one has moved (with objects anywhere no fixed
#: detour around the neighbours exists), and touch, like point, reaches for a pose: minus the
#: L1 distance to the touching pose of where the target is meant to be (``touch_l1``: the
#: palm pressed on its top; `placement.touch_pose`), plus ``touch_bonus`` while the arm
#: touches it, less ``touch_moved_penalty`` per metre it has moved (instead of the paper's
#: penalty for touching it, under which an actor hovers).
FREE = TaskSet("free", (Action("point", _free_point_reward, _point_success),
                        Action("touch", _free_touch_reward, _touch_success),
                        Action("push", _free_push_reward, _push_success)),
               target_obs="population")
#: The free family with the hand units (``hand_obs``): the actor also sees where its palm is
#: relative to the target, as a robot watching its hand and the object would (the paper's
#: "online visual feedback"). Same actions, rewards and success rules as `FREE`.
FREE_HAND = dataclasses.replace(FREE, name="free_hand", hand_obs=True)
#: The paper's task set with a memory of the two steps before (joints and actions): the
#: actor can tell where it is going, not only where it is (the paper's suggestion for touch's
#: oscillation: "a recurrent network, memory of past positions"). Same actions, rewards and
#: success rules as `PAPER`.
PAPER_MEMORY = dataclasses.replace(PAPER, name="paper_memory", memory=2)


#: The paper's task set with touch's reward the free family's (not the paper's): minus the L1
#: distance of the joints to the slot's touching pose (the palm pressed on the target's top,
#: `placement.touch_pose`), plus ``touch_bonus`` while the arm touches the target, less
#: ``touch_moved_penalty`` per metre it moved (10 by default: 3 cm cost 0.3) and
#: ``touch_other_penalty`` while it touches another object -- instead of the paper's minus the
#: palm's distance to the target and -0.3 while touching it, under which a precise actor hovers.
#: Point and push, the observation and the success rules are the paper's.
PAPER_TOUCH_POSE = TaskSet("paper_touch_pose", (
    POINT, Action("touch", _free_touch_reward, _touch_success), PUSH))
#: `PAPER_TOUCH_POSE` with `PAPER_MEMORY`'s memory.
PAPER_MEMORY_TOUCH_POSE = dataclasses.replace(PAPER_TOUCH_POSE, name="paper_memory_touch_pose",
                                              memory=2)
#: The task sets that cannot be replaced (saved agents name them).
BUILT_IN = (PAPER, FREE, FREE_HAND, PAPER_MEMORY, PAPER_TOUCH_POSE, PAPER_MEMORY_TOUCH_POSE)
TASK_SETS: dict[str, TaskSet] = {t.name: t for t in BUILT_IN}


def register(task_set: TaskSet) -> TaskSet:
    """Make ``task_set`` available by its name to the configs (replacing one of that name,
    except the built-in ones, `BUILT_IN`, which stay as they are). Returns it."""
    for fixed in BUILT_IN:
        if task_set.name == fixed.name and task_set is not fixed:
            raise ValueError(f"task_set: the name {fixed.name!r} is built in and cannot be "
                             f"replaced; choose another name")
    TASK_SETS[task_set.name] = task_set
    return task_set


def get(name: str) -> TaskSet:
    """The task set registered as ``name``; ValueError naming the accepted values."""
    if name not in TASK_SETS:
        raise ValueError(f"task_set: unknown value {name!r}; accepted values: "
                         f"{tuple(TASK_SETS)} (add one with tasks.register)")
    return TASK_SETS[name]


# The paper's task set, as module constants (what most code and users need).
ACTIONS = PAPER.action_names
N_ACTIONS = PAPER.n_actions
OBS_JOINTS = slice(0, N_JOINTS)
OBS_TOUCH = N_JOINTS
OBS_ACTION = PAPER.obs_action
OBS_POSITION = PAPER.obs_position
OBS_SIZE = PAPER.obs_size
ACTION_SIZE = PAPER.action_size
SENTENCE_SIZE = PAPER.sentence_size
