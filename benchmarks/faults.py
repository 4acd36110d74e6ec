"""Fault injection on tiny sweeps and saved modules: is anything lost, mixed or silently wrong?

Each fault is injected, then the run is resumed (sweeps) or loaded (modules); the outcome is
one of ``identical`` (the resumed run's metrics equal an uninterrupted run's, bit for bit),
``refused`` (a clear error, exit code 2 on the command line, the files left as they were) or
``WRONG`` (anything else: a silent difference, a traceback, a lost file). The goal is zero
``WRONG``.

- SIGKILL at ``--kills`` random moments of a sweep, then ``--resume``;
- SIGINT at ``--interrupts`` random moments (exit 130, the resume command printed), then it;
- each file of a sweep step in turn flipped (4 bytes), truncated (half) and deleted, then
  ``--resume`` (it must fall back to the intact step before and say so);
- each file of saved modules in turn flipped, truncated and deleted, then ``load``;
- the checkpoint config edited, deleted, made binary; the modules' config.json edited;
- a second writer (``--overwrite``) while a sweep runs;
- a full disk (``RLIMIT_FSIZE``) while writing checkpoints and while writing results;
- a home that cannot be written (a read-only tmpfs where the machine allows a mount) under the
  sweep and show CLIs;
- a 300 x 300 x 5-seed grid (refused before compiling);
- SIGTERM and SIGKILL at a random rename of a sweep's final write;
- a real full disk (ENOSPC on a small tmpfs) inside orbax and while writing results;
- ``--overwrite`` with ``checkpoints/`` a symbolic link; ``perform(" PUSH ", " RED ")``.

Usage:  python benchmarks/faults.py [--kills 20] [--interrupts 5] [--seed 0]
        [--only home,final_write --merge]   (some families; the others' rows kept)
Writes results/benchmarks/faults.json and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import os
import pathlib
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
import grounding_jax as gj  # noqa: E402
from grounding_jax.core.checkpoint import CheckpointError  # noqa: E402
from grounding_jax.core.io import (  # noqa: E402
    atomic_write_text,
    library_versions,
    recover_staged,
)

SWEEP = textwrap.dedent("""
    module = "al"
    seeds = 2
    chunk = 1
    metric = "td_error"
    [params]
    phase1_episodes = 2
    phase2_episodes = 30
    actor_hidden = 4
    critic_hidden = 4
    episode_length = 10
    [grid]
    critic_lr = [0.01, 0.02]
