"""REPORT.md: the paper's numbers beside ours, from a run's ``metrics.json``.

``train.py`` writes ``results/<profile>/metrics.json`` and then `report` of it;
``python train.py --report-only`` rewrites the report from the stored metrics alone.
"""

from __future__ import annotations

import statistics

from grounding_jax.paper import stage

#: What the paper reports, in one place (the report's "paper" column).
PAPER = {
    "tl_test_acc": "~95%", "tl_train_acc": "100%", "tl_test_rmse": "0.136",
    "tl_train_rmse": "0.037", "fig6_h50": "~95%", "fig7_n1": "<= 75%",
    "fig7_best": "20 (~95%)", "noise_fixed": "100% / ~75%",
    "point": "perfect (Fig 10)", "touch": "keeps touching gently (Fig 10)",
    "push": "very good (Fig 10)", "random_start_point": "generalizes (Fig 11)",
    "goal_switch": "turns to the new goal (Fig 13)",
    "an_accuracy": "> 99%", "an_settle": "a few", "fig12": "clusters by both",
    # the values the paper went on with after each sweep (its Table 2)
    "sweep_choice": {"fig8a_critic_lr": 0.01, "fig8b_critic_hidden": 20,
                     "fig9a_actor_lr": 0.001, "fig9b_actor_hidden": 40},
}


def _an_report(an: dict) -> list[str]:
    sd = lambda r: f"{_pct(r['acc_mean'])} ± {100 * r['acc_std']:.1f}"  # noqa: E731
    f12 = an["fig12"]
    return [
        "", "## Action namer and SOM", "",
        f"ESN 90 -> 50 linear reservoir (spectral radius 0.9, 20% connectivity) -> 9, readout "
        f"by pseudo-inverse over all steps; {an['seeds']} seeds (each its own reservoir and "
        f"2/3 : 1/3 split of the 216 configurations), {an['steps']}-step sequences of AL agent "
        f"0 and a TL (H=50, n=20; test accuracy {_pct(an['tl_test_acc'])}). Correct = both "
        "words right at the last step.", "",
        "| result | paper | ours |", "|---|---|---|",
        f"| train accuracy | {PAPER['an_accuracy']} | {sd(an['train'])} |",
        f"| test accuracy (home start, zero initial state) | {PAPER['an_accuracy']} | "
        f"{sd(an['test'])} |",
        f"| test accuracy, random arm start and random initial state | {PAPER['an_accuracy']} | "
        f"{sd(an['test_random'])} |",
        f"| steps until the naming settles (median; random starts) | {PAPER['an_settle']} | "
        f"{an['test']['settle_median']:.1f} ({an['test_random']['settle_median']:.1f}) |",
        f"| Fig 12: SOM cluster purity by action / by position | {PAPER['fig12']} | "
        f"{f12['purity_action']:.2f} / {f12['purity_position']:.2f} |",
        "", "![Fig 15](an/fig15.png)", "![Fig 12](an/fig12.png)"]


