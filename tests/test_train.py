"""train.py end to end (the real quick profile, C backend), the README's examples, and its
argument checks."""

from __future__ import annotations

import importlib.metadata
import json
import pathlib
import re
import sys

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
import train  # noqa: E402
from grounding_jax.paper import beyond  # noqa: E402


@pytest.fixture(scope="module")
def quick(tmp_path_factory) -> pathlib.Path:
    """``python train.py`` (quick profile) into <tmp>/results/quick, run once for the module."""
    out = tmp_path_factory.mktemp("run") / "results" / "quick"
    assert train.main(["--out", str(out)]) == 0
    return out


def test_quick_profile_writes_report_metrics_and_every_figure(quick):
    tmp_path = quick
    data = json.loads((tmp_path / "metrics.json").read_text())
    assert data["profile"] == "quick" and data["settings"] == train.PROFILES["quick"]
    assert data["libraries"]["mujoco"] == importlib.metadata.version("mujoco")
    rows = {(r["action"], r["position"]): r for r in data["scripted_episodes"]}
    assert len(rows) == 6
    for pos in ("left", "middle", "right"):
        assert rows["point", pos]["final_point_l1"] < 0.01
        assert rows["push", pos]["target_moved_m"] > 0.02
        assert rows["push", pos]["others_moved_m"] < 1e-3
    tl = data["tl"]
    assert tl["accuracy"]["epochs"] == 200 and tl["accuracy"]["seeds"] == 3
    assert [p["hidden"] for p in tl["fig6"]["points"]] == [5, 20, 50]
    # 200 epochs of the quick profile already learn: far above chance (1/3)
    assert tl["accuracy"]["train_acc_mean"] > 0.95 and tl["accuracy"]["test_acc_mean"] > 0.5
    report = (tmp_path / "REPORT.md").read_text()
    assert "| test accuracy, H=50, n=20 | ~95% |" in report and "| push | left |" in report
    assert f"mujoco {data['libraries']['mujoco']}" in report
    # the speed figures other checks read: the whole command, its programs, its floor
    wall = data["wall_s"]
    own = data["beside"]  # run on their own thread, overlapping the parts in sequence
    assert own == ["tl"] and 0 < wall["tl"] < wall["total"]
    assert wall["total"] >= sum(v for k, v in wall.items() if k not in ("total", *own)) > 0
    assert "tl ran on its own thread beside the other parts" in report
    assert 50 < data["compiles"] == data["compiles_detail"]["programs"] < 2000
    phys = data["physics"]
    assert phys["rl_steps"] > 100_000 and phys["ceiling_rl_steps_per_s"] > 100
    assert 0 < data["physics_floor_s"] < wall["total"]
    assert f"Whole command: {wall['total']:.1f} s" in report
    assert f"XLA programs built: {data['compiles']} " in report and "Physics floor:" in report
    ref = tl["reference"]["learners"]
    assert ref["lookup"]["test_acc_mean"] > 0.9  # the same splits: the evidence is there
    assert "| lookup |" in report and "MLP 50 ReLU (Adam)" in report
    for name in ("accuracy", "reference", "fig6", "fig7", "noise", "noise_fresh"):
        assert (tmp_path / "tl" / f"{name}.png").stat().st_size > 1000
        assert f"tl/{name}.png" in report
    sweeps = data["sweeps"]
    assert list(sweeps) == list(train.AL_SWEEPS)
    for name, s in sweeps.items():
        fig = s["spec"]["figure"]
        assert (tmp_path / "sweeps" / name / f"{fig}.png").stat().st_size > 1000
        assert f"sweeps/{name}/{fig}.png" in report
        assert all(len(p["runs"]) == 2 for p in s["points"])  # sweep_seeds of the profile
        assert s["diverged_runs"] == 0
    assert [p["point"]["critic_lr"] for p in sweeps["fig8a_critic_lr"]["points"]] == [
        0.001, 0.01, 0.1]
    assert "| Fig 8A: critic_lr (td_error) |" in report
    al = data["al"]
    assert al["seeds"] == 3 and set(al["success"]) == {"300"}
    home, rand = al["final"]["home"]["by_action"], al["final"]["random_starts"]["by_action"]
    assert set(home) == {"point", "touch", "push"} and set(rand) == {"point"}  # Fig 11: point
    for rates in (home, rand):
        assert all(0.0 <= v <= 1.0 for v in rates.values())
    assert "| point, from home |" in report
    # the quick profile's AL must actually learn (it replaces a separate point-learning test):
    # 3 agents, 300 episodes; measured: point 89% of the episodes from home, 88% from random
    # starts (36 layouts, untrained agents: 0%), final L1 median 0.064 (untrained ~2.7)
    assert al["final"]["home"]["pooled"]["point"] >= 0.75
    assert al["final"]["random_starts"]["pooled"]["point"] >= 0.75
    assert al["final"]["home"]["point_l1_median"] < 0.1
    fig10 = np.asarray(al["fig10"]["reward_mean"])[:3]  # the point tasks, over the episode
    assert np.all(fig10[:, -1] > fig10[:, 0] + 0.3)
    for name in ("fig10", "fig11", "fig13", "fig14", "fig14_paper_schedule"):
        assert (tmp_path / "al" / f"{name}.png").stat().st_size > 1000
        assert f"al/{name}.png" in report
    an = data["an"]
    assert an["seeds"] == 3 and len(an["test"]["acc_per_seed"]) == 3
    assert all(0.0 <= an[k]["acc_mean"] <= 1.0 for k in ("train", "test", "test_random"))
    assert an["train"]["acc_mean"] > 0.9  # the readout fits its training sequences
    assert "| train accuracy | > 99% |" in report
    for name in ("fig15", "fig12"):
        assert (tmp_path / "an" / f"{name}.png").stat().st_size > 1000
        assert f"an/{name}.png" in report
    xy = data["beyond"]["tl_xy"]
    assert xy["seeds"] == 1 and xy["scenes"] == 6000 and xy["test_scenes"] == 1200
    # even the quick localizer (4000 updates) is far better than guessing the region's
    # centre (~6.5 cm median)
    assert xy["median_cm_median_seed"] < 3.0
    assert "## Beyond the paper" in report and "beyond/tl_xy.png" in report
    assert (tmp_path / "beyond" / "tl_xy.png").stat().st_size > 1000
    free = data["beyond"]["free"]
    assert free["seeds"] == 2 and set(free["success"]) == {"45", "90"}
    # the agent saved is chosen on validation placements, not the reported ones
    assert free["saved_agent"] == beyond.choose(free["validation"]) in (0, 1)
    assert len(free["validation"]["per_agent"]) == 2
    assert free["eyes"]["words"] == ["red", "green", "blue"]
    assert free["eyes_shape"]["words"] == ["box", "cylinder", "sphere"]
    for table in (free["final"], free["eyes"], free["eyes_shape"]):
        assert set(table["by_action"]) == {"point", "touch", "push"}
        assert all(0.0 <= v <= 1.0 for v in table["by_action"].values())
    assert len(free["moving"]["rows"]) == 2 * 4 * 2  # actions x speeds x robots
    assert free["an"]["sequences"] == 3 * 6 * 3
    assert free["an"]["train"]["acc_mean"] > 0.5  # the namer's readout fits its sequences
    for name in ("moving", "camera_strip"):
        assert (tmp_path / "beyond" / f"{name}.png").stat().st_size > 1000
        assert f"beyond/{name}.png" in report
    assert "### Acting anywhere" in report and "### Naming what it did" in report
    assert data["beyond"]["strip"]["named"][0] in ("point", "touch", "push")
    assert not list(tmp_path.rglob("*.tmp")) and not list(tmp_path.glob(".modules*"))
    csv = (tmp_path / "metrics.csv").read_text().splitlines()
    assert csv[0] == "key,value" and any(r.startswith("an.train.acc_mean,") for r in csv)
    # the report can be rebuilt from metrics.json alone, identically
    (tmp_path / "REPORT.md").unlink()
    assert train.main(["--out", str(tmp_path), "--report-only"]) == 0
    assert (tmp_path / "REPORT.md").read_text() == report
    assert train.main(["--out", str(tmp_path / "nothing"), "--report-only"]) == 2


