"""Every action from random starting postures: the saved robot's AL agents judged on point,
touch and push from joints drawn around home, at several noise levels.

The paper measures random starts for point only (Fig 11, joints within ±0.5 of home in
scaled joint units, where each joint's range spans [-1, 1]). This stage judges all three
actions from the home pose (noise 0) and from random starts, on the same tasks and the same
keys at every level (a start is the same direction from home, scaled), for every AL agent the
run saved: the median agent and the spread over agents. A few episodes are performed again
through ``Robot.perform`` (the TL finding the object, the robot acting) and must succeed or
fail as the batched judge said.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import jax
import numpy as np

from grounding_jax.core import trees
from grounding_jax.core.io import atomic_write_text
from grounding_jax.paper import al_eval
from grounding_jax.paper.stage import Inputs, Stage
from grounding_jax.sim import scene
from grounding_jax.sim.env import Env, EnvParams, make_task

#: the layouts judged: every shape at every slot once (6), or all 36
LAYOUTS = {"shapes": al_eval.SHAPE_LAYOUTS, "all": al_eval.ALL_LAYOUTS}
#: the goals at ±0.3 (success of the median agent)
GOALS = {"point": 0.90, "touch": 0.85, "push": 0.90}
GOAL_NOISE = 0.3


@dataclasses.dataclass(frozen=True)
class RandomStartsConfig:
    """The noise levels (half-widths in scaled joint units; 0 is the home pose), which
    layouts, the starts per task, and how many episodes ``perform`` runs again per level."""

    noise: tuple[float, ...] = (0.0, 0.15, 0.3, 0.5)
    layouts: str = "shapes"
    starts: int = 1
    perform_checks: int = 3

    def __post_init__(self) -> None:
        if not self.noise or any(not 0.0 <= n <= 1.0 for n in self.noise):
            raise ValueError(f"noise: {self.noise!r}; accepted: one or more values in [0, 1]")
        if self.layouts not in LAYOUTS:
            raise ValueError(f"layouts: {self.layouts!r}; accepted values: {list(LAYOUTS)}")
        if self.starts < 1 or self.perform_checks < 0:
            raise ValueError(f"starts >= 1 and perform_checks >= 0, got {self.starts} and "
                             f"{self.perform_checks}")


def _level(table: dict, out: dict, saved: int) -> dict:
    touch = np.asarray(out["action"]) == 1
    moved = np.asarray(out["target_moved"])[..., touch]
    failed = np.asarray(out["success"])[..., touch] < 0.5
    # why touch episodes failed (shares of all touch episodes; one may have several reasons)
    why = {"no_late_contact": np.asarray(out["touched_late"])[..., touch] < 0.5,
           "target_moved_3cm": moved >= 0.03,
           "wrong_object_moved": np.asarray(out["wrong_moved"])[..., touch] > 0.5}
    return {"by_action": table["by_action"], "spread": table["spread"],
            "pooled": table["pooled"],
            "saved_agent": {a: v[saved] for a, v in table["per_agent_by_action"].items()},
            "touch_target_moved_cm_median": float(100 * np.median(moved)),
            "touch_failures": {k: float(np.mean(v & failed)) for k, v in why.items()}}


def perform_checks(robot, out: dict, keys: jax.Array, tasks, params: EnvParams, n: int,
                    saved: int) -> list[dict]:
    """The first ``n`` tasks of each action of ``tasks`` again through ``robot.perform`` (its
    TL included), with the judge's own key for that episode (``keys[0, task]``): did it
    succeed as the judge's ``out`` said for agent ``saved``?"""
    rows = []
    acts = np.asarray(tasks.action)
    for a in range(len(scene.ACTIONS)):
        for t in np.flatnonzero(acts == a)[:n]:
            pos, lay = int(tasks.position[t]), int(tasks.layout[t])
            word = scene.LAYOUTS[lay][0][pos]
            res = robot.perform(scene.ACTIONS[a], word, layout=lay, key=keys[0, t],
                                params=params)
            got = al_eval.episode_success(res["trajectory"], make_task(a, pos, lay))
            rows.append({"command": f"{scene.ACTIONS[a]} {word}", "layout": lay,
                         "located": res["position"] == scene.POSITIONS[pos],
                         "judge": bool(np.asarray(out["success"])[saved, 0, t]),
                         "perform": bool(got["success"])})
    return rows