def _al_report(al: dict) -> list[str]:
    eps = sorted(al["success"], key=int)
    goal = {a: f"{PAPER[a]}; goal >= {AL_GOALS[a]:.0%}" for a in ("point", "touch", "push")}
    head = " | ".join(f"after {e} episodes" for e in eps)

    def cell(table: dict, a: str) -> str:
        lo, _, med, _, hi = table["spread"][a]
        return f"{_pct(med)} ({_pct(lo)}-{_pct(hi)})"

    lines = ["", "## Action learner", "",
             f"CACLA, {al['seeds']} agents, phase 1 for {al['phase1']} episodes then plain "
             f"CACLA; hyperparameters {al['hyper']}. Judged with the greedy actor in "
             "100-step episodes on all 9 tasks x 36 layouts from home (the criteria: point -- "
             "final L1 < 0.1, L1 range over the last 10 steps < 0.02, target moved < 1 cm; "
             "touch -- contact with the target in the second half, target moved < 3 cm; push "
             "-- target moved >= 2 cm; none may move a wrong object). Random starts: point "
             f"from joints uniform within +-{al['random_start_noise']} (scaled) of home, one "
             "per position and layout (108). Goal switch: each of the 9 tasks x 6 layouts "
             "switched at step 20 to each task that differs in action or position alone "
             "(216 per agent), judged by the second task's criterion on what happened after "
             "the switch. Each cell: the median agent's success rate (min-max over agents). "
             "450 episodes is the paper's schedule (150 + 300).", "",
             f"| success rate | paper | {head} |", "|---|---|" + "---|" * len(eps)]
    for a in ("point", "touch", "push"):
        lines.append(f"| {a}, from home | {goal[a]} | " + " | ".join(
            cell(al["success"][e]["home"], a) for e in eps) + " |")
    lines.append(f"| point, random starts | {PAPER['random_start_point']}; goal >= "
                 f"{AL_GOALS['random-start point']:.0%} | " + " | ".join(
        cell(al["success"][e]["random_starts"], "point") for e in eps) + " |")
    if all("switch" in al["success"][e] for e in eps):
        lines.append(f"| goal switch at step 20 | {PAPER['goal_switch']}; goal >= "
                     f"{AL_GOALS['goal switch']:.0%} | " + " | ".join(
                         _pct(al["success"][e]["switch"]["overall"]) for e in eps) + " |")
    lines.append("| point: median / 90th percentile final L1 (criterion < 0.1) | - | "
                 + " | ".join(f"{al['success'][e]['home']['point_l1_median']:.3f} / "
                              f"{al['success'][e]['home']['point_l1_p90']:.3f}" for e in eps)
                 + " |")
    last = al["final"]["home"]["by_task"]
    lines += ["", f"Per task after {eps[-1]} episodes, from home (all agents' episodes "
              "pooled): " + ", ".join(f"{k} {_pct(v)}" for k, v in last.items()) + "."]
    if "switch" in al["final"]:
        lines += ["", "Goal switch by the second task's action (the median agent): " + ", ".join(
            f"{k} {_pct(v)}" for k, v in al["final"]["switch"]["by_action"].items()) + "."]
    lines += ["",
              "| Fig 13 switch (step 20) | reward before | just after | final | second task "
              "succeeded |", "|---|---|---|---|---|"]
    for r in al["fig13"]["runs"]:
        lines.append(f"| {r['first']} -> {r['second']} | {r['reward_before_switch']:+.3f} | "
                     f"{r['reward_after_switch']:+.3f} | {r['final_reward']:+.3f} | "
                     f"{'yes' if r['second_task_success'] else 'no'} |")
    tail, knocks = al["training_tail"], al["exploration_knocks"]
    ret = lambda t: ", ".join(f"{a} {v:.1f}" for a, v in t["return_by_action"].items()  # noqa: E731
                              if v is not None)
    lines += ["", f"Training, last {tail['episodes'][1] - tail['episodes'][0]} episodes: "
              f"{_pct(tail['wrong_moved_share'])} ended early because a wrong object moved; "
              f"{tail['mean_steps']:.1f} steps per episode on average (of 75); return by "
              f"action {ret(tail)}."]
    if "no_tricks_tail" in al:
        nt = al["no_tricks_tail"]
        lines.append(f"Fig 14, no tricks (plain CACLA from the start, {nt['episodes'][1]} "
                     f"episodes), last {nt['episodes'][1] - nt['episodes'][0]} episodes: "
                     f"return by action {ret(nt)}; wrong-move share "
                     f"{_pct(nt['wrong_moved_share'])}.")
    lines += ["", "Exploration alone knocks objects: a perfect point policy (tracking the "
              "stored pose) plus Gaussian exploration noise moves a wrong object in "
              + ", ".join(f"{_pct(v['wrong_moved_share'])} of episodes at sigma {k}"
                          for k, v in knocks.items()) + " (with the earlier geometry -- palm "
              "1 cm above the object, home beside the right object, 26-50 g objects: 52% at "
              "sigma 0.3).", "",
              _al_goals(al)]
    lines += ["", "![success against episodes](al/success_curve.png)",
              "![Fig 10](al/fig10.png) ![Fig 11](al/fig11.png)",
              "![Fig 13](al/fig13.png)"]
    if "fig14" in al:
        lines += ["![Fig 14, no tricks](al/fig14.png) "
                  "![Fig 14, with phase 1](al/fig14_paper_schedule.png)"]
    return lines


#: the goals for the median agent, after the shipped schedule
AL_GOALS = {"point": 0.95, "touch": 0.85, "push": 0.90, "random-start point": 0.90,
            "goal switch": 0.80}


def _al_goal_split(al: dict) -> tuple[dict[str, float], dict[str, float]]:
    """(goals the final median agent meets, goals it misses): {goal name: measured rate}."""
    fin = al["final"]
    got = {**{a: fin["home"]["by_action"][a] for a in ("point", "touch", "push")},
           "random-start point": fin["random_starts"]["by_action"]["point"]}
    if "switch" in fin:
        got["goal switch"] = fin["switch"]["overall"]
    return ({k: v for k, v in got.items() if v >= AL_GOALS[k]},
            {k: v for k, v in got.items() if v < AL_GOALS[k]})


def _al_goals(al: dict) -> str:
    """Which goals the final median agent meets and misses, with the measured reasons."""
    met, missed = _al_goal_split(al)
    fmt = lambda d: ", ".join(f"{k} {_pct(v)} (goal {_pct(AL_GOALS[k])})"  # noqa: E731
                              for k, v in d.items()) or "none"
    text = (f"Goals after {max(map(int, al['success']))} episodes -- met: {fmt(met)}; "
            f"missed: {fmt(missed)}.")
    reasons = {
        "touch": "touch -- the paper's reward pays about 0.3 less for resting in contact than "
                 "for resting a few millimetres short of it, so a precise greedy actor hovers "
                 "(its failures move nothing)",
        "push": "push -- the failures move a neighbour on the way or stop short of 2 cm",
        "goal switch": "goal switch -- see its rates by the second task's action above: "
                       "switches to touch share touch's hovering; switches to push start "
                       "wherever the first task left the arm (not analysed further)",
        "point": "point -- the actor rests short of the pose (precision)",
        "random-start point": "random-start point -- as point, from farther away"}
    if missed:
        text += (" Why, as measured (docs/al.md): "
                 + "; ".join(reasons[k] for k in missed) + ".")
    if max(map(int, al["success"])) > 450:
        text += (" At the paper's 450 episodes the decays of the learning rate and sigma, "
                 "spread over the whole run, have not yet taken hold (the table).")
    return text