def _readout_block(heading: str, page: str = "docs/robot.md") -> str:
    text = (ROOT / page).read_text()
    section = text[text.index(heading):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_example_loads_the_trained_robot_and_uses_it(quick, monkeypatch, capsys):
    import grounding_jax as gj

    code = _readout_block("## Loading and performing")
    assert 'gj.load("results/quick/modules")' in code
    monkeypatch.chdir(quick.parent.parent)  # where results/quick/ is
    exec(compile(code, "docs/robot.md", "exec"), {})
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] in ("0", "1", "2")
    robot = gj.load(quick / "modules")
    out = robot.perform("push", "red", layout=3)
    assert lines[-1] == " ".join(str(out[k]) for k in ("position", "true_position",
                                                         "final_reward", "named"))
    assert out["named"][0] in ("point", "touch", "push")


def test_the_perform_check_runs_every_saved_agent_on_the_same_episodes(quick, monkeypatch):
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import free_perform_check

    monkeypatch.chdir(quick.parent.parent)  # it writes results/benchmarks/ here
    res = free_perform_check.main(["--modules", str(quick / "modules"), "--episodes", "3",
                                   "--all-agents"])
    assert [r["action"] for r in res["rows"]] == ["point", "touch", "push"]
    assert all(len(v) == 2 for v in res["per_agent"].values())
    # the robot's own agent, run again through with_free_agent, does as the robot did
    for a in ("point", "touch", "push"):
        assert res["per_agent"][a][res["saved_agent"]] == res[f"success_{a}"]
    assert (quick.parent / "benchmarks" / "free_perform_check.json").exists()