""")
EPISODES = 32  # phase1_episodes + phase2_episodes of SWEEP
CMD = [sys.executable, "-m", "grounding_jax.sweep", "s.toml", "--out", "out", "--no-progress"]


def _env() -> dict:
    return {**os.environ, "GROUNDING_JAX_THREADS": "2"}


#: runs argv[2:] with files limited to argv[1] bytes (a full disk: writes past it get EFBIG)
LIMITED = ("import os, resource, sys; n = int(sys.argv[1]); "
           "resource.setrlimit(resource.RLIMIT_FSIZE, (n, n)); os.execv(sys.argv[2], sys.argv[2:])")


def _run(folder: pathlib.Path, *extra: str, limit: int | None = None
         ) -> subprocess.CompletedProcess:
    cmd = [*CMD, *extra]
    if limit:
        cmd = [sys.executable, "-c", LIMITED, str(limit), *cmd]
    return subprocess.run(cmd, cwd=folder, env=_env(), capture_output=True, text=True,
                          timeout=900)


def _metrics(folder: pathlib.Path) -> dict:
    with np.load(folder / "out" / "s" / "metrics.npz") as f:
        return {k: f[k] for k in f.files}


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k], equal_nan=True) for k in a)


def _files(folder: pathlib.Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != ".lock"}


def _clean_error(r: subprocess.CompletedProcess) -> bool:
    return (r.returncode == 2 and "Traceback" not in r.stderr
            and "Event loop is closed" not in r.stderr
            and sum(ln.startswith("error:") for ln in r.stderr.splitlines()) == 1)


def _damage(path: pathlib.Path, fault: str) -> None:
    data = bytearray(path.read_bytes())
    if fault == "flip":
        for i in range(4):
            if data:
                data[(len(data) * (2 * i + 1)) // 8] ^= 0x20
        path.write_bytes(bytes(data))
    elif fault == "truncate":
        path.write_bytes(bytes(data[: len(data) // 2]))
    else:
        path.unlink()


def _fresh(root: pathlib.Path, name: str) -> pathlib.Path:
    d = root / name
    d.mkdir()
    (d / "s.toml").write_text(SWEEP)
    return d


def signals(root: pathlib.Path, whole: dict, n: int, sig: int, rng) -> list[dict]:
    """``n`` runs, each sent ``sig`` at a random moment, then resumed."""
    rows = []
    for i in range(n):
        d = _fresh(root, f"{signal.Signals(sig).name}-{i}")
        # a random moment of the run: while it starts (1 in 5), else after a random number of
        # checkpoints plus up to 60 ms (landing anywhere in an episode or a save)
        target = 0 if rng.random() < 0.2 else rng.randint(1, EPISODES - 1)
        jitter = rng.uniform(0.0, 0.06)
        steps = d / "out" / "s" / "checkpoints" / "group0" / "steps"
        proc = subprocess.Popen(CMD, cwd=d, env=_env(), stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
        t = time.perf_counter()
        if target == 0:
            time.sleep(rng.uniform(0.3, 3.0))
        else:
            while proc.poll() is None and not (steps.is_dir() and max(
                    (int(p.name) for p in steps.iterdir() if p.name.isdigit()),
                    default=0) >= target):
                time.sleep(0.005)
            time.sleep(jitter)
        at = time.perf_counter() - t
        ended_first = proc.poll() is not None
        sealed = sum((p / "manifest.json").is_file() for p in steps.iterdir()
                     if p.name.isdigit()) if steps.is_dir() else 0
        newest = max((int(p.name) for p in steps.iterdir() if p.name.isdigit()),
                     default=0) if steps.is_dir() else 0
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=300)
        clean = sig == signal.SIGKILL or ended_first or (
            proc.returncode == 128 + sig and "Traceback" not in err and "--resume" in err)
        r = _run(d, "--resume")
        ok = clean and r.returncode == 0 and _same(_metrics(d), whole)
        if not clean:
            print(err[-1500:], flush=True)
        rows.append({"fault": signal.Signals(sig).name, "at_s": round(at, 2),
                     "ended_before": ended_first, "episodes_done": newest,
                     "sealed_steps": sealed, "rc": proc.returncode,
                     "outcome": "identical" if ok else "WRONG"})
        print(f"{signal.Signals(sig).name} at {at:.2f} s (episode {newest}): "
              f"{rows[-1]['outcome']}", flush=True)
        shutil.rmtree(d)
    return rows


def sweep_files(root: pathlib.Path, done: pathlib.Path, whole: dict) -> list[dict]:
    """Each file of the newest step (and the group's config) flipped, truncated, deleted."""
    from grounding_jax import sweep

    group = done / "out" / "s" / "checkpoints" / "group0"
    newest = max(int(p.name) for p in (group / "steps").iterdir() if p.name.isdigit())
    names = sorted(p.relative_to(group).as_posix()
                   for p in (group / "steps" / str(newest)).rglob("*") if p.is_file())
    rows = []
    spec = sweep.load_spec(done / "s.toml")
    for name in [*names, "config.json"]:
        for fault in ("flip", "truncate", "delete"):
            d = root / "files"
            shutil.copytree(done, d)
            _damage(d / "out" / "s" / "checkpoints" / "group0" / name, fault)
            before = _files(d / "out" / "s" / "checkpoints")
            try:  # reading without resuming (as load does) must refuse
                sweep.trained_agents(spec, d / "out")
                read = "WRONG"
            except CheckpointError:
                read = "refused"
            r = _run(d, "--resume")
            if name == "config.json":
                ok = _clean_error(r) and _files(d / "out" / "s" / "checkpoints") == before
                outcome = "refused" if ok else "WRONG"
            else:
                ok = (r.returncode == 0 and "trying the step before it" in r.stderr
                      and "Traceback" not in r.stderr and _same(_metrics(d), whole))
                outcome = "identical" if ok else "WRONG"
            kind = "sweep group config.json" if name == "config.json" else "sweep step file"
            rows.append({"fault": f"{kind} {fault}", "file": name,
                         "read": read, "outcome": outcome if read == "refused" else "WRONG"})
            if rows[-1]["outcome"] == "WRONG":
                rows[-1].update(rc=r.returncode, stderr=r.stderr[-1500:])
            shutil.rmtree(d)
    return rows


def module_files(root: pathlib.Path) -> list[dict]:
    """Each file of the committed quick modules flipped, truncated, deleted; then load."""
    src = HERE.parent / "results" / "quick" / "modules"
    names = sorted(p.relative_to(src).as_posix() for p in src.rglob("*") if p.is_file())
    rows = []
    for name in names:
        for fault in ("flip", "truncate", "delete"):
            d = root / "modules"
            shutil.copytree(src, d)
            _damage(d / name, fault)
            before = _files(d)
            try:
                gj.load(d)
                outcome = "WRONG"
            except CheckpointError:
                outcome = "refused" if _files(d) == before else "WRONG"
            rows.append({"fault": f"modules file {fault}", "file": name, "outcome": outcome})
            shutil.rmtree(d)
    return rows


def configs(root: pathlib.Path, done: pathlib.Path) -> list[dict]:
    rows = []
    cases = {"edited (critic_lr)": lambda t: t.replace("0.02", "0.03"),
             "binary": lambda t: None, "deleted": lambda t: ""}
    for what, edit in cases.items():
        d = root / "cfg"
        shutil.copytree(done, d)
        cfg = d / "out" / "s" / "checkpoints" / "group0" / "config.json"
        new = edit(cfg.read_text())
        if new is None:
            cfg.write_bytes(bytes(range(256)))
        elif new == "":
            cfg.unlink()
        else:
            cfg.write_text(new)
        before = _files(d / "out" / "s" / "checkpoints")
        r = _run(d, "--resume", "--set", "critic_lr=0.01,0.03")
        ok = _clean_error(r) and _files(d / "out" / "s" / "checkpoints") == before
        rows.append({"fault": f"sweep config {what}", "outcome": "refused" if ok else "WRONG"})
        shutil.rmtree(d)
    d = root / "mcfg"
    shutil.copytree(HERE.parent / "results" / "quick" / "modules", d)
    cfg = json.loads((d / "config.json").read_text())
    cfg["config"]["tl"]["hidden"] = 7
    (d / "config.json").write_text(json.dumps(cfg))
    try:
        gj.load(d)
        outcome = "WRONG"
    except CheckpointError:
        outcome = "refused"
    rows.append({"fault": "modules config.json edited (TL hidden 50 -> 7)", "outcome": outcome})
    shutil.rmtree(d)
    return rows


def writers(root: pathlib.Path, whole: dict) -> list[dict]:
    d = _fresh(root, "writers")
    first = subprocess.Popen(CMD, cwd=d, env=_env(), stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
    while not (d / "out" / "s" / "checkpoints").exists() and first.poll() is None:
        time.sleep(0.05)
    second = _run(d, "--overwrite")
    first.communicate(timeout=600)
    ok = (_clean_error(second) and f"pid {first.pid}" in second.stderr
          and first.returncode == 0 and _same(_metrics(d), whole))
    shutil.rmtree(d)
    return [{"fault": "second writer (--overwrite) while a sweep runs",
             "outcome": "refused" if ok else "WRONG"}]


def disk(root: pathlib.Path, done: pathlib.Path, whole: dict) -> list[dict]:
    rows = []
    for limit, what in ((2_000, "checkpoint"), (30_000, "checkpoint"), (4_000, "results")):
        d = root / "disk"
        if what == "results":
            shutil.copytree(done, d)
        else:
            d = _fresh(root, "disk")
        before = _files(d / "out") if (d / "out").exists() else {}
        r = _run(d, *(["--resume"] if what == "results" else []), limit=limit)
        if what == "results":
            ok = _clean_error(r) and _files(d / "out") == before
        else:  # every step left is sealed; resuming without the limit ends identical
            steps = d / "out" / "s" / "checkpoints" / "group0" / "steps"
            sealed = all((p / "manifest.json").is_file() for p in steps.iterdir()
                         if p.name.isdigit()) if steps.exists() else True
            again = _run(d, "--resume")
            ok = (_clean_error(r) and sealed and again.returncode == 0
                  and _same(_metrics(d), whole))
        rows.append({"fault": f"disk full ({limit} B) while writing "
                              f"{'results' if what == 'results' else 'checkpoints'}",
                     "outcome": ("refused" if what == "results" else "identical") if ok
                     else "WRONG"})
        shutil.rmtree(d)
    return rows


@contextlib.contextmanager
def _mounted(where: pathlib.Path, options: str):
    """A tmpfs mounted at ``where`` with ``options`` (None where mounting is refused)."""
    where.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(where)],
                       capture_output=True, text=True)
    try:
        yield where if r.returncode == 0 else None
    finally:
        if r.returncode == 0:
            subprocess.run(["umount", "-l", str(where)], capture_output=True)