def _pct(v: float) -> str:
    return f"{100 * v:.1f}%"


def metrics_csv(result: dict) -> str:
    """Every number of metrics.json as ``key,value`` rows (dotted keys; lists by index)."""
    rows = []

    def walk(prefix: str, v) -> None:
        if isinstance(v, dict):
            for k, x in v.items():
                walk(f"{prefix}.{k}" if prefix else str(k), x)
        elif isinstance(v, list):
            for i, x in enumerate(v):
                walk(f"{prefix}.{i}", x)
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            rows.append(f"{prefix},{v!r}")

    walk("", result)
    return "key,value\n" + "\n".join(rows) + "\n"


def _beyond_report(beyond: dict | None) -> list[str]:
    lines = ["", "## Beyond the paper", ""]
    if not beyond:
        return lines + ["Not in this metrics.json (made before the free-placement work)."]
    x = beyond["tl_xy"]
    ok = lambda v, goal: "met" if v <= goal else "missed"  # noqa: E731
    g = x["goals_cm"]
    words = list(x["by_word_median_cm"])
    lines += [
        "Objects anywhere on the reachable table (x in [-0.27, -0.20] m, y in [0.09, 0.31] m, "
        "centres >= 9 cm apart, yaw random). The target localizer answers the target's table "
        f"coordinates (regression; docs/beyond.md): {x['seeds']} seeds, each "
        f"trained on its own {x['scenes'] - x['test_scenes']} of {x['scenes']} rendered "
        f"scenes and judged on the other {x['test_scenes']} (all six target words each), "
        "against the positions the simulator holds.", "",
        "| held-out error | goal | median seed | seeds (min-max) | |", "|---|---|---|---|---|",
        f"| median (cm) | <= {g['median']} | {x['median_cm_median_seed']:.2f} | "
        f"{min(x['median_cm']):.2f}-{max(x['median_cm']):.2f} | "
        f"{ok(x['median_cm_median_seed'], g['median'])} |",
        f"| 95th percentile (cm) | <= {g['p95']} | {x['p95_cm_median_seed']:.2f} | "
        f"{min(x['p95_cm']):.2f}-{max(x['p95_cm']):.2f} | "
        f"{ok(x['p95_cm_median_seed'], g['p95'])} |", "",
        "| word | " + " | ".join(words) + " |", "|---|" + "---|" * len(words),
        "| median (cm) | " + " | ".join(f"{x['by_word_median_cm'][w]:.2f}" for w in words)
        + " |",
        "| 95th pct (cm) | " + " | ".join(f"{x['by_word_p95_cm'][w]:.2f}" for w in words)
        + " |", "", "![TL with free placement](beyond/tl_xy.png)",
    ]
    return lines + _free_report(beyond.get("free"), beyond.get("strip"))


def _rate_cell(table: dict, action: str) -> str:
    lo, hi = table["spread"][action][0], table["spread"][action][-1]
    return f"{_pct(table['by_action'][action])} ({_pct(lo)}-{_pct(hi)})"


def _networks(heads: list[int] | None) -> str:
    """The sentence on which actions share an actor-critic (``CaclaConfig.heads``)."""
    if not heads:
        return "One actor-critic serves all three actions (told the action by its one-hot)."
    names = ("point", "touch", "push")
    groups = [[n for n, h in zip(names, heads, strict=True) if h == g]
              for g in range(max(heads) + 1)]
    said = [g[0] + " alone" if len(g) == 1 else " and ".join(g) + " together" for g in groups]
    return ("Networks (`CaclaConfig.heads`): " + "; ".join(said)
            + " -- an actor-critic of the paper's sizes each.")


#: What the report says of the hand units (``TaskSet.hand_obs``) where a run had them.
_HAND_TEXT = (", and sees where its palm is relative to those coordinates (three units, "
              "tanh of the offset per axis over 10 cm: the hand units)")


def _free_touch_text(free: dict) -> str:
    """What the free family's touch reward was in the run that wrote ``free``."""
    h = free["hyper"]
    if free.get("touch_reward") != "pose":  # runs before the touching pose
        return ("touch pays minus the palm's distance to where the target is now until it "
                "touches it, then nothing, less 10 per metre the target moved.")
    return ("touch, like point, pays minus the L1 distance to a pose: the touching pose (the "
            "palm pressed on the target's top; IK poses on the pointing map's grid, "
            f"interpolated inside jit), plus {h.get('touch_bonus', 0.0)} while touching it, "
            f"less {h.get('touch_moved_penalty', 10.0)} per metre the target moved; push pays "
            "minus the palm's distance to the target's centre.")


