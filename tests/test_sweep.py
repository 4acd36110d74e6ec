"""Sweep runner: grid expansion, grouping, validation, sharding, Ray, resume, divergence."""

from __future__ import annotations

import dataclasses
import hashlib
import os
import pathlib
import re
import signal
import subprocess
import sys
import textwrap
import time

import jax
import numpy as np
import pytest

from grounding_jax import sweep
from grounding_jax.core.checkpoint import CheckpointError
from grounding_jax.learn import al, tl
from grounding_jax.paper import adapters, al_eval, al_experiments

ROOT = pathlib.Path(__file__).resolve().parents[1]
SWEEPS = sorted((ROOT / "sweeps").glob("*.toml"))

#: a tiny AL sweep: 4-unit networks, 10-step episodes
TINY_AL = {"module": "al", "seeds": 2, "chunk": 2, "metric": "td_error",
           "params": {"phase1_episodes": 2, "phase2_episodes": 2, "actor_hidden": 4,
                      "critic_hidden": 4, "episode_length": 10},
           "grid": {"critic_lr": [0.01, 0.02]}}
#: a tiny TL sweep: 2 hidden sizes x 2 replications x 2 learning rates, 2 epochs
TINY_TL = {"module": "tl", "seeds": 2, "metric": "test_acc",
           "params": {"epochs": 2, "eval_every": 1},
           "grid": {"hidden": [3, 4], "replication": [1, 2], "lr": [0.1, 0.2]}}


def _spec(base: dict, **changes) -> sweep.SweepSpec:
    data = {**base, "params": dict(base["params"]), "grid": dict(base["grid"])}
    if "grid" in changes:  # a new grid; its fields leave [params]
        data["grid"] = changes.pop("grid")
        data["params"] = {k: v for k, v in data["params"].items() if k not in data["grid"]}
    for k, v in changes.items():
        if k in sweep.TOP_KEYS:
            data[k] = v
        else:
            data["grid" if k in data["grid"] else "params"][k] = v
    return sweep.parse_spec(data)


def _metrics(folder: pathlib.Path) -> dict[str, np.ndarray]:
    with np.load(folder / "metrics.npz") as f:
        return {k: f[k] for k in f.files}