#: makes os.replace of a staged result file send ``SIG`` to its own process at the ``AT``-th
#: such rename (the final write of a sweep interrupted mid-way)
HOOK = textwrap.dedent("""
    import os, signal
    real, n = os.replace, [0]
    def replace(a, b):
        if ".staged-" in str(a):
            n[0] += 1
            if n[0] == int(os.environ["GJ_FAULT_AT"]):
                os.kill(os.getpid(), int(os.environ["GJ_FAULT_SIG"]))
        real(a, b)
    os.replace = replace
""")


def _result_set(folder: pathlib.Path) -> dict:
    """A sweep's result files (not its checkpoints), the JSON ones without their wall time."""
    out = {}
    for name, data in _files(folder / "out" / "s").items():
        if name.startswith("checkpoints/"):
            continue
        if name.endswith(".json"):
            data = json.loads(data)
            data.pop("wall_s", None)
        out[name] = data
    return out


def _stray(folder: pathlib.Path) -> list[pathlib.Path]:
    return [p for p in folder.rglob(".*") if "staged" in p.name]


def home(root: pathlib.Path, whole: dict) -> list[dict]:
    """The sweep and show CLIs with a home that cannot be written (a read-only tmpfs where
    the machine allows a mount, else a home that is a file): one warning line, same results."""
    d = _fresh(root, "home")
    rows = []
    with _mounted(root / "ro-home", "ro,size=64k") as ro:
        home_dir = ro or (root / "home-file")
        if ro is None:
            home_dir.write_text("")
        env = {k: v for k, v in _env().items() if k not in ("GROUNDING_JAX_CACHE",
                                                           "MPLCONFIGDIR")}
        env.update(HOME=str(home_dir), TMPDIR=str(root))
        what = "read-only tmpfs" if ro else "a file"
        r = subprocess.run(CMD, cwd=d, env=env, capture_output=True, text=True, timeout=900)
        warned = [ln for ln in r.stderr.splitlines() if "warning" in ln.lower()]
        ok = (r.returncode == 0 and "Traceback" not in r.stderr and len(warned) == 1
              and _same(_metrics(d), whole))
        rows.append({"fault": "HOME not writable: python -m grounding_jax.sweep",
                     "home": what, "outcome": "identical" if ok else "WRONG"})
        modules = HERE.parent / "results" / "quick" / "modules"
        r = subprocess.run([sys.executable, "-m", "grounding_jax.show", "push red", "--layout",
                            "3", "--modules", str(modules), "--out", str(d / "v.mp4")],
                           cwd=d, env=env, capture_output=True, text=True, timeout=900)
        warned = [ln for ln in r.stderr.splitlines() if "warning" in ln.lower()]
        ok = (r.returncode == 0 and "Traceback" not in r.stderr and len(warned) == 1
              and (d / "v.mp4").stat().st_size > 0)
        rows.append({"fault": "HOME not writable: python -m grounding_jax.show", "home": what,
                     "outcome": "identical" if ok else "WRONG"})
    shutil.rmtree(d)
    return rows