def _free_report(free: dict | None, strip: dict | None) -> list[str]:
    if not free:
        return ["", "Not in this metrics.json: the free family's action learner (made before "
                "it existed)."]
    goals = free["final"]["goals"]
    stops = sorted(free["success"], key=int)
    hyper = ", ".join(f"{k} {v}" for k, v in free["hyper"].items())
    lines = [
        "", "### Acting anywhere: the free family's action learner", "",
        f"CACLA, {free['seeds']} agents trained on random placements (a new one every "
        f"episode, random layout), phase 1 for {free['phase1']} episodes then plain CACLA. "
        "The actor is told where the target is by the simulator, as a population code of its "
        "coordinates (Gaussian bumps on a 3 x 7 grid over the reachable region) instead of "
        f"its slot{_HAND_TEXT if free.get('hand_obs') else ''}. "
        f"{_networks(free.get('heads'))} Settings: {hyper} (the paper family's "
        "but for gamma, the actor's rate and, where listed, the action's scale; "
        "docs/beyond.md has the measurements behind each change). The "
        "free family's rewards: every action pays -0.5 while touching a non-target object; "
        + _free_touch_text(free) + " Point's reward and criterion "
        "use the pointing map (IK poses on a 1 cm grid, smoothed, interpolated inside jit). "
        f"Judged like the paper family (greedy, 100 steps, from home) on "
        f"{free['eval_placements']} held-out random placements x 3 slots per action; each "
        "cell: the median agent (min-max over agents).", "",
        "| success | goal | " + " | ".join(f"after {e} episodes" for e in stops) + " | |",
        "|---|---|" + "---|" * len(stops) + "---|"]
    for a in ("point", "touch", "push"):
        met = "met" if free["final"]["by_action"][a] >= goals[a] else "missed"
        lines.append(f"| {a} | >= {_pct(goals[a])} | "
                     + " | ".join(_rate_cell(free["success"][e], a) for e in stops)
                     + f" | {met} |")
    # the agent the robot acts with: chosen on validation placements (before they existed,
    # the median one)
    saved = free.get("saved_agent", free["median_agent"])
    who = "The saved agent" if "saved_agent" in free else "The median agent"
    if "saved_agent" in free:
        per = free["final"]["per_agent_by_action"]
        lines += [
            "", f"**The saved agent** (the one `load` gives): agent {saved}, chosen on "
            f"{free['eval_placements']} validation placements x 3 slots per action (another "
            f"draw than the held-out ones above) as {free['selection']}. On the held-out "
            "placements: " + ", ".join(f"{a} {_pct(per[a][saved])}"
                                       for a in ("point", "touch", "push"))
            + f" (the median agent by overall rate: agent {free['median_agent']})."]
    eyes = free.get("eyes")
    if eyes:
        lines += [
            "", f"**Through its eyes.** {who} again, on {eyes['placements']} other "
            "held-out placements, told the coordinates the continuous TL reads from an "
            "eye-camera image of the scene (the target named by its colour; TL error on these: "
            f"median {eyes['tl_error_cm_median']:.2f} cm, 95th percentile "
            f"{eyes['tl_error_cm_p95']:.2f} cm): point {_pct(eyes['by_action']['point'])}, "
            f"touch {_pct(eyes['by_action']['touch'])}, push {_pct(eyes['by_action']['push'])} "
            "(the same agent told by the simulator: "
            + ", ".join(f"{a} {_pct(free['final']['per_agent_by_action'][a][saved])}"
                        for a in ("point", "touch", "push")) + ")."]
    shape = free.get("eyes_shape")
    if shape:  # the same placements, the target named by its shape (the TL's error tail)
        lines[-1] += (
            " Named by its shape instead (TL error median "
            f"{shape['tl_error_cm_median']:.2f} cm, 95th percentile "
            f"{shape['tl_error_cm_p95']:.2f} cm): "
            + ", ".join(f"{a} {_pct(shape['by_action'][a])}" for a in ("point", "touch", "push"))
            + ". Point's criterion (final L1 < 0.1 to the true pointing pose) leaves about 1 cm "
            "for the TL's error.")
    mv = free.get("moving")
    if mv:
        lines += [
            "", "### A moving target", "",
            f"The target slides right (+y) at a constant speed from the region's left edge to "
            f"its right edge (20-22 cm), its neighbours parked out of reach; {mv['scenes']} "
            f"scenes, {mv['steps']} steps ({mv['steps'] * mv['dt_s']:.0f} s), "
            f"{who.lower()}. "
            "*Tracking*: told the target's current coordinates every step (from the simulator); "
            "*start only*: told where it started (the paper's setting). Palm-target distance to "
            "the target's current point, mean over the episode's second half (median over "
            "scenes, quartiles), and at the last step.", "",
            "| action | speed (cm/s) | robot | palm-target, 2nd half (cm) | final (cm) | "
            "point L1, 2nd half | wrong object moved |", "|---|---|---|---|---|---|---|"]
        for r in mv["rows"]:
            q = r["palm_target_cm_late"]
            lines.append(f"| {r['action']} | {r['speed_cm_s']:.0f} | {r['robot']} | "
                         f"{q[1]:.1f} ({q[0]:.1f}-{q[2]:.1f}) | {r['palm_target_cm_final']:.1f} "
                         f"| {r['point_l1_late']:.3f} | {_pct(r['wrong_moved'])} |")
        lines += ["", "![moving target](beyond/moving.png)"]
    namer = free.get("an")
    if namer:
        lines += [
            "", "### Naming what it did", "",
            f"An ESN of {namer.get('n_res', 50)} units (the paper's 50 served 40 + 50 inputs; "
            f"here the continuous TL adds 200) reads {who.lower()}'s hidden layer and the "
            f"continuous TL's hidden layer for the scene and the word, and names action and "
            f"target: {namer['sequences']} sequences ({namer['scenes']} rendered random scenes x "
            f"6 words x 3 actions, 100 steps), {namer['seeds']} splits 2/3 : 1/3 by scene, "
            f"named at the last step. Train {_pct(namer['train']['acc_mean'])}, held-out scenes "
            f"{_pct(namer['test']['acc_mean'])}, held-out scenes from random arm starts "
            f"{_pct(namer['test_random']['acc_mean'])} (paper family: the AN section above)."]
    if strip:
        action, word = strip["command"].split()
        call = (f'robot.perform("{action}", "{word}", layout={strip["layout"]}, '
                'placement="random")')
        lines += ["", f"**One command, start to end** (`{call}` on the saved modules): the TL "
                  f"put the target at ({strip['xy'][0]:.3f}, {strip['xy'][1]:.3f}) m, truly at "
                  f"({strip['true_xy'][0]:.3f}, {strip['true_xy'][1]:.3f}) m; the target moved "
                  f"{strip['target_moved_cm']:.1f} cm; the namer said "
                  f"{' '.join(strip['named']) if strip.get('named') else '(no namer saved)'}.",
                  "",
                  "![camera strip](beyond/camera_strip.png)"]
    lines += ["", "Not done: the TL on fresh camera frames during motion (the moving "
              "target's coordinates come from the simulator)."]
    return lines