def _assert_same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def _tree_hash(folder: pathlib.Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        h.update(str(p.relative_to(folder)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


# ------------------------------------------------------------------------- expansion, grouping
def test_grid_expands_to_every_combination_and_groups_by_static_fields():
    spec = _spec(TINY_TL)
    pts = spec.points()
    assert len(pts) == 8
    assert {(p["hidden"], p["replication"], p["lr"]) for p in pts} == {
        (h, n, lr) for h in (3, 4) for n in (1, 2) for lr in (0.1, 0.2)}
    assert all(p["epochs"] == 2 and p["noise"] == 0.0 for p in pts)  # params + defaults
    groups = spec.groups()
    assert [g[0]["hidden"] for g in groups] == [3, 4]  # hidden is static; n and lr traced
    assert sorted(i for _, idx in groups for i in idx) == list(range(8))
    al_spec = _spec(TINY_AL, grid={"critic_lr": [0.01, 0.1], "episode_length": [8, 9, 10]})
    assert len(al_spec.points()) == 6 and len(al_spec.groups()) == 3
    # AL hidden sizes are traced (padded to the largest): one group, built at size 7
    al_spec = _spec(TINY_AL, grid={"critic_lr": [0.01, 0.1], "critic_hidden": [3, 5, 7]})
    assert len(al_spec.points()) == 6 and len(al_spec.groups()) == 1
    assert sweep.module_config(al_spec, al_spec.groups()[0][0]).learner.critic_hidden == 7
    # one field at a time around the base (each field's first value)
    axes = _spec(TINY_AL, design="axes", grid={"critic_lr": [0.01, 0.1, 0.3], "sigma": [0.1, 0.2]})
    assert [(p["critic_lr"], p["sigma"]) for p in axes.points()] == [
        (0.01, 0.1), (0.1, 0.1), (0.3, 0.1), (0.01, 0.2)]
    assert [sweep.point_label(axes, {"critic_lr": c, "sigma": s}) for c, s in
            ((0.01, 0.1), (0.3, 0.1))] == ["base", "critic_lr=0.3"]


@pytest.fixture
def trace_counter(monkeypatch):
    """Counts how often each module's training function is traced (= compiled)."""
    counts = {"al": 0, "tl": 0}
    make_steps, make_train = al.make_steps, tl.make_train

    def counted_steps(config):
        run = make_steps(config)

        def traced(*args):
            counts["al"] += 1
            return run(*args)

        return traced

    def counted_train(config, data=None):
        train = make_train(config, data)

        def traced(*args):
            counts["tl"] += 1
            return train(*args)

        return traced

    monkeypatch.setattr(al, "make_steps", counted_steps)
    monkeypatch.setattr(tl, "make_train", counted_train)
    al._batched_episodes.cache_clear()  # compiled runners of earlier tests would hide traces
    yield counts
    al._batched_episodes.cache_clear()


def test_one_compile_per_static_group(tmp_path, trace_counter):
    s = sweep.run(_spec(TINY_TL, name="tl"), tmp_path, show_progress=False)
    assert trace_counter["tl"] == 2  # 8 points, 2 hidden sizes
    assert len(s["points"]) == 8 and all(len(p["runs"]) == 2 for p in s["points"])
    spec = _spec(TINY_AL, name="al", figure="figx",
                 grid={"critic_lr": [0.01, 0.1], "episode_length": [8, 10],
                       "critic_hidden": [3, 5]})
    s = sweep.run(spec, tmp_path, show_progress=False)
    # 8 points, 2 episode lengths (static), hidden sizes traced; 2 chunks of the same shape
    assert trace_counter["al"] == 2
    assert len(s["groups"]) == 2
    # the same static config and batch shape again (another sweep): no new compile
    sweep.run(_spec(spec.to_json() | {"name": "al2", "params": {**spec.params, "sigma": 0.2}}),
              tmp_path, show_progress=False)
    assert trace_counter["al"] == 2
    for f in ("sweep.json", "runs.csv", "figx.png", "figx.json", "metrics.npz"):
        assert (tmp_path / "al" / f).is_file(), f


def test_chunks_have_one_shape_when_possible():
    assert sweep.chunk_stops(500, 50) == list(range(50, 501, 50))
    assert sweep.chunk_stops(200, 60) == [50, 100, 150, 200]  # largest divisor <= 60
    assert sweep.chunk_stops(101, 50) == [50, 100, 101]  # prime: a short last chunk


# --------------------------------------------------------------------------------- validation
@pytest.mark.parametrize("path", SWEEPS, ids=[p.stem for p in SWEEPS])
def test_every_sweep_file_validates(path):
    spec = sweep.load_spec(path)
    assert spec.seeds >= 5
    assert spec.figure.startswith("fig") or spec.name in ("al_tuning", "free_al_tuning",
                                                          "al_asha")
    if spec.search == "grid":
        assert len(spec.points()) >= 5
    else:
        assert spec.trials >= 5 and spec.holdout_seeds >= 5


def test_the_free_tuning_sweep_starts_from_the_shipped_settings():
    # its comment promises: each field's first value (and every fixed param) is beyond's
    from grounding_jax.paper import beyond

    spec = sweep.load_spec(ROOT / "sweeps" / "free_al_tuning.toml")
    shipped = {**beyond.FREE_TUNED, "actor_hidden": beyond.FREE_LEARNER.actor_hidden}
    base = {**spec.params, **{k: v[0] for k, v in spec.grid.items()}}
    for name, value in base.items():
        if name in shipped:
            assert value == pytest.approx(shipped[name]), name
    assert set(beyond.FREE_TUNED) - {"touch_bonus"} <= set(base)


def test_the_six_paper_sweeps_are_there():
    assert {p.stem for p in SWEEPS} == {"fig6_tl_hidden", "fig7_tl_replication",
                                        "fig8a_critic_lr", "fig8b_critic_hidden",
                                        "fig9a_actor_lr", "fig9b_actor_hidden", "al_tuning",
                                        "free_al_tuning", "al_asha"}


BAD = [
    ('module = "al"\nbogus = 1\n[grid]\ncritic_lr = [0.1]', "bogus"),
    ('module = "al"\n[grid]\ncritic_lr = ["fast"]', "grid.critic_lr"),
    ('module = "al"\nseeds = "five"\n[grid]\ncritic_lr = [0.1]', "seeds"),
    ('module = "al"\n[grid]\ncritic_lr = []', "grid.critic_lr"),
    ('module = "al"\n[grid]', "grid"),
    ('module = "al"\n[grid]\nactor_lr = [0.01, -0.001]', "grid.actor_lr"),
    ('module = "al"\n[params]\ncritic_lr = -1.0\n[grid]\nsigma = [0.1]', "params.critic_lr"),
    ('module = "al"\n[grid]\ncritic_hidden = [0, 20]', "grid.critic_hidden"),
    ('module = "tl"\n[grid]\nhidden = [0]', "grid.hidden"),
    ('module = "al"\n[params]\nlr = 0.1\n[grid]\nsigma = [0.1]', "params.lr"),
    ('module = "esn"\n[grid]\nn_res = [50]', "module"),
    ('[grid]\ncritic_lr = [0.1]', "module"),
    ('module = "al"\nmetric = "accuracy"\n[grid]\ncritic_lr = [0.1]', "metric"),
    ('module = "al"\n[params]\nbackend = "bullet"\n[grid]\ncritic_lr = [0.1]',
     "params.backend"),
    ('module = "al"\n[params]\nphase1_episodes = 0\nphase2_episodes = 0\n[grid]\n'
     'critic_lr = [0.1]', "phase1_episodes"),
    ('module = "al"\n[grid]\ncritic_lr = [0.1, 0.1]', "grid.critic_lr"),
    ('module = "al"\n[grid\n', "not valid TOML"),
    ('module = "tl"\neval_at = [2]\n[grid]\nlr = [0.1]', "eval_at"),
    ('module = "al"\ndesign = "random"\n[grid]\nsigma = [0.1]', "design"),
    ('module = "al"\neval_at = [0]\n[grid]\nsigma = [0.1]', "eval_at"),
    ('module = "al"\neval_at = [5000]\n[grid]\nsigma = [0.1]', "eval_at"),
    ('module = "al"\nmetric = "success_point"\n[grid]\nphase2_episodes = [10, 20]', "grid"),
]


@pytest.mark.parametrize("text,key", BAD, ids=[k for _, k in BAD])
def test_bad_sweep_files_name_the_key_and_file_before_compiling(tmp_path, text, key,
                                                                trace_counter):
    path = tmp_path / "bad.toml"
    path.write_text(text + "\n")
    with pytest.raises(sweep.SweepError) as e:
        sweep.load_spec(path)
    assert key in str(e.value) and str(path) in str(e.value)
    assert trace_counter == {"al": 0, "tl": 0}
    # the command line says the same and exits 2 without writing anything
    assert sweep.main([str(path), "--out", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()


def test_sweep_fields_and_validate_read_one_rule_table():
    """Each traced field the sweep takes from a dataclass is checked by that dataclass's own
    rule: the same words in both errors, from one table."""
    from grounding_jax.learn import cacla
    from grounding_jax.sim import env

    owners = [(cacla.HYPER_RULES, lambda n, v: cacla.validate(cacla.CaclaHyper(**{n: v}))),
              (al.HYPER_RULES, lambda n, v: al.validate(al.ALHyper(**{n: v}))),
              (env.PARAM_RULES, lambda n, v: env.EnvParams(**{n: v}).validate()),
              (tl.HYPER_RULES, lambda n, v: tl.validate(tl.TLHyper(**{n: v}), tl.TLConfig()))]
    checked = 0
    for module, fields in sweep.FIELDS.items():
        for name, field in fields.items():
            table, validate = next(((t, f) for t, f in owners if name in t), (None, None))
            if field.kind != "traced" or table is None:
                continue
            rule = table[name]
            assert (field.rule, field.type) == (rule.text, rule.type), name
            bad = rule.type(-1)
            if rule.holds(bad):  # e.g. the touch penalties: any finite number
                continue
            with pytest.raises(ValueError, match=rf"^{name}: must be {re.escape(rule.text)}"):
                validate(name, bad)
            with pytest.raises(sweep.SweepError,
                               match=rf"grid.{name}: must be {re.escape(rule.text)}"):
                sweep.parse_spec({"module": module, "grid": {name: [bad]}})
            checked += 1
    assert checked >= 15


def test_overrides_replace_grid_lists_and_params(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('module = "al"\nseeds = 5\n[grid]\ncritic_lr = [0.1, 0.2]\n')
    spec = sweep.load_spec(path, ["critic_lr=0.01,0.03,0.1", "seeds=2", "sigma=0.3",
                                  "backend=mjx"])
    assert spec.grid["critic_lr"] == [0.01, 0.03, 0.1]
    assert spec.seeds == 2 and spec.params["sigma"] == 0.3 and spec.params["backend"] == "mjx"
    with pytest.raises(sweep.SweepError, match="params.sigma"):
        sweep.load_spec(path, ["sigma=-1"])
    with pytest.raises(sweep.SweepError, match="executor"):
        sweep.run(spec, tmp_path, executor="slurm")


# ------------------------------------------------------------------------- divergence, devices
def test_a_diverging_point_is_flagged_and_the_others_are_unchanged(tmp_path):
    good = sweep.run(_spec(TINY_AL, name="good"), tmp_path, show_progress=False)
    bad = sweep.run(_spec(TINY_AL, name="bad", critic_lr=[0.01, 1e9]), tmp_path,
                    show_progress=False)
    assert bad["diverged_runs"] == 2 and good["diverged_runs"] == 0
    assert bad["points"][1]["diverged"] == [0, 1] and bad["points"][1]["mean"] is None
    assert bad["best"] == {"critic_lr": 0.01} and bad["lower_is_better"]  # td_error
    lower = min(good["points"], key=lambda p: p["mean"])["point"]
    assert good["best"] == lower
    assert bad["points"][0] == good["points"][0]  # same keys, same results, bit for bit
    m_good, m_bad = _metrics(tmp_path / "good"), _metrics(tmp_path / "bad")
    for k in m_good:
        if k != "finite":
            np.testing.assert_array_equal(m_bad[k][:2], m_good[k][:2], err_msg=k)
    assert not m_bad["finite"][2:].any()
    csv = (tmp_path / "bad" / "runs.csv").read_text().splitlines()
    assert csv[0] == "critic_lr,seed,td_error,diverged" and csv[-1].endswith(",1")


def test_success_rates_are_recorded_at_the_evaluation_episodes(tmp_path):
    spec = _spec(TINY_AL, name="succ", metric="success_mean", eval_at=[2],
                 grid={"action_scale": [0.2, 0.3]})
    assert spec.evaluations() == (2, 4)
    out = sweep.run(spec, tmp_path, show_progress=False)
    m = _metrics(tmp_path / "succ")
    names = [f"success_{k}" for k in al_eval.SUCCESS_METRICS]
    for k in names:
        assert m[k].shape == (4, 2) and np.all((m[k] >= 0) & (m[k] <= 1)), k
    np.testing.assert_allclose(m["success_mean"], np.mean([m[k] for k in names[:-1]], 0),
                               rtol=1e-6)
    assert out["evaluations"] == [2, 4] and not out["lower_is_better"]
    assert [p["runs"] for p in out["points"]] == m["success_mean"][:, -1].reshape(2, 2).tolist()
    assert out["success"][1]["point"] == {"action_scale": 0.3}
    assert out["success"][1]["rates"]["touch"]["runs"] == m["success_touch"][2:, -1].tolist()
    header = (tmp_path / "succ" / "runs.csv").read_text().splitlines()[0]
    assert header.startswith("action_scale,seed,success_mean,diverged,success_point")
    # the hook measured the run's own agent with its own action scale: row 3's agent, as the
    # sweep's checkpoint gives it back, evaluated directly with row 3's hyperparameters (that
    # a sweep's agents equal ones trained alone: test_al's chunk tests and the resume tests)
    found = sweep.trained_agents(spec, tmp_path)
    assert [f[0] for f in found] == [4, 4]
    hp = sweep.adapter("al").hyper([spec.points()[1]])
    cfg = sweep.module_config(spec, spec.groups()[0][0])
    agents = jax.tree.map(lambda x: x[1:], found[1][1])  # point 1, its second seed: row 3
    direct = al_eval.make_success_rates(cfg.env)(agents, jax.random.key(adapters.EVAL_SEED),
                                                        hp.env)
    for k in al_eval.SUCCESS_METRICS:
        assert direct[k][0] == m[f"success_{k}"][3, -1], k
    tail = al_experiments.point_tail(found[1][1], found[1][2].env, cfg.env, last=5,
                                     layouts=(0,))
    assert tail.shape == (2, 3, 5) and np.all(tail >= 0)


SUBPROCESS_SWEEP = textwrap.dedent("""
    import json, sys
    from grounding_jax import sweep
    spec = sweep.parse_spec(json.loads(sys.argv[1]))
    sweep.run(spec, sys.argv[2], resume=len(sys.argv) > 3, show_progress=False)
""")


def _sweep_process(spec: dict, out: pathlib.Path, *extra: str, env: dict | None = None,
                   wait: bool = True):
    import json

    cmd = [sys.executable, "-c", SUBPROCESS_SWEEP, json.dumps(spec), str(out), *extra]
    env = {**os.environ, "GROUNDING_JAX_THREADS": "2", **(env or {})}
    if not wait:
        return subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE)
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]


@pytest.mark.slow
def test_two_forced_host_devices_give_the_same_results(tmp_path):
    spec = {**TINY_AL, "seeds": 3}  # 6 runs, and 2 groups -> padding is exercised too
    spec = {**spec, "grid": {"critic_lr": [0.01], "episode_length": [8, 10]},
            "params": {k: v for k, v in spec["params"].items() if k != "episode_length"}}
    _sweep_process(spec, tmp_path / "one")
    _sweep_process(spec, tmp_path / "two",
                   env={"XLA_FLAGS": "--xla_force_host_platform_device_count=2"})
    one, two = (tmp_path / d / "sweep" for d in ("one", "two"))
    import json

    assert json.loads((two / "sweep.json").read_text())["devices"] == 2
    assert json.loads((one / "sweep.json").read_text())["devices"] == 1
    _assert_same(_metrics(one), _metrics(two))


@pytest.mark.slow
def test_ray_executor_on_a_local_cluster_matches_local(tmp_path):
    ray = pytest.importorskip("ray")
    spec = _spec(TINY_TL)
    sweep.run(spec, tmp_path / "local", show_progress=False)
    # a search's batches go to Ray the same way (here: a random search of the TL)
    searched = sweep.parse_spec({**TINY_TL, "grid": {}, "search": "random", "trials": 3,
                                 "name": "search", "holdout_seeds": 2,
                                 "space": {"lr": {"log": [0.05, 0.5]}}})
    local = sweep.run(searched, tmp_path / "local", show_progress=False)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        s = sweep.run(spec, tmp_path / "ray", executor="ray", show_progress=False)
        remote = sweep.run(searched, tmp_path / "ray", executor="ray", show_progress=False)
        # ASHA's brackets are Ray tasks
        brackets = _spec(TINY_AL, grid={}, search="asha", trials=4, name="asha",
                         space={"critic_lr": {"log": [0.01, 0.3]}},
                         asha={"eta": 2, "rungs": [2, 4], "brackets": 2})
        by_ray = sweep.run(brackets, tmp_path / "ray", executor="ray", show_progress=False)
    finally:
        ray.shutdown()
    assert s["executor"] == "ray" and remote["executor"] == "ray"
    _assert_same(_metrics(tmp_path / "local" / "sweep"), _metrics(tmp_path / "ray" / "sweep"))
    assert remote["trials"] == local["trials"] and remote["best"] == local["best"]
    assert remote["heldout"]["runs"] == local["heldout"]["runs"]
    here = sweep.run(brackets, tmp_path / "local", show_progress=False)
    assert by_ray["trials"] == here["trials"] and by_ray["best"] == here["best"]


# ------------------------------------------------------------------------------- checkpoints
def _steps(folder: pathlib.Path) -> list[int]:
    """Complete checkpoint steps (orbax writes into a temporary folder, then renames)."""
    return [int(p.name) for p in folder.iterdir() if p.name.isdigit()] if folder.exists() else []


def test_sigkill_mid_sweep_then_resume_matches_an_uninterrupted_run(tmp_path):
    spec = {**TINY_AL, "chunk": 1, "grid": {"critic_lr": [0.01]},
            "params": {**TINY_AL["params"], "phase2_episodes": 30}}
    _sweep_process(spec, tmp_path / "whole")
    proc = _sweep_process(spec, tmp_path / "cut", wait=False)
    steps = tmp_path / "cut" / "sweep" / "checkpoints" / "group0" / "steps"
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        done = _steps(steps)
        if done and max(done) >= 3:
            break
        time.sleep(0.02)
    assert proc.poll() is None, "the sweep ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed_at = max(_steps(steps))
    assert 3 <= killed_at < 32 and not (tmp_path / "cut" / "sweep" / "sweep.json").exists()
    _sweep_process(spec, tmp_path / "cut", "--resume")
    _assert_same(_metrics(tmp_path / "whole" / "sweep"), _metrics(tmp_path / "cut" / "sweep"))


def test_corrupt_or_mismatched_checkpoints_are_refused_and_kept(tmp_path):
    spec = _spec(TINY_AL, grid={"critic_lr": [0.01]})
    sweep.run(spec, tmp_path, show_progress=False)
    folder = tmp_path / "sweep" / "checkpoints"
    before = _tree_hash(folder)
    with pytest.raises(CheckpointError, match="--resume"):  # no silent overwrite
        sweep.run(spec, tmp_path, show_progress=False)
    with pytest.raises(CheckpointError, match="sigma.*--overwrite"):  # another config
        sweep.run(_spec(TINY_AL, grid={"critic_lr": [0.01]}, sigma=0.2), tmp_path,
                  resume=True, show_progress=False)
    assert _tree_hash(folder) == before
    whole = _metrics(tmp_path / "sweep")
    # damage every data file of the newest checkpoint: the resumed run says so, sets it
    # aside and goes on from the step before, to the same results
    steps = folder / "group0" / "steps"
    newest = max(steps.iterdir(), key=lambda p: int(p.name))
    for f in newest.rglob("*"):
        if f.is_file() and f.parent.name in ("d", "ocdbt.process_0"):
            f.write_bytes(b"garbage")
    damaged = _tree_hash(newest)
    with pytest.raises(CheckpointError, match=f"steps/{newest.name}: damaged"):
        sweep.trained_agents(spec, tmp_path)  # reading without resuming: refused
    sweep.run(spec, tmp_path, resume=True, show_progress=False)
    aside = list((folder / "group0" / "damaged").iterdir())
    assert len(aside) == 1 and _tree_hash(aside[0]) == damaged  # kept, not deleted
    _assert_same(_metrics(tmp_path / "sweep"), whole)
    (folder / "group0" / "config.json").write_text("{not json")
    with pytest.raises(CheckpointError, match="corrupt"):
        sweep.run(spec, tmp_path, resume=True, show_progress=False)
    # --overwrite starts over
    s = sweep.run(spec, tmp_path, overwrite=True, show_progress=False)
    assert s["diverged_runs"] == 0


def test_a_checkpoint_from_another_version_is_refused(tmp_path, monkeypatch):
    spec = _spec(TINY_TL, grid={"hidden": [3]})
    sweep.run(spec, tmp_path, show_progress=False)
    monkeypatch.setattr("grounding_jax.core._version.__version__", "9.9.9")
    with pytest.raises(CheckpointError, match="9.9.9"):
        sweep.run(spec, tmp_path, resume=True, show_progress=False)


@dataclasses.dataclass(frozen=True)
class _QuadConfig:
    steps: int


def _quad_train(cfg, keys, hp, spec, sharding, ck, progress):
    """Gradient descent on x**2 from a random start: the loss falls faster with a larger lr."""
    def one(key, lr):
        def body(x, _):
            return x - lr * 2 * x, None

        x, _ = jax.lax.scan(body, jax.random.normal(key), None, length=cfg.steps)
        return x, {"final_loss": x ** 2}

    params, metrics = jax.jit(jax.vmap(one))(keys, hp)
    if progress:
        progress(keys.shape[0] * cfg.steps)
    return metrics, params


def test_a_module_of_ones_own_runs_through_the_same_runner(tmp_path, monkeypatch):
    """The runner knows modules only through adapters: one registered here is checked,
    grouped, batched and summarised like the package's own."""
    import jax.numpy as jnp

    from grounding_jax.sweep import spec as spec_module

    quad = sweep.Adapter(
        fields={"steps": sweep.Field("static", int, 5, "an int >= 1", lambda v: v >= 1),
                "lr": sweep.Field("traced", float, 0.1, "in (0, 0.5]", lambda v: 0 < v <= 0.5)},
        metrics={"loss": "x**2 after the steps"}, unit="steps", length=lambda p: p["steps"],
        config=lambda points, static: _QuadConfig(static["steps"]),
        hyper=lambda rows: jnp.asarray([r["lr"] for r in rows], jnp.float32),
        train=_quad_train, lower_is_better=frozenset({"loss"}))
    sweep.adapters()  # the package's own first, then ours beside them
    monkeypatch.setitem(spec_module._REGISTRY, "quad", quad)
    with pytest.raises(sweep.SweepError, match=r"grid\.lr: must be in \(0, 0\.5\], got 0\.9"):
        sweep.parse_spec({"module": "quad", "grid": {"lr": [0.1, 0.9]}})
    spec = sweep.parse_spec({"module": "quad", "name": "quad", "seeds": 3,
                             "grid": {"lr": [0.05, 0.4], "steps": [2, 4]}})
    assert len(spec.groups()) == 2  # one compile per static steps value
    summary = sweep.run(spec, tmp_path, show_progress=False)
    assert summary["best"] == {"lr": 0.4, "steps": 4}
    means = {(p["point"]["lr"], p["point"]["steps"]): p["mean"] for p in summary["points"]}
    assert means[(0.4, 4)] < means[(0.4, 2)] < means[(0.05, 2)]
    assert (tmp_path / "quad" / "runs.csv").read_text().count("\n") == 1 + 4 * 3
    with pytest.raises(sweep.SweepError, match="unknown module 'nope'.*'quad'"):
        sweep.parse_spec({"module": "nope", "grid": {"lr": [0.1]}})