def huge_grid(root: pathlib.Path) -> list[dict]:
    """300 x 300 points x 5 seeds: refused before compiling, nothing written."""
    d = root / "huge"
    d.mkdir()
    values = ", ".join(f"{1e-5 * (i + 1):.6g}" for i in range(300))
    (d / "s.toml").write_text(f'module = "al"\nseeds = 5\nmetric = "td_error"\n[grid]\n'
                              f"critic_lr = [{values}]\nactor_lr = [{values}]\n")
    t = time.perf_counter()
    r = _run(d)
    ok = (_clean_error(r) and "in parts of at most" in r.stderr
          and not (d / "out").exists())
    shutil.rmtree(d)
    return [{"fault": "a grid beyond memory (450,000 runs)", "refused_in_s":
             round(time.perf_counter() - t, 1), "outcome": "refused" if ok else "WRONG"}]


def final_write(root: pathlib.Path, done: pathlib.Path, rng) -> list[dict]:
    """SIGTERM / SIGKILL at a random rename of the final write of an ``--overwrite`` run with
    a new seed: the old set or the new set, never a mix, and no staged file left once the
    next run has opened the folder."""
    new = _fresh(root, "seed7")
    assert _run(new, "--seed", "7").returncode == 0
    sets = {"old": _result_set(done), "new": _result_set(new)}
    hook = root / "hook"
    hook.mkdir(exist_ok=True)
    (hook / "sitecustomize.py").write_text(HOOK)
    rows = []
    for sig in (signal.SIGTERM, signal.SIGKILL, signal.SIGTERM, signal.SIGKILL):
        d = root / "final"
        shutil.copytree(done, d)
        at = rng.randint(1, 5)  # the journal, then the set's files
        env = {**_env(), "PYTHONPATH": str(hook), "GJ_FAULT_AT": str(at),
               "GJ_FAULT_SIG": str(int(sig))}
        r = subprocess.run([*CMD, "--overwrite", "--seed", "7"], cwd=d, env=env,
                           capture_output=True, text=True, timeout=900)
        clean = (r.returncode == 143 and "Traceback" not in r.stderr) if sig == \
            signal.SIGTERM else r.returncode == -signal.SIGKILL
        if sig == signal.SIGKILL:  # the next writer completes the interrupted commit
            recover_staged(d / "out" / "s")
        got = _result_set(d)
        which = [n for n, want in sets.items() if got == want]
        ok = clean and len(which) == 1 and not _stray(d / "out")
        rows.append({"fault": f"{signal.Signals(sig).name} during the final write",
                     "at_rename": at, "rc": r.returncode, "set": which[0] if which else "mixed",
                     "outcome": "identical" if ok else "WRONG"})
        shutil.rmtree(d)
    shutil.rmtree(new)
    return rows