def _observer_report(obs: dict | None) -> list[str]:
    lines = ["", "## Beyond the paper: naming what it watches", ""]
    if not obs:
        return lines + ["Not in this metrics.json (made before the observer was built)."]
    lines += [
        "The paper's AN names what the robot does itself. Here the saved robot names what "
        "it only watches, by motor resonance (docs/observer.md): for each of its own "
        "commands (3 actions x 3 slots) it imagines making its own actor's move from every "
        "watched state, one env step, and picks the command whose imagined steps follow "
        "the watched ones most closely, in the joints and in the hand, over the reach (the "
        "smallest product of the two mean squared mismatches over the first 5 / action_scale "
        "steps); its AN then names that command from its own "
        "actor's hidden layer on the watched states and its TL's hidden layer for a word "
        "its TL places in that slot. A watched episode is named right when the "
        "action word is and the target word names the target (its shape or its colour: the "
        "observer cannot hear which one the watched robot was told). Watched: the AL agents "
        f"trained beside it from other seeds ({obs['episodes_per_agent']} episodes each, "
        f"{obs['steps']} steps, layouts and placements from a key nothing else used), and "
        "scripted movements that do each action another way (a slow straight path in joint "
        "space to a pointing, touching or pushing pose; the paper's push: a sweep from "
        "behind the object). The watched episodes the watched robot did right (by the "
        "success criteria) are counted apart: where it failed, what it did may truly look "
        "like another action.", "",
        "| watched | episodes | named right (median agent) | agents (min-max) | "
        "of the episodes it did right | goal |",
        "|---|---|---|---|---|---|"]
    for fam in ("paper", "free"):
        if fam in obs:
            r = obs[fam]
            n = sum(a["n"] for a in r["agents"])
            done = [a["acc_succeeded"] for a in r["agents"] if a["acc_succeeded"] is not None]
            k = len(r["agents"])
            lines.append(f"| {fam} family, {k} other agent{'s' * (k != 1)} | {n} | "
                         f"{_pct(r['acc_median'])} | {_pct(r['acc_min'])}-{_pct(r['acc_max'])}"
                         f" | {_pct(statistics.median(done)) if done else '-'} (median agent)"
                         f" | >= {_pct(obs['goal'])} |")
    for fam, r in obs["scripted"].items():
        lines.append(f"| {fam} family, scripted movements | {r['n']} | {_pct(r['acc'])} "
                     f"(action {_pct(r['action_acc'])}, target {_pct(r['target_acc'])}) | - | "
                     + (_pct(r["acc_succeeded"]) if r["acc_succeeded"] is not None else "-")
                     + " | - |")
    if obs.get("other_agent") is not None:
        ok = "met" if obs["other_agent"] >= obs["goal"] else "missed"
        lines += ["", f"Other agents, both families together: the median agent "
                  f"{_pct(obs['other_agent'])} (goal >= {_pct(obs['goal'])}: {ok})."]
    names = ("point", "touch", "push")
    lines += ["", "Where it confuses (rows: the action done; columns: the action named; "
              "summed over the watched agents):", "",
              "| watched | " + " | ".join(f"{a} named {b}" for a in names for b in names
                                          if a != b) + " |",
              "|---|" + "---|" * 6]
    rows = [(f"{fam} family, other agents", obs[fam]["confusion"]) for fam in ("paper", "free")
            if fam in obs]
    rows += [(f"{fam} family, scripted", r["confusion"]) for fam, r in obs["scripted"].items()]
    for label, m in rows:
        lines.append(f"| {label} | " + " | ".join(str(m[i][j]) for i in range(3)
                                                    for j in range(3) if i != j) + " |")
    lines += ["", "![observer](observer/observer.png)", "",
              "Naming from frames only (no joint angles) is the `watch_frames` stage: its "
              "section below." if obs.get("frames") is None else ""]
    return lines


