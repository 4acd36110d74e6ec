"""Faults and bad input: checksummed checkpoints, run identity, one writer, interrupts, full
disks, and clear one-line errors. Each test injects the fault and checks that nothing was lost,
mixed or silently changed (the long randomised version: benchmarks/faults.py)."""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import shlex
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grounding_jax as gj
from grounding_jax import sweep
from grounding_jax.core import guard
from grounding_jax.core.checkpoint import Checkpointer, CheckpointError, DamagedStepError
from grounding_jax.robot import trained
from grounding_jax.sim import rollout

ROOT = pathlib.Path(__file__).resolve().parents[1]
#: a tiny AL sweep file: 4-unit networks, 10-step episodes, a checkpoint every episode
TINY = textwrap.dedent("""
    module = "al"
    seeds = 2
    chunk = 1
    metric = "td_error"
    [params]
    phase1_episodes = 2
    phase2_episodes = 40
    actor_hidden = 4
    critic_hidden = 4
    episode_length = 10
    [grid]
    critic_lr = [0.01, 0.02]
""")


def _tree(folder: pathlib.Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name != ".lock"}


def _cli(*args: str, cwd: pathlib.Path, wait: bool = True, limit_bytes: int | None = None,
         module: str = "grounding_jax.sweep"):
    cmd = [sys.executable, "-m", module, *args] if module else [sys.executable, *args]
    env = {**os.environ, "GROUNDING_JAX_THREADS": "2"}
    if limit_bytes is not None:  # a disk that fills up: writes past the size fail (EFBIG)
        cmd = [sys.executable, "-c", LIMITED, str(limit_bytes), *cmd]
    if not wait:
        return subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


#: runs argv[2:] with files limited to argv[1] bytes (Python ignores SIGXFSZ, so a write past
#: the limit fails with EFBIG, as on a full disk)
LIMITED = ("import os, resource, sys; n = int(sys.argv[1]); "
           "resource.setrlimit(resource.RLIMIT_FSIZE, (n, n)); os.execv(sys.argv[2], sys.argv[2:])")


def _one_line_error(r: subprocess.CompletedProcess, *words: str) -> None:
    assert r.returncode == 2, r.stderr[-2000:]
    assert "Traceback" not in r.stderr and "Event loop is closed" not in r.stderr, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, r.stderr
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """The tiny sweep run whole through the CLI: its folder (read-only for the tests)."""
    root = tmp_path_factory.mktemp("whole")
    (root / "tiny.toml").write_text(TINY)
    r = _cli("tiny.toml", "--out", "out", "--no-progress", cwd=root)
    assert r.returncode == 0, r.stderr[-3000:]
    return root


def _copy(whole: pathlib.Path, tmp_path: pathlib.Path) -> pathlib.Path:
    shutil.copytree(whole, tmp_path / "w")
    return tmp_path / "w"


def _npz(folder: pathlib.Path) -> dict[str, np.ndarray]:
    with np.load(folder / "out" / "tiny" / "metrics.npz") as f:
        return {k: f[k] for k in f.files}


def _same_results(a: pathlib.Path, b: pathlib.Path) -> None:
    ma, mb = _npz(a), _npz(b)
    assert ma.keys() == mb.keys()
    for k in ma:
        np.testing.assert_array_equal(ma[k], mb[k], err_msg=k)