def real_disk(root: pathlib.Path, whole: dict) -> list[dict]:
    """A real ENOSPC (a small tmpfs) inside orbax's checkpoint write and while writing the
    results: one line, no traceback, the earlier state kept, resumed identical elsewhere."""
    rows = []
    with _mounted(root / "small", "size=160k") as disk:
        if disk is None:
            return [{"fault": "ENOSPC (tmpfs)", "outcome": "skipped: mount refused"}]
        d = _fresh(disk, "ck")
        r = _run(d)
        steps = d / "out" / "s" / "checkpoints" / "group0" / "steps"
        sealed = [p for p in steps.iterdir() if (p / "manifest.json").is_file()]
        ok = (_clean_error(r) and r.stderr.strip().count("\n") == 0
              and "no space left" in r.stderr and bool(sealed))
        moved = root / "ck-moved"
        shutil.copytree(d, moved)
        again = _run(moved, "--resume")
        ok = ok and again.returncode == 0 and _same(_metrics(moved), whole)
        rows.append({"fault": "ENOSPC (tmpfs) inside orbax's checkpoint write",
                     "outcome": "identical" if ok else "WRONG"})
        if not ok:
            rows[-1].update(rc=r.returncode, stderr=r.stderr[-1500:],
                            resumed=again.stderr[-1500:])
        shutil.rmtree(moved)
    with _mounted(root / "small2", "size=600k") as disk:
        d = _fresh(disk, "res")
        assert _run(d).returncode == 0
        before = _files(d / "out")
        subprocess.run(["dd", "if=/dev/zero", f"of={disk / 'fill'}", "bs=4k"],
                       capture_output=True)
        r = _run(d, "--resume")
        ok = (_clean_error(r) and r.stderr.strip().count("\n") == 0
              and _files(d / "out") == before)
        rows.append({"fault": "ENOSPC (tmpfs) while writing the results",
                     "outcome": "refused" if ok else "WRONG"})
    return rows


def linked(root: pathlib.Path, done: pathlib.Path) -> list[dict]:
    """``--overwrite`` with ``checkpoints/`` a symbolic link: the link stays, the run works."""
    new = _fresh(root, "link-ref")
    assert _run(new, "--seed", "7").returncode == 0
    d = root / "link"
    shutil.copytree(done, d)
    scratch = root / "scratch"
    shutil.move(d / "out" / "s" / "checkpoints", scratch)
    (d / "out" / "s" / "checkpoints").symlink_to(scratch)
    r = _run(d, "--overwrite", "--seed", "7")
    ok = (r.returncode == 0 and (d / "out" / "s" / "checkpoints").is_symlink()
          and _same(_metrics(d), _metrics(new)))
    shutil.rmtree(d), shutil.rmtree(new), shutil.rmtree(scratch)
    return [{"fault": "--overwrite with checkpoints/ a symbolic link",
             "outcome": "identical" if ok else "WRONG"}]