def _sweeps_report(sweeps: dict | None) -> list[str]:
    if not sweeps:
        return ["", "## Action learner sweeps (Figs 8, 9)", "", "Not in this metrics.json "
                "(written before the sweeps were part of train.py)."]
    titles = {"fig8a_critic_lr": "Fig 8A", "fig8b_critic_hidden": "Fig 8B",
              "fig9a_actor_lr": "Fig 9A", "fig9b_actor_hidden": "Fig 9B"}
    chosen = PAPER["sweep_choice"]
    lines = ["", "## Action learner sweeps (Figs 8, 9)", "",
             "From `sweeps/*.toml` (run one alone with `python -m grounding_jax.sweep FILE`). "
             "The paper's settings elsewhere (actor lr 0.001, critic lr 0.01, sigma 0.1, "
             f"gamma 0, 40/20 hidden units), phase 1 for the first "
             f"{next(iter(sweeps.values()))['spec']['params'].get('phase1_episodes', 150)} "
             "episodes. Critic sweeps plot the critic's RMS TD error per episode (lower is "
             "better), actor sweeps the reward at each training episode's last step (higher "
             "is better); the value below is the mean over the last tenth of the episodes, "
             "mean ± std over seeds. Diverged runs (non-finite) are counted and left out. "
             "The paper's text does not name the measure its Figs 8 and 9 plot, so these two "
             "are our choice; its conclusions are compared below, not its curves.", "",
             "| figure | episodes | paper | ours: value per grid point | best (ours) | the "
             "paper's choice, ranked among ours |", "|---|---|---|---|---|---|"]
    from grounding_jax.paper.adapters import LOWER_IS_BETTER

    for name, s in sweeps.items():
        spec = s["spec"]
        x = spec["x"]
        ok = [p for p in s["points"] if p["mean"] is not None]
        vals = "; ".join(f"{p['point'][x]}: " + ("diverged" if p["mean"] is None else
                                                 f"{p['mean']:.3f} ± {p['std']:.3f}")
                         for p in s["points"])
        eps = spec["params"].get("phase1_episodes", 150) + spec["params"].get(
            "phase2_episodes", 300)
        div = f" ({s['diverged_runs']} runs diverged)" if s["diverged_runs"] else ""
        sign = 1 if s["metric"] in LOWER_IS_BETTER else -1
        ranked = sorted(ok, key=lambda p, sign=sign: p["mean"] * sign)
        pick = [i for i, p in enumerate(ranked) if p["point"][x] == chosen.get(name)]
        rank = (f"{x} = {chosen[name]}: {pick[0] + 1} of {len(ranked)}" if pick else
                "not in the grid")
        lines.append(f"| {titles.get(name, name)}: {x} ({s['metric']}) | {eps} | "
                     f"{spec['paper']} | {vals}{div} | {x} = {ranked[0]['point'][x]} | {rank} |")
    lines += [""] + [f"![{titles.get(n, n)}](sweeps/{n}/{s['spec']['figure']}.png)"
                     for n, s in sweeps.items()]
    return lines


def _tl_reference_report(tl: dict) -> list[str]:
    """The TL beside the lookup bound and the standard learners, the goals, and the noise
    protocols."""
    a, n, nf = tl["accuracy"], tl["noise"], tl["noise_fresh"]
    lines = ["", "Our TL beside a lookup that knows the task's structure (the majority label of "
             "the training configurations with the same target word and the same colour order, "
             "for colour words, or shape order, for shape words) and two standard learners "
             "(optax Adam, cross-entropy, on the paper's unscaled inputs), on the same "
             "train/test splits:", "",
             "| learner | test accuracy | min over splits | shape words | colour words |",
             "|---|---|---|---|---|"]
    for name, r in tl.get("reference", {}).get("learners", {}).items():
        lines.append(f"| {name} | {_pct(r['test_acc_mean'])} ± {100 * r['test_acc_std']:.1f}"
                     f" | {_pct(r['test_acc_min'])} | {_pct(r['test_acc_shape_words_mean'])} | "
                     f"{_pct(r['test_acc_colour_words_mean'])} |")
    low = min(a["test_acc_per_seed"])
    met = a["test_acc_mean"] >= 0.95 and low >= 0.85
    lines += ["", "![reference](tl/reference.png)", "",
              f"Goal (>= 95% mean test accuracy, no split below 85%): "
              f"{'met' if met else 'MISSED'} -- {_pct(a['test_acc_mean'])} mean, lowest split "
              f"{_pct(low)}.",
              "", f"Pixel noise (10% flips): with one fixed draw per pattern (a fixed noisy data "
              f"set) the network still learns every training pattern ({_pct(n['train_acc_mean'])})"
              f" and tests at {_pct(n['test_acc_mean'])}; with fresh flips at every presentation "
              f"the noise acts as a regularizer ({_pct(nf['test_acc_mean'])}). The paper's "
              "100% train / ~75% test, 'probably due to overfitting', is the fixed protocol: "
              "only a fixed noisy set can be learned to 100% while test patterns bring unseen "
              "flips."]
    return lines