def test_readme_beyond_example_runs_on_the_committed_modules(monkeypatch):
    code = _readout_block("**Acting anywhere", "docs/beyond.md")
    assert 'gj.load("results/paper/modules")' in code
    monkeypatch.chdir(ROOT)
    scope: dict = {}
    exec(compile(code, "docs/beyond.md", "exec"), scope)
    out = scope["out"]
    assert out["named"][0] in ("point", "touch", "push") and out["xy"].shape == (2,)
    assert scope["robot"].free is not None and scope["sliding"].velocity is not None


def test_the_saved_robot_watches_the_other_agents_and_reruns_alike(quick, capsys,
                                                                   monkeypatch):
    import dataclasses

    import grounding_jax as gj

    data = json.loads((quick / "metrics.json").read_text())
    obs = data["observer"]
    st = train.PROFILES["quick"]
    # every agent trained beside the saved one is watched: 3 - 1 paper, 2 - 1 free
    assert [a["agent"] for a in obs["paper"]["agents"]] == [1, 2]
    assert len(obs["free"]["agents"]) == st["free_seeds"] - 1
    for fam in ("paper", "free"):
        for a in obs[fam]["agents"]:
            assert a["n"] == st["observer_episodes"] and 0 <= a["acc"] <= 1
            assert sum(map(sum, a["confusion"])) == a["n"]
    assert obs["other_agent"] == float(np.median(
        [a["acc"] for f in ("paper", "free") for a in obs[f]["agents"]]))
    assert obs["frames"] is None  # the camera route is not built, and says so
    assert set(obs["scripted"]) == {"paper", "free"}
    # the scripted movements mostly do what they are named for, by the success rules (7 of 9
    # in this run: they do not depend on training)
    assert obs["scripted"]["paper"]["watched_success"] >= 0.5
    report = (quick / "REPORT.md").read_text()
    assert "## Beyond the paper: naming what it watches" in report
    assert "observer/observer.png" in report
    assert (quick / "observer" / "observer.png").stat().st_size > 1000
    robot = gj.load(quick / "modules")
    assert robot.n_agents == st["al_seeds"] and robot.saved_agent == 0
    np.testing.assert_array_equal(robot.al.agent.actor.w1, robot.agents.actor.w1[0])
    # --only observer: the same keys, the same results; the rest of the run kept
    assert train.main(["--out", str(quick), "--only", "observer"]) == 0
    after = json.loads((quick / "metrics.json").read_text())
    assert after["observer"] == obs and "observer_rerun" in after["wall_s"]
    assert "observer" in after["reruns"]
    assert after["al"] == data["al"] and after["beyond"] == data["beyond"]
    capsys.readouterr()
    assert train.main(["--out", str(quick), "--only", "observer", "--set", "tl_seeds=2"]) == 2
    assert "tl_seeds" in capsys.readouterr().err
    # modules saved before the AL agents were: nothing to watch, said before anything runs
    load = gj.load
    monkeypatch.setattr(gj, "load", lambda p: dataclasses.replace(load(p), agents=None))
    assert train.main(["--out", str(quick), "--only", "observer"]) == 2
    assert "holds no other AL agents" in capsys.readouterr().err
    monkeypatch.undo()
    assert json.loads((quick / "metrics.json").read_text()) == after  # nothing rewritten


