"""Faults around what a run writes: a home that cannot be written, a grid too big for memory,
result sets interrupted while they replace the earlier set, a real full disk inside orbax, and
a symlinked checkpoints folder (the long randomised version: benchmarks/faults.py)."""

from __future__ import annotations

import contextlib
import json
import os
import pathlib
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import test_reliability

from grounding_jax import sweep
from grounding_jax.core import guard
from grounding_jax.core.io import Staged, recover_staged

#: the reliability tests' tiny AL sweep, shorter: 8 episodes
TINY = test_reliability.TINY.replace("phase2_episodes = 40", "phase2_episodes = 6")
assert "phase2_episodes = 6" in TINY


def _sweep(cwd: pathlib.Path, *args: str, env: dict | None = None
           ) -> subprocess.CompletedProcess:
    env = {**os.environ, "GROUNDING_JAX_THREADS": "2", **(env or {})}
    return subprocess.run([sys.executable, "-m", "grounding_jax.sweep", "tiny.toml", "--out",
                           "out", "--no-progress", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)


def _tiny(folder: pathlib.Path) -> pathlib.Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "tiny.toml").write_text(TINY)
    return folder


def _npz(folder: pathlib.Path) -> dict[str, np.ndarray]:
    with np.load(folder / "out" / "tiny" / "metrics.npz") as f:
        return {k: f[k] for k in f.files}


def _stray(folder: pathlib.Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(".*") if "staged" in p.name)