def spoken() -> list[dict]:
    """perform(" RED ") is perform("red")."""
    robot = gj.load(HERE.parent / "results" / "quick" / "modules")
    a = robot.perform("push", "red", layout=3, steps=8)
    b = robot.perform(" PUSH ", " RED ", layout=3, steps=8)
    ok = a["named"] == b["named"] and np.array_equal(a["trajectory"].obs, b["trajectory"].obs)
    return [{"fault": 'perform(" PUSH ", " RED ")', "outcome": "identical" if ok else "WRONG"}]


FAMILIES = ("signals", "files", "modules", "configs", "writers", "disk", "home", "huge_grid",
            "final_write", "real_disk", "linked", "spoken")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kills", type=int, default=20)
    ap.add_argument("--interrupts", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(HERE.parent / "results" / "benchmarks" /
                                         "faults.json"))
    ap.add_argument("--only", default=",".join(FAMILIES),
                    help=f"comma-separated families of faults, of {FAMILIES}")
    ap.add_argument("--merge", action="store_true",
                    help="keep the other families' rows of an existing --out")
    args = ap.parse_args()
    only = [f for f in args.only.split(",") if f]
    bad = [f for f in only if f not in FAMILIES]
    if bad:
        ap.error(f"--only: unknown {bad}; accepted: {', '.join(FAMILIES)}")
    gj.enable_compilation_cache()
    rng = random.Random(args.seed)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = pathlib.Path(tmp)
        done = _fresh(root, "whole")
        t = time.perf_counter()
        r = _run(done)
        wall = time.perf_counter() - t
        assert r.returncode == 0, r.stderr[-3000:]
        whole = _metrics(done)
        run = {"signals": lambda: [*signals(root, whole, args.kills, signal.SIGKILL, rng),
                                   *signals(root, whole, args.interrupts, signal.SIGINT, rng)],
               "files": lambda: sweep_files(root, done, whole),
               "modules": lambda: module_files(root), "configs": lambda: configs(root, done),
               "writers": lambda: writers(root, whole), "disk": lambda: disk(root, done, whole),
               "home": lambda: home(root, whole), "huge_grid": lambda: huge_grid(root),
               "final_write": lambda: final_write(root, done, rng),
               "real_disk": lambda: real_disk(root, whole),
               "linked": lambda: linked(root, done), "spoken": spoken}
        rows = [{**row, "family": name} for name in only for row in run[name]()]
    if args.merge and pathlib.Path(args.out).is_file():  # the other families' rows kept
        kept = json.loads(pathlib.Path(args.out).read_text())["rows"]
        rows = [r for r in kept if r.get("family") not in only] + rows
    counts = collections.defaultdict(collections.Counter)
    for row in rows:
        counts[row["fault"]][row["outcome"]] += 1
    summary = [{"fault": f, "injected": sum(c.values()), **dict(c)} for f, c in counts.items()]
    kills = [r for r in rows if r["fault"] in ("SIGKILL", "SIGINT")]
    landed = {"before the first checkpoint": sum(r["episodes_done"] == 0 and not
                                                 r["ended_before"] for r in kills),
              "mid-run": sum(r["episodes_done"] > 0 and not r["ended_before"] for r in kills),
              "after the run ended": sum(r["ended_before"] for r in kills)}
    out = {"rows": rows, "summary": summary, "wrong": sum(r["outcome"] == "WRONG" for r in rows),
           "injected": len(rows), "signals_landed": landed, "whole_run_s": wall,
           "wall_s": time.perf_counter() - t0,
           "seed": args.seed, "libraries": library_versions()}
    atomic_write_text(pathlib.Path(args.out), json.dumps(out, indent=1) + "\n")
    print(table(out), end="")
    print(f"\nsignals landed: {landed}")
    print(f"\n{out['injected']} faults injected, {out['wrong']} wrong; wrote {args.out} "
          f"({out['wall_s']:.0f} s)")


def table(result: dict) -> str:
    """The Markdown table of a run (``results/benchmarks/faults.json``): per fault, how often
    it was injected, resumed bit-identical, refused, or gave a wrong result."""
    lines = ["| fault | injected | identical | refused | wrong |", "|---|---|---|---|---|"]
    for s in result["summary"]:
        lines.append(f"| {s['fault']} | {s['injected']} | {s.get('identical', 0)} | "
                     f"{s.get('refused', 0)} | {s.get('WRONG', 0)} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