def test_only_free_robot_reruns_that_part_with_the_whole_runs_keys(quick, capsys,
                                                                   monkeypatch):
    import grounding_jax as gj

    before = json.loads((quick / "metrics.json").read_text())
    paper_agent = gj.load(quick / "modules").al.agent
    assert train.main(["--out", str(quick), "--only", "free-robot"]) == 0
    after = json.loads((quick / "metrics.json").read_text())
    # the same keys: the free robot's results come out as the whole run made them
    untimed = lambda free: {k: v for k, v in free.items() if k != "train_s"}  # noqa: E731
    assert untimed(after["beyond"]["free"]) == untimed(before["beyond"]["free"])
    assert after["beyond"]["strip"] == before["beyond"]["strip"]
    assert "free-robot" in after["reruns"] and "free_robot_rerun" in after["wall_s"]
    assert {k: v for k, v in after.items() if k not in ("beyond", "wall_s", "reruns")} == \
        {k: v for k, v in before.items() if k not in ("beyond", "wall_s", "reruns")}
    robot = gj.load(quick / "modules")  # saved again: the paper's agents unchanged
    np.testing.assert_array_equal(robot.al.agent.actor.w1, paper_agent.actor.w1)
    assert robot.n_agents == 3 and robot.saved_agent == 0
    # every free agent saved, the robot's own the one chosen on validation placements
    saved = after["beyond"]["free"]["saved_agent"]
    assert robot.free.n_agents == 2 and robot.free.saved_agent == saved
    np.testing.assert_array_equal(robot.free.al.agent.actor.w1,
                                  robot.free.agents.actor.w1[saved])
    assert robot.free is not None and "free-robot" in (quick / "REPORT.md").read_text()
    # --only beyond trains the continuous TL again, with the whole run's keys, and hands it
    # to the free robot (stubbed: the real one has just been re-run above)
    handed = []

    def free_robot(key, out, st, backend, xy_params, cfg):
        handed.append(xy_params)
        f = robot.free
        return after["beyond"]["free"], {
            "xy_params": xy_params, "xy_config": cfg, "agent": f.al.agent, "agents": f.agents,
            "saved_agent": f.saved_agent, "al_config": f.al.config,
            "env_config": f.env_config, "params": f.params, "net": f.an.net,
            "esn_config": f.an.config}

    monkeypatch.setattr(train, "beyond_robot", free_robot)
    assert train.main(["--out", str(quick), "--only", "beyond"]) == 0
    again = json.loads((quick / "metrics.json").read_text())
    untimed_xy = lambda xy: {k: v for k, v in xy.items() if k != "wall_s"}  # noqa: E731
    assert untimed_xy(again["beyond"]["tl_xy"]) == untimed_xy(before["beyond"]["tl_xy"])
    assert {"beyond", "free-robot"} <= set(again["reruns"]) and "beyond_rerun" in again["wall_s"]
    (xy,) = handed  # the TL trained again is the whole run's, bit for bit
    np.testing.assert_array_equal(xy.w1, robot.free.xy_params.w1)
    np.testing.assert_array_equal(gj.load(quick / "modules").free.xy_params.w1, xy.w1)
    monkeypatch.undo()
    # refused before anything runs: a kept part's settings changed, or no run there
    capsys.readouterr()
    assert train.main(["--out", str(quick), "--only", "free-robot",
                       "--set", "al_seeds=4"]) == 2
    err = capsys.readouterr().err
    assert "al_seeds" in err and "free_seeds" in err  # what changed, and what may
    assert train.main(["--out", str(quick / "nothing"), "--only", "free-robot"]) == 2
    assert "needs a whole run" in capsys.readouterr().err


