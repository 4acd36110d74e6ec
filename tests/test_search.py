"""Searches: the [space] table and its checks, random/Optuna/ASHA/PBT end to end on a tiny AL,
resumption after an interruption and after SIGKILL, the held-out check, the outputs."""

from __future__ import annotations

import csv
import io
import json
import math
import pathlib
import signal
import time

import numpy as np
import pytest
from test_sweep import TINY_AL, _sweep_process

from grounding_jax import sweep
from grounding_jax.core import checkpoint
from grounding_jax.sweep import search, space

#: a tiny AL search: 3 fields, 6 trials of 2 seeds, 6 episodes in chunks of 2
TINY = {"module": "al", "seeds": 2, "chunk": 2, "metric": "td_error", "trials": 6,
        "holdout_seeds": 2, "params": {**TINY_AL["params"], "phase2_episodes": 4},
        "space": {"critic_lr": {"log": [0.01, 0.3]}, "sigma": {"uniform": [0.05, 0.3]},
                  "gamma": {"choice": [0.0, 0.5]}}}
OPTIONS = {"random": {}, "optuna": {"optuna": {"batch": 3}},
           "asha": {"asha": {"eta": 2, "rungs": [2, 6], "batch": 3}},
           "pbt": {"pbt": {"interval": 2}}}


def _search(strategy: str, **changes) -> dict:
    """The tiny search with ``strategy`` (a field in a new [space] leaves [params])."""
    params = {k: v for k, v in TINY["params"].items() if k not in changes.get("space", {})}
    return {**TINY, "search": strategy, "name": strategy, **OPTIONS[strategy],
            "params": params, **changes}


def _stable(summary: dict) -> dict:
    """A search's summary without its wall times."""
    out = {k: v for k, v in summary.items() if k not in ("wall_s", "search_s")}
    if "heldout" in out:
        out["heldout"] = {k: v for k, v in out["heldout"].items() if k != "wall_s"}
    return out


@pytest.fixture(scope="module")
def searched(tmp_path_factory) -> tuple[pathlib.Path, dict[str, dict]]:
    """Every strategy run once, uninterrupted (the reference of the other tests)."""
    out = tmp_path_factory.mktemp("searches")
    return out, {s: sweep.run(sweep.parse_spec(_search(s)), out, show_progress=False)
                 for s in OPTIONS}


# ------------------------------------------------------------------------------------ checks
@pytest.mark.parametrize("changes, key, words", [
    ({"search": "bayes"}, "search", "accepted values"),
    ({"space": {"sigma": {"uniform": [0.3, 0.1]}}}, "space.sigma", "low < high"),
    ({"space": {"sigma": {"uniform": [0.1, 0.1]}}}, "space.sigma", "low < high"),
    ({"space": {"sigma": {"log": [0.0, 0.3]}}}, "space.sigma", "low > 0"),
    ({"space": {"gamma": {"choice": []}}}, "space.gamma", "non-empty"),
    ({"space": {"gamma": {"normal": [0, 1]}}}, "space.gamma", "uniform"),
    ({"space": {"gamma": {"uniform": [0.0, 2.0]}}}, "space.gamma", "must be"),
    ({"space": {"actor_hidden": {"uniform": [4, 8]}}}, "space.actor_hidden", "int, choice"),
    ({"space": {"episode_length": {"int": [5, 10]}}}, "space.episode_length", "static"),
    ({"space": {"nosuch": {"uniform": [0, 1]}}}, "space.nosuch", "unknown field"),
    ({"space": {}}, "space", "empty"),
    ({"grid": {"sigma": [0.1, 0.2]}}, "grid.sigma", "[space]"),
    ({"search": "asha", "asha": {"eta": 1}}, "asha.eta", ">= 2"),
    ({"search": "asha", "asha": {"rungs": [2, 4, 6, 8]}}, "asha.rungs", "only 3 chunks"),
    ({"search": "asha", "asha": {"rungs": [3, 6]}}, "asha.rungs", "multiple of chunk"),
    ({"search": "asha", "asha": {"rungs": [2, 4]}}, "asha.rungs", "last rung"),
    ({"search": "asha", "asha": {"speed": 2}}, "asha.speed", "accepted keys"),
    ({"search": "asha", "asha": {"rungs": [2, 6], "brackets": 3}}, "asha.brackets",
     "one bracket per rung"),
    ({"search": "pbt", "pbt": {"interval": 3}}, "pbt.interval", "multiple of chunk"),
    ({"search": "pbt", "pbt": {"interval": 6}}, "pbt.interval", "shorter than the run"),
    ({"search": "pbt", "pbt": {"fraction": 0.7}}, "pbt.fraction", "(0, 0.5]"),
    ({"search": "pbt", "asha": {"eta": 1}}, "asha.eta", ">= 2"),
    ({"search": "pbt", "optuna": 3}, "optuna", "expected dict"),
    ({"search": "optuna", "optuna": {"sampler": "grid"}}, "optuna.sampler", "tpe"),
    ({"trials": 0}, "trials", ">= 1"),
    ({"holdout_seeds": -1}, "holdout_seeds", ">= 0"),
])
def test_bad_search_keys_are_named_before_anything_compiles(changes, key, words):
    data = _search("random", **changes)
    for section in ("asha", "pbt", "optuna"):
        if section in data and data.get("search") != section and section not in changes:
            del data[section]
    with pytest.raises(sweep.SweepError) as e:
        sweep.parse_spec(data, "s.toml")
    assert f"s.toml: {key}:" in str(e.value) and words in str(e.value), str(e.value)