# --------------------------------------------------------------------------------- integrity
def test_every_file_of_a_step_flipped_truncated_or_deleted_is_refused_by_name(tmp_path):
    tree = {"w": jnp.arange(3000.0), "b": {"c": jnp.ones((40, 40))}, "k": jax.random.key(1)}
    with Checkpointer(tmp_path / "ck", "t", {"x": 1}) as ck:
        ck.save(1, tree)
    step = tmp_path / "ck" / "steps" / "1"
    files = sorted(p.relative_to(step).as_posix() for p in step.rglob("*") if p.is_file())
    assert "manifest.json" in files and len(files) >= 8
    named_arrays = set()
    for name in files:
        for fault in ("flip", "truncate", "delete"):
            bad = tmp_path / f"bad-{fault}"
            shutil.rmtree(bad, ignore_errors=True)
            shutil.copytree(tmp_path / "ck", bad)
            f = bad / "steps" / "1" / name
            data = bytearray(f.read_bytes())
            if fault == "flip":
                for i in range(4):
                    data[(len(data) * (2 * i + 1)) // 8] ^= 0x20
                f.write_bytes(bytes(data))
            elif fault == "truncate":
                f.write_bytes(bytes(data[: len(data) // 2]))
            else:
                f.unlink()
            with Checkpointer(bad, "t", {"x": 1}, read_only=True) as ck, pytest.raises(
                    DamagedStepError, match=r"steps/1") as e:
                ck.restore(1, tree)
            msg = str(e.value)
            assert name in msg or "manifest.json" in msg, (fault, name, msg)
            named_arrays |= {a for a in ("['w']", "['b']['c']", "['k']") if a in msg}
    assert named_arrays  # silent array damage is named by the array it hit


def test_edited_config_or_manifest_is_refused(tmp_path):
    tree = {"w": jnp.arange(10.0)}
    with Checkpointer(tmp_path / "ck", "t", {"x": 1}) as ck:
        ck.save(3, tree)
    cfg = tmp_path / "ck" / "config.json"
    cfg.write_text(cfg.read_text().replace('"x": 1', '"x": 2'))
    with Checkpointer(tmp_path / "ck", "t", {"x": 2}, read_only=True) as ck, pytest.raises(
            DamagedStepError, match="config.json: edited after step 3"):
        ck.restore(3, tree)
    cfg.write_text(cfg.read_text().replace('"x": 2', '"x": 1'))
    m = tmp_path / "ck" / "steps" / "3" / "manifest.json"
    m.write_text(m.read_text().replace('"step": 3', '"step": 3 '))  # same JSON, still whole
    with Checkpointer(tmp_path / "ck", "t", {"x": 1}) as ck:
        np.testing.assert_array_equal(ck.restore(3, tree)["w"], tree["w"])
    m.write_text(m.read_text().replace('"format": 1', '"format": 1, "note": 0'))
    with Checkpointer(tmp_path / "ck", "t", {"x": 1}) as ck, pytest.raises(
            DamagedStepError, match="manifest.json: damaged"):
        ck.restore(3, tree)


def test_resume_falls_back_to_the_newest_intact_step_and_says_so(whole, tmp_path):
    w = _copy(whole, tmp_path)
    steps = w / "out" / "tiny" / "checkpoints" / "group0" / "steps"
    newest = max(int(p.name) for p in steps.iterdir())
    data = next(p for p in (steps / str(newest)).rglob("*")
                if p.is_file() and p.parent.name == "d" and p.stat().st_size > 1000)
    b = bytearray(data.read_bytes())
    b[len(b) // 2] ^= 1
    data.write_bytes(bytes(b))
    # reading it (load-like) is refused; resuming falls back, says so, and ends the same
    spec = sweep.load_spec(w / "tiny.toml")
    with pytest.raises(DamagedStepError, match=f"steps/{newest}: damaged"):
        sweep.trained_agents(spec, w / "out")
    r = _cli("tiny.toml", "--out", "out", "--no-progress", "--resume", cwd=w)
    assert r.returncode == 0, r.stderr[-3000:]
    assert f"steps/{newest}: damaged" in r.stderr and f"resuming from step {newest - 1}" \
        in r.stderr and "Traceback" not in r.stderr
    _same_results(whole, w)
    assert len(list((w / "out" / "tiny" / "checkpoints" / "group0" / "damaged").iterdir())) == 1


def test_load_refuses_damaged_modules_and_leaves_the_folder_as_it_was(tmp_path):
    src = ROOT / "results" / "quick" / "modules"
    robot = gj.load(src)  # the committed modules are sealed, and load
    before = _tree(src)
    gj.load(src)
    assert _tree(src) == before  # loading writes nothing
    shutil.copytree(src, tmp_path / "m")
    data = max((p for p in (tmp_path / "m").rglob("*") if p.is_file() and p.parent.name == "d"),
               key=lambda p: p.stat().st_size)
    b = bytearray(data.read_bytes())
    for i in range(4):
        b[len(b) // 3 + 97 * i] ^= 4
    data.write_bytes(bytes(b))
    before = _tree(tmp_path / "m")
    with pytest.raises(DamagedStepError, match="steps/0: damaged") as e:
        gj.load(tmp_path / "m")
    assert "['free']" in str(e.value) or data.name in str(e.value)
    assert _tree(tmp_path / "m") == before  # nothing added (no steps/ folder, no config)
    assert robot.tl.localize(3, "red") in (0, 1, 2)


# ---------------------------------------------------------------------------------- identity
def test_resume_refuses_another_code_default_or_library_and_names_the_field(
        whole, tmp_path, monkeypatch):
    w = _copy(whole, tmp_path)
    spec = sweep.load_spec(w / "tiny.toml")
    folder = w / "out" / "tiny" / "checkpoints"
    before = _tree(folder)
    monkeypatch.setattr("grounding_jax.sweep.runner.code_fingerprint", lambda: "0" * 64)
    with pytest.raises(CheckpointError, match=r"fields that differ: code\b"):
        sweep.run(spec, w / "out", resume=True, show_progress=False)
    monkeypatch.undo()
    # a default the sweep file never names (sigma) changed in the code
    shipped = sweep.adapter("al")
    fields = dict(shipped.fields)
    fields["sigma"] = dataclasses.replace(fields["sigma"], default=0.2)
    sweep.register("al", dataclasses.replace(shipped, fields=fields))
    try:
        with pytest.raises(CheckpointError, match=r"points\[0\]\.sigma"):
            sweep.run(spec, w / "out", resume=True, show_progress=False)
    finally:
        sweep.register("al", shipped)
    monkeypatch.setattr("grounding_jax.sweep.runner.library_versions", lambda: {"jax": "0.0"})
    with pytest.raises(CheckpointError, match=r"libraries\.jax"):
        sweep.run(spec, w / "out", resume=True, show_progress=False)
    assert _tree(folder) == before


def test_checkpoints_without_a_readable_config_are_refused_and_never_given_one(whole, tmp_path):
    w = _copy(whole, tmp_path)
    cfg = w / "out" / "tiny" / "checkpoints" / "group0" / "config.json"
    cfg.unlink()
    r = _cli("tiny.toml", "--out", "out", "--resume", "--no-progress", "--set",
             "critic_lr=0.01,0.03", cwd=w)
    _one_line_error(r, "no config.json")
    assert not cfg.exists()
    cfg.write_bytes(bytes(range(256)))  # binary
    r = _cli("tiny.toml", "--out", "out", "--resume", "--no-progress", cwd=w)
    _one_line_error(r, "corrupt checkpoint config")
    assert cfg.read_bytes() == bytes(range(256))


# -------------------------------------------------------------------------------- one writer
def test_a_second_writer_is_refused_before_it_touches_anything(whole, tmp_path):
    w = _copy(whole, tmp_path)
    folder = w / "out" / "tiny"
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import sys, time
        from grounding_jax.core import guard
        with guard.folder_lock({str(folder)!r}, "a test holder"):
            print("held", flush=True)
            time.sleep(60)
    """)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        before = _tree(folder)
        r = _cli("tiny.toml", "--out", "out", "--overwrite", "--no-progress", cwd=w)
        _one_line_error(r, f"pid {holder.pid}", "another writer")
        assert _tree(folder) == before
        r = gj.load(ROOT / "results" / "quick" / "modules")
        with pytest.raises(guard.FolderBusyError, match=f"pid {holder.pid}"):
            trained.save(folder / "m", r.tl.params, r.tl.hyper, r.al.agent, r.al.config,
                         r.an.net, r.an.config, r.env_config)
        assert _tree(folder) == before
    finally:
        holder.kill()
        holder.wait()
    # the lock dies with its holder: the folder is free again at once
    with guard.folder_lock(folder):
        pass


# -------------------------------------------------------------------------------- interrupts
@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupt_keeps_the_newest_step_and_prints_the_resume_command(
        whole, tmp_path, sig, code):
    w = tmp_path / "w"
    w.mkdir()
    (w / "tiny.toml").write_text(TINY)
    proc = _cli("tiny.toml", "--out", "out", "--no-progress", cwd=w, wait=False)
    steps = w / "out" / "tiny" / "checkpoints" / "group0" / "steps"
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if steps.is_dir() and sum(p.name.isdigit() for p in steps.iterdir()) >= 2:
            break
        time.sleep(0.02)
    assert proc.poll() is None, "the sweep ended before it could be interrupted"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == code, err[-2000:]
    assert "Traceback" not in err and "Event loop is closed" not in err, err
    cmd = err.strip().splitlines()[-1].strip()
    assert cmd.endswith("--resume") and "grounding_jax.sweep tiny.toml" in cmd
    kept = max(int(p.name) for p in steps.iterdir() if p.name.isdigit())
    assert (steps / str(kept) / "manifest.json").is_file()  # sealed
    # a resume continues from there (not from scratch) and ends as an uninterrupted run
    r = subprocess.run([sys.executable, *shlex.split(cmd)[1:]], cwd=w, capture_output=True,
                       text=True, timeout=600,
                       env={**os.environ, "GROUNDING_JAX_THREADS": "2"})
    assert r.returncode == 0 and "nothing to resume" not in r.stderr, r.stderr[-2000:]
    assert f"note: resuming {steps.parent} from its step {kept}" in r.stderr, r.stderr
    _same_results(whole, w)


def test_resume_with_nothing_to_resume_says_so(tmp_path):
    (tmp_path / "tiny.toml").write_text(TINY.replace("phase2_episodes = 40",
                                                     "phase2_episodes = 1"))
    r = _cli("tiny.toml", "--out", "out", "--no-progress", "--resume", cwd=tmp_path)
    assert r.returncode == 0 and "nothing to resume" in r.stderr, r.stderr[-2000:]


# ------------------------------------------------------------------------------------- disk
def test_a_full_disk_keeps_the_earlier_results_and_checkpoints(whole, tmp_path):
    w = _copy(whole, tmp_path)
    folder = w / "out" / "tiny"
    before = _tree(folder)
    # results bigger than the disk allows: refused in one line, the earlier set kept whole
    r = _cli("tiny.toml", "--out", "out", "--no-progress", "--resume", cwd=w,
             limit_bytes=4000)
    _one_line_error(r, "cannot write the results", "kept")
    assert _tree(folder) == before
    # a checkpoint that cannot be written: the run stops with the step named
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    (fresh / "tiny.toml").write_text(TINY)
    r = _cli("tiny.toml", "--out", "out", "--no-progress", cwd=fresh, limit_bytes=2000)
    _one_line_error(r, "could not be written")
    steps = fresh / "out" / "tiny" / "checkpoints" / "group0" / "steps"
    assert not steps.exists() or not [p for p in steps.iterdir() if p.name.isdigit()
                                      and not (p / "manifest.json").exists()]


def test_a_full_disk_while_saving_modules_keeps_the_earlier_save(tmp_path):
    shutil.copytree(ROOT / "results" / "quick" / "modules", tmp_path / "modules")
    before = _tree(tmp_path / "modules")
    script = textwrap.dedent("""
        import sys
        import grounding_jax as gj
        from grounding_jax.robot import trained
        r = gj.load(sys.argv[1])
        try:
            trained.save(sys.argv[1], r.tl.params, r.tl.hyper, r.al.agent, r.al.config,
                         r.an.net, r.an.config, r.env_config)
        except Exception as e:
            print(type(e).__name__, e)
    """)
    r = _cli("-c", script, str(tmp_path / "modules"), cwd=tmp_path, module="",
             limit_bytes=20_000)
    assert "could not be written" in r.stdout or "File too large" in r.stdout, r.stdout
    assert _tree(tmp_path / "modules") == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [".lock", "modules"]


# ------------------------------------------------------------------------------ valid input
STATIC = {
    "al": {"phase1_episodes": [1, 2], "phase2_episodes": [1, 2], "episode_length": [5, 6],
           "substeps": [10, 5], "var": [False, True], "random_layout": [True, False],
           "placement": ["fixed", "random"]},
    "tl": {"hidden": [3, 4], "epochs": [2, 3], "eval_every": [1, 2],
           "noise_mode": ["fixed", "fresh"]},
}


@pytest.mark.parametrize("module", [pytest.param("al", marks=pytest.mark.slow), "tl"])
def test_every_static_field_works_as_a_two_value_grid(tmp_path, module):
    # one field changed at a time around the base: a group (compile) per field's second value;
    # the backend's second value (mjx) is left to test_backends' MJX runs (its compile alone
    # would double this test)
    assert set(STATIC[module]) | {"backend"} >= {
        k for k, f in sweep.FIELDS[module].items() if f.kind == "static"}
    params = {"actor_hidden": 4, "critic_hidden": 4} if module == "al" else {}
    spec = sweep.parse_spec({"module": module, "seeds": 1, "design": "axes", "chunk": 2,
                             "params": params, "grid": STATIC[module]})
    out = sweep.run(spec, tmp_path, show_progress=False)
    assert len(out["groups"]) == 1 + len(STATIC[module])
    assert out["diverged_runs"] == 0 and all(p["mean"] is not None for p in out["points"])
    for f in ("sweep.json", "runs.csv", "metrics.npz", "sweep.png"):
        assert (tmp_path / "sweep" / f).is_file(), f
    if module == "al":  # the runs of other lengths: each summarised over its own episodes
        m = np.load(tmp_path / "sweep" / "metrics.npz")["td_error"]
        lengths = [p["phase1_episodes"] + p["phase2_episodes"] for p in spec.points()]
        assert m.shape[1] == max(lengths)
        for row, n in enumerate(lengths):
            assert np.isfinite(m[row, :n]).all() and np.isnan(m[row, n:]).all()
            window = max(1, n // 10)
            assert out["points"][row]["runs"][0] == pytest.approx(
                float(m[row, n - window:n].mean()))


# ------------------------------------------------------------------------------ bad input
BAD_FILES = [
    (b'module = "al"\n# caf\xe9\n[grid]\nsigma = [0.1]\n', "not a UTF-8 text file"),
    (b'module = "al"\ngrid = [1, 2]\n', "grid: must be a table"),
    (b'module = "al"\nparams = "x"\n[grid]\nsigma = [0.1]\n', "params: must be a table"),
    (b'module = "al"\n[grid]\nactor_lr = [1e39]\n', "fit in float32"),
    (b'module = "al"\n[params]\ntouch_bonus = 1e39\n[grid]\nsigma = [0.1]\n',
     "fit in float32"),
]


@pytest.mark.parametrize("text,words", BAD_FILES, ids=[w for _, w in BAD_FILES])
def test_bad_sweep_files_get_one_line(tmp_path, text, words):
    (tmp_path / "bad.toml").write_bytes(text)
    with pytest.raises(sweep.SweepError, match=words):
        sweep.load_spec(tmp_path / "bad.toml")
    assert sweep.main([str(tmp_path / "bad.toml"), "--out", str(tmp_path / "o")]) == 2
    assert not (tmp_path / "o").exists()


def test_out_naming_a_file_gets_one_line(tmp_path):
    (tmp_path / "tiny.toml").write_text(TINY)
    (tmp_path / "afile").write_text("x")
    _one_line_error(_cli("tiny.toml", "--out", "afile", cwd=tmp_path), "afile")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "tiny").write_text("x")
    _one_line_error(_cli("tiny.toml", "--out", "out", cwd=tmp_path), "is a file")


@pytest.mark.parametrize("content,words", [("{broken", "not valid JSON"),
                                           ("{}", "not a train.py metrics file")])
def test_report_only_on_a_bad_metrics_file_gets_one_line(tmp_path, content, words):
    (tmp_path / "metrics.json").write_text(content)
    r = _cli(str(ROOT / "train.py"), "--report-only", "--out", str(tmp_path), cwd=tmp_path,
             module="")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert words in r.stderr and not (tmp_path / "REPORT.md").exists()


def test_env_flags_traced_values_it_could_not_check():
    env = gj.make_env("mujoco", episode_length=3)

    @jax.jit
    def episode(task, params):
        return rollout.run_episode(env, jax.random.key(0), task, lambda s: jnp.zeros(4),
                                   params)[1].metrics["invalid"]

    ok = gj.make_task("push", 1, 0)
    assert not episode(ok, gj.EnvParams()).any()
    assert episode(ok, gj.EnvParams(action_scale=jnp.float32(jnp.nan))).all()
    assert episode(ok, gj.EnvParams(touch_bonus=jnp.float32(jnp.inf))).all()
    outside = gj.Task(action=jnp.int32(7), position=jnp.int32(5), layout=jnp.int32(0))
    assert episode(outside, gj.EnvParams()).all()
    with pytest.raises(ValueError, match="action_scale"):  # outside jit: refused at once
        env.reset(jax.random.key(0), ok, gj.EnvParams(action_scale=float("nan")))
    robot = gj.load(ROOT / "results" / "quick" / "modules")
    with pytest.raises(ValueError, match="action_scale"):  # perform checks on the host
        robot.perform("push", "red", params=gj.EnvParams(action_scale=float("nan")))


def test_train_py_accepts_every_tl_epoch_count_and_refuses_impossible_ones(tmp_path):
    import train

    args = train.parse_args(["--set", "tl_epochs=9", "--out", str(tmp_path)])
    assert args.settings["tl_epochs"] == 9
    from grounding_jax.paper import tl_experiments

    res = tl_experiments.accuracy(jax.random.key(0), tmp_path, seeds=1, epochs=9)
    assert res["epochs"] == 9 and 0 <= res["test_acc_mean"] <= 1
    with pytest.raises(SystemExit):
        train.parse_args(["--set", "tl_epochs=0"])
    with pytest.raises(ValueError, match="eval_every: must be <= epochs"):
        from grounding_jax.learn import tl

        tl.TLConfig(epochs=5, eval_every=10)
    json.dumps(res)  # the result is plain JSON