def _strips_report(strips: dict[str, str] | None) -> list[str]:
    if not strips:
        return []
    from grounding_jax.paper.strips import COMMANDS, LAYOUT

    words = dict(COMMANDS)
    lines = ["## The robot acting", "",
             f"The saved modules asked to perform, on layout {LAYOUT} (the paper's slots), "
             "seen from the third-person camera; four frames of each 100-step episode, with "
             "what the robot heard and how its namer named the episode "
             "(`python -m grounding_jax.show` renders any command as a video).", ""]
    for action, path in strips.items():
        lines += [f"**{action} {words[action]}**", "", f"![{action}]({path})", ""]
    return lines


def _speed_report(result: dict, wall: dict[str, float]) -> list[str]:
    """Wall time by part, the XLA programs built and the physics floor (runs before these
    were recorded show the wall times only)."""
    parts = ", ".join(f"{k} {v:.1f} s" for k, v in wall.items() if k != "total")
    lines = ["", "## Speed", ""]
    own = result.get("beside") or []
    if "total" in wall:
        lines.append(f"Whole command: {wall['total']:.1f} s (parts: {parts})."
                     + (f" {', '.join(own)} ran on its own thread beside the other parts, so "
                        "the parts add up to more than the whole." if own else ""))
    else:
        lines.append(f"Wall time: {parts}.")
    if "compiles" in result:
        d = result.get("compiles_detail", {})
        sec = d.get("seconds", {})
        lines += ["", f"XLA programs built: {result['compiles']} ({d.get('compiled', '?')} "
                  f"compiled, {d.get('from_cache', '?')} loaded from the persistent cache; "
                  f"tracing {sec.get('trace', 0):.1f} s, lowering {sec.get('lower', 0):.1f} s, "
                  f"compiling or loading {sec.get('build', 0):.1f} s; counted with "
                  "`jax.monitoring`)."]
    floor, phys = result.get("physics_floor_s"), result.get("physics")
    if floor and phys and "total" in wall:
        lines += ["", f"Physics floor: {floor:.1f} s = {phys['rl_steps']:,} RL steps at the "
                  f"physics-alone ceiling of {phys['ceiling_rl_steps_per_s']:,.0f} RL steps/s "
                  "(measured at the end of the run on a sample of the steps it simulated, "
                  "batches of 256, the faster of `mujoco.rollout` and the compiled step) + "
                  f"the TL's compute {phys['tl_compute_s']:.1f} s. "
                  f"Whole command / floor: **{wall['total'] / floor:.2f}×**."]
        if "tl" in own and phys.get("physics_s"):
            lines[-1] += (" The TL's compute was timed while it shared the cores with the "
                          "other parts, which makes it longer than alone; the whole command "
                          "/ the physics term alone: "
                          f"{wall['total'] / phys['physics_s']:.2f}×.")
    elif "physics_floor_s" in result:
        lines += ["", "Physics floor: not measured (the MJX backend has no rollout-alone "
                  "counter)."]
    else:
        lines += ["", "XLA programs and physics floor: not recorded (this run predates "
                  "them)."]
    return lines