def test_a_module_trained_in_one_piece_is_refused_for_asha_and_pbt():
    data = {"module": "tl", "search": "asha", "seeds": 1, "params": {"epochs": 2, "eval_every": 1},
            "space": {"lr": {"log": [0.01, 0.3]}}}
    with pytest.raises(sweep.SweepError, match="search: 'asha' trains runs piece by piece"):
        sweep.parse_spec(data)
    assert sweep.parse_spec({**data, "search": "random"}).trials == 16


def test_a_grid_spec_is_written_as_before_searches_existed():
    spec = sweep.parse_spec({**TINY_AL, "name": "g"})
    assert not {"search", "trials", "holdout_seeds", "space"} & set(spec.to_json())
    assert sweep.parse_spec(spec.to_json()) == spec
    with pytest.raises(sweep.SweepError, match="trials: only for a search"):
        sweep.parse_spec({**TINY_AL, "trials": 3})


def test_overrides_set_the_strategy_and_its_tables(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text('module = "al"\nsearch = "random"\n[params]\nphase1_episodes = 2\n'
                 'phase2_episodes = 4\n[space]\nsigma = { uniform = [0.05, 0.3] }\n')
    spec = sweep.load_spec(f, ["search=asha", "asha.eta=2", "chunk=2", "trials=5",
                               "space.gamma={ choice = [0.0, 0.5] }", "holdout_seeds=3"])
    assert (spec.search, spec.asha["eta"], spec.asha["rungs"], spec.trials) == (
        "asha", 2, [4, 6], 5)
    assert list(spec.space) == ["sigma", "gamma"] and spec.holdout_seeds == 3
    from grounding_jax.sweep.__main__ import main

    assert main([str(f), "--set", "search=hyperband", "--no-progress"]) == 2


def test_draws_stay_in_their_ranges_and_obey_each_kind():
    spec = sweep.parse_spec(_search("random", space={
        "critic_lr": {"log": [0.001, 0.1]}, "sigma": {"uniform": [0.05, 0.3]},
        "actor_hidden": {"int": [4, 8]}, "gamma": {"choice": [0.0, 0.5]}}))
    rng = np.random.default_rng(0)
    pts = [space.sample(spec.space, rng) for _ in range(2000)]
    lr = np.asarray([p["critic_lr"] for p in pts])
    assert lr.min() >= 0.001 and lr.max() <= 0.1
    assert abs(np.median(np.log10(lr)) + 2) < 0.1  # log-uniform: the median at 10^-2
    assert {p["actor_hidden"] for p in pts} == {4, 5, 6, 7, 8}
    assert all(isinstance(p["actor_hidden"], int) for p in pts)
    assert {p["gamma"] for p in pts} == {0.0, 0.5}
    sig = np.asarray([p["sigma"] for p in pts])
    assert abs(np.median(sig) - 0.175) < 0.01
    for p in pts[:300]:
        q = space.perturb(spec.space, p, rng)
        assert 0.001 <= q["critic_lr"] <= 0.1 and 4 <= q["actor_hidden"] <= 8
        assert 0.05 <= q["sigma"] <= 0.3 and q["gamma"] in (0.0, 0.5)
    assert space.normalised(spec.space["critic_lr"], 0.01) == pytest.approx(0.5)


def test_lineages_follow_the_copies_back_in_time():
    trials = [search.Trial(i, {"x": i}, schedule=[(0, {"x": i})]) for i in range(3)]
    events = [{"units": 2, "member": 0, "donor": 1, "params": {"x": 10}},
              {"units": 4, "member": 2, "donor": 0, "params": {"x": 20}}]
    search._lineages(trials, events)
    assert trials[2].schedule == [(0, {"x": 1}), (2, {"x": 10}), (4, {"x": 20})]
    assert trials[0].schedule == [(0, {"x": 1}), (2, {"x": 10})]
    assert trials[1].schedule == [(0, {"x": 1})]


# -------------------------------------------------------------------------------- end to end
def test_every_strategy_writes_trials_a_figure_and_a_heldout_check(searched):
    out, runs = searched
    for name, s in runs.items():
        folder = out / name
        assert s["search"] == name and len(s["trials"]) == 6
        rows = list(csv.DictReader(io.StringIO((folder / "runs.csv").read_text())))
        assert len(rows) == 6 and {"trial", "critic_lr", "sigma", "gamma", "episodes",
                                   "rl_steps", "status", "reason", "td_error"} <= set(rows[0])
        assert (folder / f"{name}.png").is_file() and (folder / "sweep.json").is_file()
        best = s["best"]
        assert best["status"] == "completed"
        finals = [t["evaluations"][-1][1] for t in s["trials"] if t["status"] == "completed"]
        assert best["evaluations"][-1][1] == min(finals)  # td_error: lower is better
        assert s["heldout"]["seeds"] == 2 and len(s["heldout"]["runs"]) == 2
        assert math.isfinite(s["heldout"]["mean"])
        assert s["budget"]["rl_steps"] == sum(t["rl_steps"] for t in s["trials"]) > 0


def test_asha_trains_what_a_grid_trains_and_stops_the_bottom_of_each_rung(searched):
    _, runs = searched
    asha, rand = runs["asha"], runs["random"]
    # the same draws and keys: a trial trained piece by piece matches the whole-run batch
    for a, r in zip(asha["trials"], rand["trials"], strict=True):
        assert a["params"] == r["params"]
        assert a["evaluations"][0] == r["evaluations"][0]
        if a["status"] == "completed":
            assert a["evaluations"][-1] == r["evaluations"][-1] and a["units"] == 6
    first = {t["index"]: t["evaluations"][0][1] for t in asha["trials"]}
    go_on = [i for i, t in enumerate(asha["trials"]) if t["units"] == 6]
    stopped = [i for i in first if i not in go_on]
    assert len(go_on) == 3 and all("not in the top 1/2" in asha["trials"][i]["reason"]
                                   for i in stopped)
    assert max(first[i] for i in go_on if i >= 3) <= min(first[i] for i in stopped if i >= 3)
    assert asha["budget"]["rl_steps"] < rand["budget"]["rl_steps"]


def test_asha_brackets_hedge_and_train_what_the_others_train(searched, tmp_path):
    _, runs = searched
    s = sweep.run(sweep.parse_spec(_search("asha", asha={"eta": 2, "rungs": [2, 6],
                                                         "batch": 3, "brackets": 2})),
                  tmp_path, show_progress=False)
    first, second = s["trials"][0::2], s["trials"][1::2]
    assert all(t["status"] == "completed" for t in second)  # first ranked at the end
    assert sum(t["status"] == "stopped" for t in first) == 2  # 3 at rung 2: 1 goes on
    for t, r in zip(s["trials"], runs["random"]["trials"], strict=True):
        if t["status"] == "completed":
            assert t["evaluations"][-1] == r["evaluations"][-1]


def test_pbt_copies_the_top_into_the_bottom_and_records_the_schedule(searched):
    _, runs = searched
    pbt = runs["pbt"]
    assert all(t["units"] == 6 and len(t["evaluations"]) == 3 for t in pbt["trials"])
    sched = pbt["best"]["schedule"]
    assert sched[0][0] == 0 and [u for u, _ in sched] == sorted(u for u, _ in sched)
    # 6 members, fraction 0.25: one copy per ranking at episodes 2 and 4
    assert any(t["params"] != t["schedule"][0][1] for t in pbt["trials"])
    assert pbt["best"]["params"] == sched[-1][1]


def test_optuna_keeps_its_study_in_sqlite(searched):
    optuna = pytest.importorskip("optuna")
    out, runs = searched
    study = optuna.load_study(study_name="optuna",
                              storage=f"sqlite:///{out / 'optuna' / 'study.db'}")
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(done) == 6
    values = sorted(t.value for t in done)
    assert values == sorted(t["evaluations"][-1][1] for t in runs["optuna"]["trials"])


def test_optuna_takes_cma_es_and_a_changed_search_is_not_resumed(tmp_path):
    pytest.importorskip("cmaes")
    spec = sweep.parse_spec(_search("optuna", optuna={"sampler": "cmaes", "batch": 3},
                                    space={"critic_lr": {"log": [0.01, 0.3]},
                                           "sigma": {"uniform": [0.05, 0.3]}}))
    s = sweep.run(spec, tmp_path, show_progress=False)
    assert all(t["status"] == "completed" for t in s["trials"])
    other = sweep.parse_spec({**spec.to_json(), "space": {
        "critic_lr": {"log": [0.01, 0.1]}, "sigma": {"uniform": [0.05, 0.3]}}})
    with pytest.raises(checkpoint.CheckpointError, match="another config.*space"):
        sweep.run(other, tmp_path, resume=True, show_progress=False)


def test_a_diverging_trial_is_flagged_and_ranked_last(tmp_path):
    data = _search("asha", space={"critic_lr": {"choice": [0.01, 1e9]},
                                  "sigma": {"uniform": [0.05, 0.3]}})
    s = sweep.run(sweep.parse_spec(data), tmp_path, show_progress=False)
    bad = [t for t in s["trials"] if t["params"]["critic_lr"] == 1e9]
    assert bad and all(t["diverged"] and t["status"] == "stopped" for t in bad)
    assert s["diverged_trials"] == len(bad)
    assert s["best"]["params"]["critic_lr"] == 0.01


class _Cut(Exception):
    pass


@pytest.mark.parametrize("strategy", list(OPTIONS))
def test_an_interrupted_search_resumes_bit_identically(strategy, searched, tmp_path,
                                                       monkeypatch):
    _, runs = searched
    saves, real = [0], checkpoint.Checkpointer.save

    def cut_after_three(self, step, tree):
        real(self, step, tree)
        saves[0] += 1
        if saves[0] == 3:
            raise _Cut

    monkeypatch.setattr(checkpoint.Checkpointer, "save", cut_after_three)
    spec = sweep.parse_spec(_search(strategy))
    with pytest.raises(_Cut):
        sweep.run(spec, tmp_path, show_progress=False)
    assert not (tmp_path / strategy / "sweep.json").exists()
    with pytest.raises(checkpoint.CheckpointError, match="--resume"):
        sweep.run(spec, tmp_path, show_progress=False)
    s = sweep.run(spec, tmp_path, resume=True, show_progress=False)
    assert saves[0] > 3
    assert _stable(s) == _stable(runs[strategy])


@pytest.mark.slow
def test_sigkill_mid_asha_then_resume_matches_an_uninterrupted_run(searched, tmp_path):
    _, runs = searched
    data = _search("asha")
    proc = _sweep_process(data, tmp_path, wait=False)
    steps = tmp_path / "asha" / "checkpoints" / "population" / "steps"
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if steps.is_dir() and any(p.name.isdigit() and int(p.name) >= 2
                                  for p in steps.iterdir()):
            break
        time.sleep(0.02)
    assert proc.poll() is None, "the search ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (tmp_path / "asha" / "sweep.json").exists()
    _sweep_process(data, tmp_path, "--resume")
    s = json.loads((tmp_path / "asha" / "sweep.json").read_text())
    assert _stable(s) == json.loads(json.dumps(_stable(runs["asha"])))


def test_a_grid_can_be_checked_on_heldout_seeds(tmp_path):
    s = sweep.run(sweep.parse_spec({**TINY_AL, "holdout_seeds": 2}), tmp_path,
                  show_progress=False)
    assert s["heldout"]["seeds"] == 2 and math.isfinite(s["heldout"]["mean"])
    # fresh seeds: not the searched runs of the best point again
    best = next(p for p in s["points"] if p["point"] == s["best"])
    assert sorted(s["heldout"]["runs"]) != sorted(best["runs"])