def test_the_random_starts_stage_judges_every_action_and_reruns_alike(quick, capsys,
                                                                      monkeypatch):
    import dataclasses

    from grounding_jax.paper import stage

    data = json.loads((quick / "metrics.json").read_text())
    entry = data["stages"]["random_starts"]
    assert entry["config"]["noise"] == [0.0, 0.15, 0.3, 0.5]
    res = entry["result"]
    assert res["agents"] == train.PROFILES["quick"]["al_seeds"] and res["tasks"] == 54
    assert list(res["levels"]) == ["0.0", "0.15", "0.3", "0.5"]
    for level in res["levels"].values():
        assert set(level["by_action"]) == {"point", "touch", "push"}
        assert all(0 <= v <= 1 for v in level["by_action"].values())
    # perform (its TL finding the object) with the judge's keys: where the TL found the
    # object, the episode succeeds or fails as the batched judge said
    rows = [r for rows in res["perform_checks"].values() for r in rows]
    assert len(rows) == 4 * 3 * 3
    assert all(r["judge"] == r["perform"] for r in rows if r["located"])
    assert data["wall_s"]["random_starts"] == entry["wall_s"]
    report = (quick / "REPORT.md").read_text()
    assert "## Beyond the paper: every action from random starts" in report
    assert "| ±0.3 |" in report
    # one stage again, with the whole run's keys: the same result, the rest kept
    assert train.main(["--out", str(quick), "--only", "random_starts"]) == 0
    after = json.loads((quick / "metrics.json").read_text())
    assert after["stages"]["random_starts"]["result"] == res
    assert "random_starts_rerun" in after["wall_s"] and "random_starts" in after["reruns"]
    # a change to a stage that --only does not run is refused, not ignored

    @dataclasses.dataclass(frozen=True)
    class Toy:
        x: int = 0

    toy = stage.Stage("toy", "Toy", Toy, run=lambda *a: {}, report=lambda *a: "")
    monkeypatch.setitem(stage._REGISTRY, "toy", toy)
    capsys.readouterr()
    assert train.main(["--out", str(quick), "--only", "random_starts",
                       "--set", "toy.x=1"]) == 2
    assert "toy" in capsys.readouterr().err


def test_the_touch_memory_stage_saves_a_robot_that_remembers(quick):
    import grounding_jax as gj
    from grounding_jax.sim import tasks

    data = json.loads((quick / "metrics.json").read_text())
    res = data["stages"]["touch_memory"]["result"]
    assert set(res["variants"]) == {"paper", "paper_memory_touch_pose_still_avoid_push_starts"}
    assert res["touch_still_penalty"] == 3.0 and res["push_other_penalty"] == -0.5
    for row in res["variants"].values():
        assert list(row["levels"]) == ["0.0", "0.3"]
        assert set(row["levels"]["0.0"]["touch_failures"]) == {
            "no_late_contact", "target_moved_3cm", "wrong_object_moved"}
    # the run's own agents are judged as the random-starts stage judges them: from home
    # (no draw in the start) the two stages' keys give the same episodes
    assert res["variants"]["paper"]["levels"]["0.0"]["by_action"] == \
        data["stages"]["random_starts"]["result"]["levels"]["0.0"]["by_action"]
    assert all(r["judge"] == r["perform"] for r in res["perform_checks"] if r["located"])
    robot = gj.load(quick / "touch_memory" / "modules")
    assert robot.env_config.task_set == "paper_memory_touch_pose" and robot.n_agents == 2
    out = robot.perform("touch", "red", layout=3)
    memory = tasks.get("paper_memory_touch_pose").obs_memory
    obs = np.asarray(out["trajectory"].obs)
    assert obs.shape == (100, res["saved_obs_size"]) and res["saved_obs_size"] == 27
    # carried from step to step: each step's memory starts with the joints of the step before
    # (until the episode ends: a finished episode's state stays as it ended)
    done = np.asarray(out["trajectory"].done)
    end = int(np.argmax(done)) + 1 if done.any() else len(done)
    assert end > 10
    np.testing.assert_array_equal(obs[1:end, memory][:, :4], obs[:end - 1, :4])
    assert "## Beyond the paper: touch with memory" in (quick / "REPORT.md").read_text()