def judge_levels(agents, env_config, key: jax.Array, config: RandomStartsConfig,
                 saved: int = 0) -> tuple[dict, dict]:
    """``agents`` (stacked) judged at each of ``config.noise`` on the same tasks and keys:
    ({noise: the level's rates}, {noise: the judge's raw output})."""
    judge = al_eval.make_success(Env(env_config), layouts=LAYOUTS[config.layouts],
                                 starts=config.starts)
    levels, raw = {}, {}
    for noise in config.noise:
        raw[str(noise)] = jax.device_get(judge(agents, key, EnvParams(start_noise=noise)))
        levels[str(noise)] = _level(al_eval.success_table(raw[str(noise)]), raw[str(noise)],
                                    saved)
        ba = levels[str(noise)]["by_action"]
        print(f"start noise {noise:.2f}: median agent point {ba['point']:.2f} touch "
              f"{ba['touch']:.2f} push {ba['push']:.2f}", flush=True)
    return levels, raw


def run(key: jax.Array, inputs: Inputs, out: pathlib.Path, config: RandomStartsConfig
        ) -> dict:
    """Judge the saved robot's agents at each noise level (see the module doc)."""
    from grounding_jax.robot import trained

    robot = trained.load(inputs.modules)
    agents = robot.agents if robot.n_agents else trees.add_axis(robot.al.agent)
    saved = robot.saved_agent or 0
    tasks = al_eval.all_tasks(LAYOUTS[config.layouts])
    keys = jax.random.split(key, (config.starts, int(tasks.action.shape[0])))
    levels, raw = judge_levels(agents, robot.env_config, key, config, saved)
    checks = {noise: perform_checks(robot, raw[noise], keys, tasks,
                                     EnvParams(start_noise=float(noise)),
                                     config.perform_checks, saved) for noise in levels}
    agree = [r["judge"] == r["perform"] for rows in checks.values() for r in rows]
    res = {"agents": int(jax.tree.leaves(agents)[0].shape[0]), "saved_agent": saved,
           "tasks": int(tasks.action.shape[0]), "starts": config.starts, "levels": levels,
           "perform_checks": checks,
           "perform_agreement": float(np.mean(agree)) if agree else None}
    pathlib.Path(out).mkdir(parents=True, exist_ok=True)
    atomic_write_text(pathlib.Path(out) / "random_starts.json", json.dumps(res, indent=1))
    return res


def pct(v: float) -> str:
    """A rate in [0, 1] as a whole percentage."""
    return f"{100 * v:.0f}%"


def rate_cell(level: dict, action: str) -> str:
    """A level's median agent for ``action``, with the min-max over agents."""
    spread = level["spread"][action]
    return f"{pct(level['by_action'][action])} ({pct(spread[0])}-{pct(spread[-1])})"


def perform_sentence(checks: int, agreement: float | None) -> list[str]:
    """The REPORT's line on episodes performed again through ``Robot.perform``."""
    if agreement is None:
        return []
    return ["", f"`Robot.perform` (its TL finding the object) on {checks} of these episodes, "
            f"with the judge's keys: the same outcome as the batched judge in "
            f"{pct(agreement)}."]


def report(res: dict, config: RandomStartsConfig) -> str:
    """The stage's REPORT section: a row per noise level."""
    lines = [f"Success of the median AL agent of {res['agents']} (min-max over agents; the "
             f"saved robot's agent in brackets) on {res['tasks']} tasks x {res['starts']} "
             "start(s), from joints uniform within ±noise (scaled joint units; each range "
             "spans [-1, 1]) of home. The paper measures point only, at ±0.5 (Fig 11: "
             "generalizes).", "", "| start noise | point | touch | push | touch: target "
             "moved (median) |", "|---|---|---|---|---|"]
    for noise, lv in res["levels"].items():
        cells = [f"{rate_cell(lv, a)} [{pct(lv['saved_agent'][a])}]"
                 for a in ("point", "touch", "push")]
        label = "0 (home)" if float(noise) == 0 else f"±{noise}"
        lines.append(f"| {label} | {' | '.join(cells)} | "
                     f"{lv['touch_target_moved_cm_median']:.1f} cm |")
    goal = res["levels"].get(str(GOAL_NOISE))
    if goal is not None:
        missed = [a for a, g in GOALS.items() if goal["by_action"][a] < g]
        lines += ["", f"Goal at ±{GOAL_NOISE}: point / touch / push >= "
                  f"{' / '.join(pct(g) for g in GOALS.values())}: "
                  + (f"missed for {', '.join(missed)}." if missed else "met.")]
    n = sum(len(v) for v in res["perform_checks"].values())
    return "\n".join(lines + perform_sentence(n, res["perform_agreement"]))


STAGE = Stage(name="random_starts", title="Beyond the paper: every action from random starts",
              config=RandomStartsConfig, run=run, report=report,
              profiles={"paper": {"layouts": "all", "perform_checks": 6}})
