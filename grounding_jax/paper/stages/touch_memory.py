"""Touch with memory: the paper family's actor given a memory of its last two steps (joints and
actions, `grounding_jax.sim.tasks.PAPER_MEMORY`), trained by CACLA on the same budget, beside
touch's reward changed to the free family's (reach the slot's touching pose, contact paid,
the target's motion penalized: ``PAPER_TOUCH_POSE``, not the paper's) and both together,
each also with touch told to hold still once in contact (``EnvParams.touch_still_penalty``:
the arm's motion while it touches the target costs), and one where push also pays for
touching or moving a neighbour (``EnvParams.push_other_penalty``).

The paper suggests "a recurrent network, memory of past positions" for touch's oscillation.
Every variant is trained from the stage's key on the run's schedule and judged, with the
run's own AL agents (no memory, the paper's reward), the way the ``random_starts`` stage
judges: all three actions, from home and from random starts, the same tasks and keys. The
variant ``save`` names is saved as a whole robot (the run's TL, that variant's agents, an AN
fitted on its agent 0) in ``<out>/modules``; ``grounding_jax.load`` it and ``perform``: the
memory is part of the observation, carried in the env's state from step to step.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
from typing import NamedTuple

import jax
import numpy as np

from grounding_jax.core import trees, xla
from grounding_jax.core.io import atomic_write_text
from grounding_jax.learn import al, an, cacla
from grounding_jax.paper import al_eval
from grounding_jax.paper.al_experiments import TUNED, TUNED_AL
from grounding_jax.paper.stage import Inputs, Stage
from grounding_jax.paper.stages import random_starts as RS
from grounding_jax.sim import tasks, tl_data
from grounding_jax.sim.env import Env, EnvConfig, EnvParams


class Variant(NamedTuple):
    """A variant: its task set, what it changes from the paper's, whether touch is told to
    hold still in contact, whether it trains from random starts (a curriculum from home),
    whether push pays for touching or moving a neighbour (``EnvParams.push_other_penalty``),
    and, for a variant trained from random starts, each action's share of them
    (`grounding_jax.learn.al.ALHyper.start_by_action`, in the task set's action order; None:
    every action alike)."""

    task_set: str
    what: str
    still: bool = False
    starts: bool = False
    avoid: bool = False
    starts_by_action: tuple[float, ...] | None = None


_STILL = "touch reaches a touching pose and holds still there"
VARIANTS = {"paper_memory": Variant("paper_memory", "memory, the paper's reward"),
            "paper_touch_pose": Variant("paper_touch_pose",
                                        "no memory, touch reaches a touching pose"),
            "paper_memory_touch_pose": Variant("paper_memory_touch_pose",
                                               "memory, touch reaches a touching pose"),
            "paper_touch_pose_still": Variant("paper_touch_pose", f"no memory, {_STILL}", True),
            "paper_memory_touch_pose_still": Variant("paper_memory_touch_pose",
                                                     f"memory, {_STILL}", True),
            "paper_touch_pose_still_starts": Variant(
                "paper_touch_pose", f"no memory, {_STILL}, trained from random starts", True,
                True),
            "paper_memory_touch_pose_still_avoid": Variant(
                "paper_memory_touch_pose", f"memory, {_STILL}, push avoids the neighbours",
                True, False, True),
            "paper_memory_touch_pose_still_avoid_push_starts": Variant(
                "paper_memory_touch_pose", f"memory, {_STILL}, push avoids the neighbours and "
                "trains from random starts", True, True, True, (0.0, 0.0, 1.0))}
GOAL_TOUCH, GOAL_OTHERS = 0.85, 0.95


@dataclasses.dataclass(frozen=True)
class TouchMemoryConfig:
    """The schedule (agents, phase 1 and 2 episodes: the quick profile's AL), the bonus the
    touching-pose variants get while touching (``EnvParams.touch_bonus``), what the arm's
    motion costs while it touches the target in the variants that hold still (per scaled
    joint unit, ``EnvParams.touch_still_penalty``), the random starts of the variants trained
    from them (``start_noise``, reached over the first ``start_ramp`` of the run:
    `grounding_jax.learn.al.ALHyper.start_ramp`), the phase 2 episodes added for the variants
    that hold still (``still_extra``: holding still is learnt after reaching, so they may be
    given more), what push pays while the arm touches or has moved a neighbour in the
    variants that avoid them (``EnvParams.push_other_penalty``: from random starts most failed
    pushes swept a neighbour aside), the touching-pose variants'
    actor-critics (``heads``: touch's own, point and push sharing one; with one for all,
    touch's larger reward took point's network, with one each push lost its), the variants
    (names of `VARIANTS`), the one saved as a robot, and how they are judged."""

    seeds: int = 2
    phase1: int = 150
    phase2: int = 150
    still_extra: int = 0
    touch_bonus: float = 0.0
    touch_still_penalty: float = 3.0
    start_noise: float = 0.5
    start_ramp: float = 0.5
    push_other_penalty: float = -0.5
    heads: tuple[int, ...] = (0, 1, 0)
    variants: tuple[str, ...] = ("paper_memory_touch_pose_still_avoid_push_starts",)
    save: str = "paper_memory_touch_pose_still_avoid_push_starts"
    noise: tuple[float, ...] = (0.0, 0.3)
    layouts: str = "shapes"
    perform_checks: int = 3

    def __post_init__(self) -> None:
        bad = [v for v in self.variants if v not in VARIANTS]
        if bad or not self.variants:
            raise ValueError(f"variants: {bad or '()'} not accepted; accepted: one or more of "
                             f"{list(VARIANTS)}")
        if self.save not in self.variants:
            raise ValueError(f"save: {self.save!r}; accepted: one of variants "
                             f"{list(self.variants)}")
        if self.seeds < 1 or self.phase1 < 0 or self.phase1 + self.phase2 < 1:
            raise ValueError(f"seeds >= 1 and phase1 + phase2 >= 1, got {self.seeds}, "
                             f"{self.phase1} + {self.phase2}")
        if self.still_extra < 0:
            raise ValueError(f"still_extra: {self.still_extra}; accepted: an int >= 0")
        if not math.isfinite(self.push_other_penalty):
            raise ValueError(f"push_other_penalty: {self.push_other_penalty}; accepted: a "
                             "finite number")
        if not self.touch_still_penalty >= 0:
            raise ValueError(f"touch_still_penalty: {self.touch_still_penalty}; accepted: >= 0")
        if not (0 <= self.start_noise <= 1 and 0 <= self.start_ramp <= 1):
            raise ValueError(f"start_noise, start_ramp: {self.start_noise}, {self.start_ramp}; "
                             "accepted: each in [0, 1]")
        RS.RandomStartsConfig(self.noise, self.layouts, 1, self.perform_checks)  # checks them
        cacla.CaclaConfig(task_set=tasks.PAPER_TOUCH_POSE.name, heads=self.heads)


def train_variant(keys: jax.Array, phase1: int, phase2: int, task_set: str,
                  fields: dict, heads: tuple[int, ...] | None = None
                  ) -> tuple[cacla.Agent, al.ALConfig]:
    """Agents ``[len(keys)]`` of task set ``task_set`` trained with the shipped settings
    (`TUNED`, `TUNED_AL`) changed by ``fields`` (traced `al.hyper` fields); ``heads``: the
    actor-critic each action uses (``cacla.CaclaConfig.heads``; None: one for all)."""
    learner = cacla.CaclaConfig(task_set=task_set)
    if heads is not None:
        learner = dataclasses.replace(learner, heads=heads)
    cfg = al.ALConfig(env=EnvConfig(task_set=task_set), learner=learner,
                      phase1_episodes=phase1, phase2_episodes=phase2)
    hp = al.validate(al.hyper(**{**TUNED, **TUNED_AL, **fields}))
    run = xla.physics_jit(jax.vmap(al.make_train(cfg), in_axes=(0, None)), Env(cfg.env))
    agents, _ = run(keys, hp)
    return jax.block_until_ready(agents), cfg


def variant_plan(name: str, config: TouchMemoryConfig
                 ) -> tuple[str, int, dict, tuple[int, ...] | None]:
    """How variant ``name`` is trained under ``config``: its task set, phase 2 episodes, the
    traced `al.hyper` fields it changes and its heads (`train_variant`'s arguments)."""
    v = VARIANTS[name]
    pose = "touch_pose" in v.task_set
    fields = {"touch_bonus": config.touch_bonus} if pose else {}
    if v.still:
        fields["touch_still_penalty"] = config.touch_still_penalty
    if v.starts:
        fields.update(start_noise=config.start_noise, start_ramp=config.start_ramp)
        if v.starts_by_action is not None:
            fields["start_by_action"] = list(v.starts_by_action)
    if v.avoid:
        fields["push_other_penalty"] = config.push_other_penalty
    phase2 = config.phase2 + (config.still_extra if v.still else 0)
    return v.task_set, phase2, fields, config.heads if pose else None


def _namer(key: jax.Array, robot, agent, env_config: EnvConfig):
    """An AN fitted on ``agent``'s hidden layer (the robot's TL and ESN config); returns
    (net, its test accuracy)."""
    data = tl_data.load()
    tl_h = np.asarray(robot.tl.hidden_layer(data.bitmaps, data.symbols))
    k_home, _, k_esn = jax.random.split(key, 3)
    env = Env(env_config)
    home = an.dataset(agent, tl_h, k_home, 100, 0.0, env)
    # only the home test is reported: no random-start sequences are drawn for the other one
    fit = an.train_namer(k_esn, home, home, config=robot.an.config)
    return fit["net"], float(fit["test"]["acc"])


def run(key: jax.Array, inputs: Inputs, out: pathlib.Path, config: TouchMemoryConfig
        ) -> dict:
    """Train and judge every variant, save one (see the module doc)."""
    from grounding_jax.robot import trained

    robot = trained.load(inputs.modules)
    k_train, k_judge, k_an = jax.random.split(key, 3)
    judged = RS.RandomStartsConfig(config.noise, config.layouts, 1, 0)
    shipped = robot.agents if robot.n_agents else trees.add_axis(robot.al.agent)
    rows = {"paper": {"what": "the run's AL agents: no memory, the paper's reward",
                      "levels": RS.judge_levels(shipped, robot.env_config, k_judge, judged)[0]}}
    keys = jax.random.split(k_train, config.seeds)
    for name in config.variants:
        ts, phase2, fields, heads = variant_plan(name, config)
        agents, cfg = train_variant(keys, config.phase1, phase2, ts, fields, heads)
        levels, raw = RS.judge_levels(agents, cfg.env, k_judge, judged)
        rows[name] = {"what": VARIANTS[name].what, "episodes": config.phase1 + phase2,
                      "levels": levels}
        if name == config.save:
            saved_agents, saved_cfg, saved_raw = agents, cfg, raw[str(config.noise[0])]
    agent = trees.take(saved_agents, 0)
    net, an_acc = _namer(k_an, robot, agent, saved_cfg.env)
    modules = pathlib.Path(out) / "modules"
    trained.save(modules, robot.tl.params, robot.tl.hyper, agent, saved_cfg.learner, net,
                 robot.an.config, saved_cfg.env,
                 extra={"stage": "touch_memory", "variant": config.save,
                        "episodes": rows[config.save]["episodes"],
                        **variant_plan(config.save, config)[2]},
                 agents=saved_agents, saved_agent=0)
    mine = trained.load(modules)  # loaded and asked to perform, as a user would
    task_list = al_eval.all_tasks(RS.LAYOUTS[config.layouts])
    judge_keys = jax.random.split(k_judge, (1, int(task_list.action.shape[0])))
    checks = RS.perform_checks(mine, saved_raw, judge_keys, task_list,
                               EnvParams(start_noise=config.noise[0]), config.perform_checks, 0)
    res = {"seeds": config.seeds, "episodes": config.phase1 + config.phase2,
           "touch_bonus": config.touch_bonus,
           "touch_still_penalty": config.touch_still_penalty,
           "start_noise": config.start_noise, "start_ramp": config.start_ramp,
           "push_other_penalty": config.push_other_penalty,
           "touch_moved_penalty": float(EnvParams().touch_moved_penalty), "variants": rows,
           "saved": config.save,
           "saved_obs_size": tasks.get(VARIANTS[config.save].task_set).obs_size,
           "saved_an_test_acc": an_acc,
           "perform_checks": checks,
           "perform_agreement": (float(np.mean([r["judge"] == r["perform"] for r in checks]))
                                 if checks else None)}
    atomic_write_text(pathlib.Path(out) / "touch_memory.json", json.dumps(res, indent=1))
    return res


def report(res: dict, config: TouchMemoryConfig) -> str:
    """The stage's REPORT section: a row per variant and start noise."""
    pct = RS.pct
    lines = [f"{res['seeds']} agents per variant, trained for the episodes the table says "
             f"({res['episodes']}: the run's AL schedule), judged on the same tasks and keys; "
             "median agent (min-max). A "
             "touching pose: touch's reward is minus the joints' L1 distance to the slot's "
             "touching pose (the palm on the target's top), +{b} while touching the target, "
             "-{m} per metre it moved, instead of the paper's minus the palm's distance and "
             "-0.3 while touching (not the paper's reward); holding still: -{s} per scaled "
             "joint unit the arm moves while it touches the target; random starts: within "
             "±{n} of home, the range growing from 0 over the first {r:.0%} of the "
             "episodes; push avoids the neighbours: {o} while the arm touches a non-target "
             "object or one has moved (the paper's push reward has no such term).".format(
                 b=res["touch_bonus"], m=res["touch_moved_penalty"],
                 s=res.get("touch_still_penalty", 0.0), n=res.get("start_noise", 0.5),
                 r=res.get("start_ramp", 0.5), o=res.get("push_other_penalty", -0.5)), "",
             "| variant | episodes | start | point | touch | push | touch failures: no late "
             "contact / target moved >= 3 cm |", "|---|---|---|---|---|---|---|"]
    for row in res["variants"].values():
        for noise, lv in row["levels"].items():
            cells = [RS.rate_cell(lv, a) for a in ("point", "touch", "push")]
            f = lv["touch_failures"]
            start = "home" if float(noise) == 0 else f"±{noise}"
            lines.append(f"| {row['what']} | {row.get('episodes', res['episodes'])} | {start} | "
                         f"{' | '.join(cells)} | "
                         f"{pct(f['no_late_contact'])} / {pct(f['target_moved_3cm'])} |")
    saved = next(iter(res["variants"][res["saved"]]["levels"].values()))["by_action"]
    met = saved["touch"] >= GOAL_TOUCH and min(saved["point"], saved["push"]) >= GOAL_OTHERS
    start = "home" if config.noise[0] == 0 else f"starts within ±{config.noise[0]}"
    lines += ["", f"Goal (from {start}): touch >= {pct(GOAL_TOUCH)} with point and push >= "
              f"{pct(GOAL_OTHERS)}: {'met' if met else 'missed'} by the saved variant "
              f"({VARIANTS[res['saved']].what}, observation of {res['saved_obs_size']} units). "
              f"Saved as a robot in `touch_memory/modules` with an AN fitted on its agent 0 "
              f"(test accuracy {pct(res['saved_an_test_acc'])})."]
    far = res["variants"][res["saved"]]["levels"].get(str(RS.GOAL_NOISE))
    if far is not None:
        missed = [a for a, g in RS.GOALS.items() if far["by_action"][a] < g]
        lines += ["", f"Random starts' goal (within ±{RS.GOAL_NOISE}: point / touch / push >= "
                  f"{' / '.join(pct(g) for g in RS.GOALS.values())}): "
                  + (f"missed for {', '.join(missed)}" if missed else "met")
                  + " by the saved variant."]
    lines += RS.perform_sentence(len(res["perform_checks"]), res["perform_agreement"])
    return "\n".join(lines)


STAGE = Stage(name="touch_memory", title="Beyond the paper: touch with memory",
              config=TouchMemoryConfig, run=run, report=report,
              profiles={"paper": {"seeds": 8, "phase2": 1050, "still_extra": 1050,
                                  "layouts": "all", "variants": tuple(VARIANTS),
                                  "perform_checks": 6}})