def report(result: dict, strips: dict[str, str] | None = None) -> str:
    """REPORT.md: the paper's numbers beside ours, figures embedded.

    Args:
        result: a run's metrics (``train.py`` writes them to ``metrics.json``).
        strips: ``{action: image path}`` of the robot acting (see
            `grounding_jax.paper.strips`), shown first; None: no such section.

    Returns:
        The report's Markdown text.
    """
    env_rows, tl, al, an = (result["scripted_episodes"], result["tl"], result["al"],
                            result["an"])
    wall, sweeps = result["wall_s"], result.get("sweeps")
    a, n, nf = tl["accuracy"], tl["noise"], tl["noise_fresh"]
    f6 = {p["hidden"]: p for p in tl["fig6"]["points"]}
    f7 = {p["replication"]: p for p in tl["fig7"]["points"]}
    best7 = max(tl["fig7"]["points"], key=lambda p: p["test_acc_mean"])
    sd = lambda p: f" ± {100 * p['test_acc_std']:.1f}"  # noqa: E731
    lines = [
        f"# grounding_jax report ({result['profile']} profile, backend {result['backend']}, "
        f"seed {result['seed']})", "",
        f"TL: the paper's network (1500-H-3 sigmoid, squared error, online backprop, "
        f"winner-take-all), {tl['accuracy']['epochs']} epochs, {tl['accuracy']['seeds']} "
        f"seeds (train/test splits) per point, lr {a['lr']}, on pixels = {a['image_scale']}, "
        f"target units = {a['target_scale']} (the paper: lr 0.1, both 1; docs/tl.md). "
        "Means ± std over seeds.", "",
        *_strips_report(strips),
        "| module | status |", "|---|---|",
        "| scene + env | done: scripted episodes below |",
        "| TL target localizer, Figs 6, 7, noise | done: below |",
        "| AL action learner, Figs 10, 11, 13, 14 | done: below ("
        + (f"success goals missed: {', '.join(missed)}" if (missed := _al_goal_split(al)[1])
           else "every success goal met") + ") |",
        "| AL sweeps, Figs 8A, 8B, 9A, 9B | done: below |",
        "| AN action namer + SOM, Figs 12, 15 | done: below |",
        "| observer: naming what it watches (beyond the paper) | "
        + ("done: below |" if result.get("observer") else "not in this run |"),
        "| trained modules | saved to `modules/`; `grounding_jax.load` (docs/robot.md) |",
        "", "## Target localizer", "",
        "| result | paper | ours |", "|---|---|---|",
        f"| test accuracy, H=50, n=20 | {PAPER['tl_test_acc']} | "
        f"{_pct(a['test_acc_mean'])}{sd(a)} |",
        f"| train accuracy, H=50, n=20 | {PAPER['tl_train_acc']} | "
        f"{_pct(a['train_acc_mean'])} |",
        f"| test RMSE per output unit | {PAPER['tl_test_rmse']} | {a['test_rmse_mean']:.3f} |",
        f"| train RMSE per output unit | {PAPER['tl_train_rmse']} | "
        f"{a['train_rmse_mean']:.3f} |",
        f"| test accuracy on patterns naming a shape / a colour | – | "
        f"{_pct(a['test_acc_shape_words_mean'])} / {_pct(a['test_acc_colour_words_mean'])} |",
        f"| best test accuracy over the run (chosen on the test set: optimistic) | – | "
        f"{_pct(a['best_epoch_test_acc_mean'])} |",
    ]
    if 50 in f6:
        lines.append(f"| Fig 6: test accuracy at H=50 | {PAPER['fig6_h50']} | "
                     f"{_pct(f6[50]['test_acc_mean'])}{sd(f6[50])} |")
    if 1 in f7:
        lines.append(f"| Fig 7: test accuracy without replication (n=1) | {PAPER['fig7_n1']} | "
                     f"{_pct(f7[1]['test_acc_mean'])}{sd(f7[1])} |")
    lines += [
        f"| Fig 7: best n | {PAPER['fig7_best']} | {best7['replication']} "
        f"({_pct(best7['test_acc_mean'])}) |",
        f"| noise 10%, fixed flips: train / test | {PAPER['noise_fixed']} | "
        f"{_pct(n['train_acc_mean'])} / "
        f"{_pct(n['test_acc_mean'])} |",
        f"| noise 10%, fresh flips every presentation: train / test | (not run) | "
        f"{_pct(nf['train_acc_mean'])} / {_pct(nf['test_acc_mean'])} |",
        "", "Fig 6 (hidden size) and Fig 7 (replication n):", "",
        "| H | " + " | ".join(str(h) for h in f6) + " |",
        "|---|" + "---|" * len(f6),
        "| test | " + " | ".join(_pct(p["test_acc_mean"]) for p in f6.values()) + " |",
        "", "| n | " + " | ".join(str(v) for v in f7) + " |",
        "|---|" + "---|" * len(f7),
        "| test | " + " | ".join(_pct(p["test_acc_mean"]) for p in f7.values()) + " |",
        "", "![accuracy](tl/accuracy.png) ![Fig 6](tl/fig6.png) ![Fig 7](tl/fig7.png)",
        "![noise](tl/noise.png) ![noise, fresh](tl/noise_fresh.png)", "",
        *_tl_reference_report(tl),
        *_sweeps_report(sweeps),
        *_al_report(al),
        *_an_report(an),
        *_beyond_report(result.get("beyond")),
        *_observer_report(result.get("observer")),
        *stage.report_sections(result),
        "", "## Scripted episodes (env check)", "",
        "| action | position | final reward | point L1 | target moved (cm) | others moved (cm) |",
        "|---|---|---|---|---|---|",
    ]
    for r in env_rows:
        lines.append(f"| {r['action']} | {r['position']} | {r['final_reward']:+.3f} | "
                     f"{r['final_point_l1']:.3f} | {r['target_moved_m'] * 100:.1f} | "
                     f"{r['others_moved_m'] * 100:.2f} |")
    lines += _speed_report(result, wall)
    if result.get("reruns"):  # parts re-run alone (train.py --only) after the whole run
        lines += ["", "Re-run alone after the whole run, with the keys it gives them (train.py "
                  "--only): " + ", ".join(result["reruns"]) + "; the other parts' results "
                  "are the whole run's."]
    if "libraries" in result:  # runs before this was recorded do not say
        lines += ["", "Run with " + ", ".join(f"{k} {v}" for k, v in result["libraries"].items())
                  + " (bit-for-bit reproduction from the same seed is only expected under the "
                  "same versions)."]
    return "\n".join(lines) + "\n"