def test_the_watch_frames_stage_saves_a_robot_that_names_rendered_frames(quick):
    import grounding_jax as gj

    data = json.loads((quick / "metrics.json").read_text())
    res = data["stages"]["watch_frames"]["result"]["families"]["paper"]
    assert res["episodes"] == 3 and len(res["rows"]) == 3 and res["own_episodes"] == 12
    for route in ("frames", "joints"):
        both = np.mean([r[route] == r["truth"] for r in res["rows"]])
        assert res[f"{route}_both"] == pytest.approx(both)
    # the episodes split by whether the act was done as told, the two parts' rates
    # recombining to the whole
    done = [r["done"] for r in res["rows"]]
    assert res["done"] == sum(done)
    for route in ("frames", "joints"):
        parts = [(res[f"{route}_both_{p}"] or 0.0) * n
                 for p, n in (("done", sum(done)), ("undone", len(done) - sum(done)))]
        assert sum(parts) == pytest.approx(res[f"{route}_both"] * len(done))
    robot = gj.load(quick / "watch_frames" / "modules")
    # the run's robot as it was saved, with its namer added
    assert set(robot.frames_namers) == {"paper"}
    assert robot.n_agents == gj.load(quick / "modules").n_agents
    assert all(r["agent"] in res["agents"] and r["agent"] != robot.saved_agent
               for r in res["rows"])  # other agents' episodes, never its own
    # loaded, it names frames the way the stage's namer did (the same arrays)
    assert robot.frames_namers["paper"].camera == "observer"  # the stage's default camera
    frames = gj.frames(robot.perform("push", "red", layout=3), width=120, height=80, every=5)
    assert robot.watch_frames(frames) in {
        (a, c) for a in ("point", "touch", "push") for c in ("red", "green", "blue")}
    with pytest.raises(ValueError, match="render them with .*camera='observer'"):
        robot.watch_frames(frames, camera="both")
    assert "## Beyond the paper: naming from the camera" in (quick / "REPORT.md").read_text()


def test_the_together_stage_compares_the_orders_on_the_same_seeds(quick):
    import grounding_jax as gj

    data = json.loads((quick / "metrics.json").read_text())
    res = data["stages"]["together"]["result"]
    seq, tog = (res["arms"][a] for a in ("sequence", "together"))
    rounds, agents = res["config"]["rounds"], res["config"]["agents"]
    # the TL reads no other module: trained in either order it ends the same, agent by agent
    assert seq["tl_test_acc"] == tog["tl_test_acc"] and len(seq["tl_test_acc"]) == agents
    for arm in (seq, tog):
        assert [len(arm["curves"][m]) for m in ("tl", "al", "an")] == [rounds] * 3
        assert arm["curves"]["an"][-1]["budget"] == 1.0
        for action in ("point", "touch", "push"):
            assert arm["summary"][action]["median"] == pytest.approx(
                float(np.median(arm["success"][action])))
    # in sequence the AL starts after the whole TL, together after its first piece
    assert seq["curves"]["al"][0]["budget"] > tog["curves"]["al"][0]["budget"]
    assert (quick / "together" / "together.png").stat().st_size > 0
    robot = gj.load(quick / "together" / "modules")
    out = robot.perform("point", "red", layout=3)
    assert out["position"] in ("left", "middle", "right") and len(out["named"]) == 2
    assert "## Beyond the paper: the modules learning together" in (
        quick / "REPORT.md").read_text()


@pytest.mark.parametrize("argv, field", [
    (["--set", "random_starts.nois=0.1"], "random_starts.nois"),
    (["--set", "random_starts.noise=2"], "noise"),
    (["--set", "nostage.x=1"], "nostage"),
    (["--profile", "huge"], "--profile"),
    (["--backend", "ode"], "--backend"),
    (["--set", "tl_epoch=5"], "tl_epoch"),
    (["--set", "tl_seeds=0"], "tl_seeds"),
    (["--set", "tl_hidden=a,b"], "tl_hidden"),
    (["--set", "al_phase1=0", "--set", "al_phase2=0"], "al_phase"),
    (["--set", "al_seeds=0"], "al_seeds"),
    (["--set", "free_an_scenes=2"], "free_an_scenes"),
    (["--set", "free_phase1=0", "--set", "free_phase2=0"], "free_phase"),
    (["--only", "tl"], "--only"),
])
def test_train_rejects_bad_arguments(argv, field, capsys):
    with pytest.raises(SystemExit):
        train.parse_args(argv)
    assert field in capsys.readouterr().err