# -------------------------------------------------------------------------------- home
def test_a_home_that_cannot_be_written_moves_the_caches_with_one_warning(tmp_path):
    home = tmp_path / "home"
    home.write_text("")  # a file: nothing can be made under it, whoever runs the test
    env = {k: v for k, v in os.environ.items() if k not in ("GROUNDING_JAX_CACHE",
                                                            "MPLCONFIGDIR", "XDG_CONFIG_HOME")}
    env.update(HOME=str(home), TMPDIR=str(tmp_path / "tmp"), GROUNDING_JAX_THREADS="2")
    (tmp_path / "tmp").mkdir()
    w = _tiny(tmp_path / "w")
    r = subprocess.run([sys.executable, "-m", "grounding_jax.sweep", "tiny.toml", "--out",
                        "out", "--no-progress"], cwd=w, env=env, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Traceback" not in r.stderr
    warnings = [ln for ln in r.stderr.splitlines() if "warning" in ln.lower()]
    assert len(warnings) == 1, r.stderr
    assert "compilation cache" in warnings[0] and "GROUNDING_JAX_CACHE" in warnings[0]
    assert "matplotlib" in warnings[0]
    moved = tmp_path / "tmp" / f"grounding_jax-{os.getuid()}"
    assert any((moved / "jax").iterdir()), "the fallback cache holds no program"
    # switched off, the cache says nothing; matplotlib's folder still moves, in one line
    env["GROUNDING_JAX_CACHE"] = "off"
    r = subprocess.run([sys.executable, "-m", "grounding_jax.sweep", "tiny.toml", "--out",
                        "out", "--no-progress", "--overwrite"], cwd=w, env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = [ln for ln in r.stderr.splitlines() if "warning" in ln.lower()]
    assert len(lines) == 1 and "compilation cache" not in lines[0], r.stderr


def test_the_cache_falls_back_to_none_when_nothing_can_be_written(tmp_path):
    blocked = tmp_path / "file"
    blocked.write_text("")
    code = textwrap.dedent(f"""
        import tempfile
        import jax, grounding_jax as gj
        tempfile.tempdir = {str(blocked)!r}  # the temporary folder cannot be written either
        print(gj.enable_compilation_cache({str(blocked / 'cache')!r}))
        print(jax.config.jax_compilation_cache_dir)
    """)
    env = {**os.environ, "MPLCONFIGDIR": str(tmp_path)}
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["None", "None"], r.stdout
    assert r.stderr.count("warning:") == 1 and "running without one" in r.stderr, r.stderr


# -------------------------------------------------------------------------------- grids
def test_a_grid_beyond_memory_is_refused_before_anything_compiles(tmp_path):
    values = ", ".join(f"{1e-5 * (i + 1):.6g}" for i in range(300))
    (tmp_path / "huge.toml").write_text(textwrap.dedent(f"""
        module = "al"
        seeds = 5
        metric = "td_error"
        [grid]
        critic_lr = [{values}]
        actor_lr = [{values}]
    """))
    spec = sweep.load_spec(tmp_path / "huge.toml")
    with pytest.raises(sweep.SweepError) as e:
        sweep.run(spec, tmp_path / "out", show_progress=False)
    msg = str(e.value)
    assert msg.startswith("grid: 450000 runs") and "GB" in msg and "in parts of at most" in msg
    fits = int(msg.split("in parts of at most ")[1].split()[0])
    assert 0 < fits < 450000
    assert not (tmp_path / "out").exists()  # nothing written, not even the folder
    # a part of the size the message gives passes the check
    part = sweep.load_spec(tmp_path / "huge.toml", [
        "seeds=1", "actor_lr=0.001", "critic_lr=" + ",".join(
            f"{1e-5 * (i + 1):.6g}" for i in range(min(fits, 300)))])
    sweep.runner.check_size(part)


# ---------------------------------------------------------------------- result sets
def _three(folder: pathlib.Path, tag: str) -> Staged:
    staged = Staged(folder)
    for name in ("runs.csv", "sweep.json", "fig/metrics.txt"):
        (folder / name).parent.mkdir(exist_ok=True)
        staged.write_text(name, f"{tag} {name}\n")
    return staged


def _set(folder: pathlib.Path) -> set[str]:
    return {(folder / n).read_text().split()[0]
            for n in ("runs.csv", "sweep.json", "fig/metrics.txt")}


def test_sigterm_during_the_renames_leaves_the_new_set_whole(tmp_path, monkeypatch):
    _three(tmp_path, "old").commit()
    staged = _three(tmp_path, "new")
    real, calls = os.replace, []

    def replace(a, b):
        calls.append(b)
        if len(calls) == 2:  # the signal lands between two renames of the set
            os.kill(os.getpid(), signal.SIGTERM)
        real(a, b)

    monkeypatch.setattr(os, "replace", replace)
    with guard.handle_interrupts(), pytest.raises(guard.Interrupted):
        staged.commit()
    monkeypatch.setattr(os, "replace", real)
    assert _set(tmp_path) == {"new"} and _stray(tmp_path) == []


def test_a_writer_killed_mid_commit_has_its_commit_completed_by_the_next(tmp_path):
    _three(tmp_path, "old").commit()
    code = textwrap.dedent(f"""
        import os, pathlib, sys
        sys.path.insert(0, {str(pathlib.Path(__file__).parent)!r})
        from test_reliability_writes import _three
        staged = _three(pathlib.Path({str(tmp_path)!r}), "new")
        real, n = os.replace, [0]
        def replace(a, b):
            n[0] += 1
            if n[0] == 3:  # the journal and one file renamed: killed outright
                os.kill(os.getpid(), 9)
            real(a, b)
        os.replace = replace
        staged.commit()
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == -9, r.stderr
    assert _set(tmp_path) == {"old", "new"}  # the mix a kill leaves ...
    assert any(p.name.endswith(".journal") for p in tmp_path.iterdir())
    done = recover_staged(tmp_path)  # ... which the next writer completes
    assert done == ["completed an interrupted commit of 3 files"]
    assert _set(tmp_path) == {"new"} and _stray(tmp_path) == []


def test_staged_files_of_a_writer_that_died_before_its_commit_are_removed(tmp_path):
    _three(tmp_path, "old").commit()
    code = textwrap.dedent(f"""
        import os, pathlib, sys
        sys.path.insert(0, {str(pathlib.Path(__file__).parent)!r})
        from test_reliability_writes import _three
        _three(pathlib.Path({str(tmp_path)!r}), "new")
        os._exit(0)  # died with its files staged, never committed
    """)
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    assert len(_stray(tmp_path)) == 3
    mine = _three(tmp_path, "mine")  # this process's own staged files are never touched
    Staged(tmp_path)
    assert _stray(tmp_path) == sorted(p.name for p, _ in mine._pending)
    mine.discard()
    assert _set(tmp_path) == {"old"} and _stray(tmp_path) == []


def test_sigterm_while_the_sweep_writes_its_results_gives_one_set_or_the_other(tmp_path):
    w = _tiny(tmp_path / "w")
    assert _sweep(w).returncode == 0
    old = _npz(w)
    # the signal lands while the second result file is renamed into place
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(textwrap.dedent("""
        import os, signal
        real, n = os.replace, [0]
        def replace(a, b):
            if ".staged-" in str(a):
                n[0] += 1
                if n[0] == 2:
                    os.kill(os.getpid(), signal.SIGTERM)
            real(a, b)
        os.replace = replace
    """))
    r = _sweep(w, "--overwrite", "--seed", "5", env={"PYTHONPATH": str(hook)})
    assert r.returncode == 143, r.stderr[-2000:]
    assert "Traceback" not in r.stderr and "--resume" in r.stderr
    # the new set, every file of it: as a run with that seed writes them
    fresh = _tiny(tmp_path / "fresh")
    assert _sweep(fresh, "--seed", "5").returncode == 0
    new, want = _npz(w), _npz(fresh)
    assert not np.array_equal(new["td_error"], old["td_error"])
    for k in want:
        np.testing.assert_array_equal(new[k], want[k], err_msg=k)
    a, b = (f / "out" / "tiny" for f in (w, fresh))
    assert (a / "runs.csv").read_text() == (b / "runs.csv").read_text()
    for name in ("tiny.json", "sweep.json"):  # the figure's data and the summary
        got, ref = (json.loads((f / name).read_text()) for f in (a, b))
        got.pop("wall_s"), ref.pop("wall_s")
        assert got == ref, name
    assert _stray(w / "out") == []


# ---------------------------------------------------------------------------- disks
@contextlib.contextmanager
def _small_disk(where: pathlib.Path, size: str):
    where.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"a real full disk needs a small tmpfs mount, refused here "
                    f"({r.stderr.strip()[:80]}); the RLIMIT_FSIZE variant is in "
                    "test_reliability.py")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def test_a_real_full_disk_inside_orbax_gets_one_line_and_keeps_the_earlier_step(tmp_path):
    with _small_disk(tmp_path / "disk", "160k") as disk:
        w = _tiny(disk / "w")
        r = _sweep(w)
        assert r.returncode == 2, r.stderr[-3000:]
        assert r.stderr.strip().count("\n") == 0, r.stderr[-3000:]  # one line, no traceback
        assert r.stderr.startswith("error: ") and "no space left on the device" in r.stderr
        steps = w / "out" / "tiny" / "checkpoints" / "group0" / "steps"
        sealed = [p for p in steps.iterdir() if (p / "manifest.json").is_file()]
        assert sealed, "no earlier step kept"
    # the results of a finished run, then a full disk: one line, the results kept
    with _small_disk(tmp_path / "disk2", "600k") as disk:
        w = _tiny(disk / "w")
        assert _sweep(w).returncode == 0
        before = {p.name: p.read_bytes() for p in (w / "out" / "tiny").iterdir() if p.is_file()}
        subprocess.run(["dd", "if=/dev/zero", f"of={disk / 'fill'}", "bs=4k"],
                       capture_output=True)
        r = _sweep(w, "--resume")
        assert r.returncode == 2 and r.stderr.strip().count("\n") == 0, r.stderr[-3000:]
        assert "free some space" in r.stderr
        after = {p.name: p.read_bytes() for p in (w / "out" / "tiny").iterdir() if p.is_file()}
        assert after == before


# ---------------------------------------------------------------------------- links
def test_overwrite_with_a_symlinked_checkpoints_folder_keeps_the_link(tmp_path):
    w = _tiny(tmp_path / "w")
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    (scratch / "notes.txt").write_text("not the sweep's")
    (w / "out" / "tiny").mkdir(parents=True)
    (w / "out" / "tiny" / "checkpoints").symlink_to(scratch)
    assert _sweep(w).returncode == 0
    assert (scratch / "group0" / "steps").is_dir()
    r = _sweep(w, "--overwrite", "--seed", "3")
    assert r.returncode == 0, r.stderr[-2000:]
    assert (w / "out" / "tiny" / "checkpoints").is_symlink()
    assert (scratch / "notes.txt").read_text() == "not the sweep's"
    fresh = _tiny(tmp_path / "fresh")
    assert _sweep(fresh, "--seed", "3").returncode == 0
    for k, v in _npz(fresh).items():
        np.testing.assert_array_equal(_npz(w)[k], v, err_msg=k)
    # a link to something that is not a folder: refused in one line naming the link
    (w / "out" / "tiny" / "checkpoints").unlink()
    (w / "out" / "tiny" / "checkpoints").symlink_to(tmp_path / "missing")
    r = _sweep(w, "--overwrite")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-2000:]
    line = r.stderr.strip()
    assert line.startswith("error: overwrite:") and "checkpoints is a symbolic link" in line
