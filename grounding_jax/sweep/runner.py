"""The sweep runner: each static group of a sweep as one sharded, vmapped batch, with
checkpoints, resumption, and the results written together.

It knows the modules it trains only through their `Adapter`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import json
import os
import pathlib
import shutil
import sys
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core import guard
from grounding_jax.core.checkpoint import Checkpointer, CheckpointError
from grounding_jax.core.io import Staged, code_fingerprint, library_versions
from grounding_jax.sweep.batching import (
    MEMORY_SHARE,
    assemble,
    batch_sharding,
    finite_rows,
    gigabytes,
    memory_budget,
    pad_rows,
)
from grounding_jax.sweep.spec import SweepError, SweepSpec, adapter, module_config
from grounding_jax.sweep.summary import csv_text, summaries, write_sweep_figure

EXECUTORS = ("local", "ray")
#: errors of a full disk (or quota)
_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
#: what the held-out key of a grid is folded from the sweep's key with
HOLDOUT_STREAM = 0x484F4C44


def run_group(spec: SweepSpec, group: int, run_keys: np.ndarray, out: pathlib.Path | None,
              resume: bool = False, progress: Callable[[int], None] | None = None,
              config: Any = None) -> dict[str, np.ndarray]:
    """Train one static group: its points x seeds as one sharded, vmapped batch.

    Args:
        spec: the sweep.
        group: index into ``spec.groups()``.
        run_keys: raw key data ``[points * seeds, ...]`` of the *whole* sweep (row
            ``point * seeds + seed``).
        out: the sweep's output folder (checkpoints under ``out/checkpoints``); None: none.
        resume: continue from this group's checkpoint if there is one.
        progress: called with the number of run-episodes (AL) or run-epochs (TL) just done.
        config: the group's static config, if not the one its points need (a search builds
            one that holds its whole space, so that every batch has one shape).

    Returns:
        ``metrics`` (each ``[rows, ...]``), ``finite`` ``[rows]`` and ``rows`` (indices into
        points x seeds).
    """
    static, _ = spec.groups()[group]
    rows = _group_rows(spec, group)
    points = spec.points()
    batch_rows = [points[r // spec.seeds] for r in rows]
    cfg = module_config(spec, static) if config is None else config
    keys = jax.random.wrap_key_data(jnp.asarray(run_keys[rows]))
    hp = adapter(spec.module).hyper(batch_rows)
    sharding, pad = batch_sharding(len(rows))
    keys, hp = pad_rows((keys, hp), pad)
    ck = None
    if out is not None:
        try:
            ck = _checkpointer(spec, group, run_keys, out, config=config)
        except CheckpointError as e:
            raise CheckpointError(f"{e}; --overwrite deletes this sweep's checkpoints and "
                                  "starts over") from None
        if ck.latest_step() is not None and not resume:
            ck.close()
            raise CheckpointError(f"{ck.directory}: holds a checkpoint of an earlier run; "
                                  "pass --resume to continue it or --overwrite to start over")
    report = None
    if progress is not None:  # count the real runs, not the padding rows
        def report(units: int) -> None:
            progress(units * len(rows) // (len(rows) + pad))
    try:
        metrics, params = adapter(spec.module).train(cfg, keys, hp, spec, sharding, ck,
                                                      report)
    finally:
        if ck is not None:
            ck.close()
    metrics = jax.tree.map(lambda x: np.asarray(x)[: len(rows)], metrics)
    finite = (finite_rows(jax.tree.map(lambda x: np.asarray(x)[: len(rows)], params),
                           len(rows)) & finite_rows(metrics, len(rows)))
    return {"metrics": metrics, "finite": finite, "rows": rows}


def _group_rows(spec: SweepSpec, group: int) -> np.ndarray:
    """The runs of a static group: indices into points x seeds (row ``point * seeds + seed``)."""
    return np.asarray([p * spec.seeds + s for p in spec.groups()[group][1]
                       for s in range(spec.seeds)])


def split_run_keys(spec: SweepSpec, key: jax.Array | None = None) -> np.ndarray:
    """Raw key data of every run: ``key`` (default ``jax.random.key(spec.seed)``) split once
    into points x seeds."""
    key = jax.random.key(spec.seed) if key is None else key
    return np.asarray(jax.random.key_data(jax.random.split(key, len(spec.points())
                                                           * spec.seeds)))


def identity(spec: SweepSpec, group: int, run_keys: np.ndarray, config: Any = None) -> dict:
    """What a static group's checkpoints belong to: the spec, every point's whole assignment
    (defaults included), the group's static config and the traced values of each of its runs
    (every field of the hyperparameter pytree, defaults included), the run keys, the device
    count, the code's fingerprint and the library versions. A resumed run must match it
    exactly (``Checkpointer`` names the fields that differ)."""
    static, idx = spec.groups()[group]
    rows = _group_rows(spec, group)
    points = spec.points()
    hp = adapter(spec.module).hyper([points[r // spec.seeds] for r in rows])
    traced = {jax.tree_util.keystr(path): np.asarray(leaf).tolist()
              for path, leaf in jax.tree_util.tree_flatten_with_path(hp)[0]}
    cfg = module_config(spec, static) if config is None else config
    return {"spec": spec.to_json(), "group": group, "static": static,
            "points": [points[i] for i in idx],
            "config": json.loads(json.dumps(dataclasses.asdict(cfg), default=repr)),
            "traced": traced, "rows": rows.tolist(), "devices": jax.local_device_count(),
            "run_keys": hashlib.sha256(run_keys.tobytes()).hexdigest(),
            "code": code_fingerprint(), "libraries": library_versions()}


def _checkpointer(spec: SweepSpec, group: int, run_keys: np.ndarray, out: pathlib.Path,
                  read_only: bool = False, config: Any = None) -> Checkpointer:
    # a reader takes the arrays as they were trained, by whatever code; a resumed run must
    # continue with the code and libraries it began with
    return Checkpointer(out / "checkpoints" / f"group{group}", f"sweep-{spec.module}",
                        identity(spec, group, run_keys, config), read_only=read_only,
                        ignore=("code", "libraries") if read_only else ())


def trained_agents(spec: SweepSpec, out: str | pathlib.Path = "results/sweeps",
                   seed: int | None = None, key: jax.Array | None = None):
    """The trained agents of a finished (or interrupted) sweep, from its checkpoints (a
    module whose adapter can read them back: ``saved_like``, as the AL's).

    Args:
        spec: the sweep, as it was run.
        out: the parent folder it was run under.
        seed: the seed it was run with, if not ``spec.seed``.
        key: the key it was run with, if `run` was given one.

    Returns:
        A list with, per point (``spec.points()`` order): ``(episode, agents [seeds],
        hp)`` -- the latest checkpointed episode of its group, its runs' agents and their
        hyperparameters (the adapter's, e.g. ``al.ALHyper``; one row per run).
    """
    found_adapter = adapter(spec.module)
    if found_adapter.saved_like is None:
        raise SweepError(f"{spec.source}: module: trained_agents reads sweeps whose adapter "
                         f"can read agents back (AL), not {spec.module!r}")
    spec = spec if seed is None else dataclasses.replace(spec, seed=seed)
    n_pts = len(spec.points())
    run_keys = split_run_keys(spec, key)
    folder = pathlib.Path(out) / spec.name
    found: dict[int, tuple] = {}
    for g, (static, idx) in enumerate(spec.groups()):
        where = folder / "checkpoints" / f"group{g}"
        if not (where / "steps").is_dir():
            raise CheckpointError(f"{where}: no checkpoint; run the sweep first")
        rows = _group_rows(spec, g)
        keys = jax.random.wrap_key_data(jnp.asarray(run_keys[rows]))
        _, pad = batch_sharding(len(rows))
        keys = pad_rows(keys, pad)
        cfg = module_config(spec, static)
        with _checkpointer(spec, g, run_keys, folder, read_only=True) as ck:
            latest = ck.restore_latest(found_adapter.saved_like(cfg, keys,
                                                                   len(spec.evaluations())))
        if latest is None:
            raise CheckpointError(f"{where}: no checkpoint; run the sweep first")
        step, saved = latest
        for j, p in enumerate(idx):
            take = slice(j * spec.seeds, (j + 1) * spec.seeds)
            found[p] = (step, jax.tree.map(lambda x, t=take: x[t], saved["agents"]),
                        found_adapter.hyper([spec.points()[p]] * spec.seeds))
    return [found[p] for p in range(n_pts)]


def run(spec: SweepSpec, out: str | pathlib.Path = "results/sweeps", resume: bool = False,
        overwrite: bool = False, executor: str = "local", ray_address: str | None = None,
        seed: int | None = None, show_progress: bool = True, key: jax.Array | None = None
        ) -> dict:
    """Run a sweep and write its results under ``out/<spec.name>``.

    The sweep's folder is locked while the sweep runs (a second writer is refused, with this
    one's pid); its result files (sweep.json, runs.csv, metrics.npz, the figure) replace the
    earlier ones together, only once all of them are written.

    Args:
        spec: a validated sweep (`load_spec`).
        out: parent folder of the sweep's folder.
        resume: continue from the sweep's checkpoints (bit-identical to an uninterrupted run;
            a damaged newest step falls back to the newest intact one, and says so).
        overwrite: delete the sweep's earlier checkpoints first (else they stop the run
            unless ``resume``).
        executor: ``"local"`` (this process, batch sharded over local devices) or ``"ray"``
            (one Ray task per static group).
        ray_address: Ray cluster address (None: the running one, else a local cluster).
        seed: overrides ``spec.seed``.
        show_progress: draw a tqdm progress bar.
        key: the sweep's PRNG key (default ``jax.random.key(seed)``), e.g. one part of a
            caller's split.

    Returns:
        The summary written to ``sweep.json``.

    Raises:
        SweepError: bad arguments, or an output folder that cannot be written.
        CheckpointError: checkpoints of another run, damaged ones, or ones left without
            ``resume``/``overwrite``.
        FolderBusyError: another process is writing this sweep's folder.
    """
    if executor not in EXECUTORS:
        raise SweepError(f"executor: unknown value {executor!r}; accepted values: {EXECUTORS}")
    if resume and overwrite:
        raise SweepError("resume and overwrite: choose one")
    if seed is not None:
        spec = dataclasses.replace(spec, seed=seed)
    folder = pathlib.Path(out) / spec.name
    if folder.exists() and not folder.is_dir():
        raise SweepError(f"out: {folder} is a file, not a folder; name another --out")
    check_size(spec)
    with contextlib.ExitStack() as stack:
        try:
            stack.enter_context(guard.folder_lock(folder, f"sweep {spec.name}"))
        except OSError as e:
            hint = ("free some space on its disk" if e.errno in _FULL else
                    "name a writable folder with --out")
            raise SweepError(f"out: cannot write {folder} ({e.strerror or e}); {hint}"
                             ) from None
        return _run_locked(spec, folder, resume, overwrite, executor, ray_address,
                           show_progress, key)


def _run_locked(spec: SweepSpec, folder: pathlib.Path, resume: bool, overwrite: bool,
                executor: str, ray_address: str | None, show_progress: bool,
                key: jax.Array | None) -> dict:
    if overwrite:
        _clear_checkpoints(folder / "checkpoints")
    if overwrite and (folder / "study.db").exists():
        (folder / "study.db").unlink()
    if spec.search != "grid":
        return _run_search(spec, folder, resume, executor, ray_address, show_progress, key)
    n_pts = len(spec.points())
    run_keys = split_run_keys(spec, key)  # the one split
    groups = spec.groups()
    if resume and not any((folder / "checkpoints" / f"group{g}" / "steps").is_dir()
                          and any((folder / "checkpoints" / f"group{g}" / "steps").iterdir())
                          for g in range(len(groups))):
        print(f"note: nothing to resume in {folder} (no checkpoint was completed); "
              "starting from the beginning", file=sys.stderr, flush=True)
    per_run = adapter(spec.module).length  # a group's static values hold the run length
    total = sum(len(idx) * spec.seeds * per_run(s) for s, idx in groups)
    t0 = time.perf_counter()
    from tqdm.auto import tqdm

    with tqdm(total=total, unit=adapter(spec.module).unit.rstrip("s"), desc=spec.name,
              disable=not show_progress, dynamic_ncols=True, smoothing=0.1) as bar:
        if executor == "ray":
            results = _run_ray(spec, groups, run_keys, folder, resume, ray_address, bar, per_run)
        else:
            results = [run_group(spec, g, run_keys, folder, resume, bar.update)
                       for g in range(len(groups))]
        metrics, finite = assemble(results, n_pts * spec.seeds)
        summary = {"name": spec.name, "source": spec.source, "spec": spec.to_json(),
                   "groups": [{"static": s, "points": idx} for s, idx in groups],
                   "executor": executor, "devices": jax.local_device_count(),
                   "wall_s": time.perf_counter() - t0,
                   "diverged_runs": int((~finite).sum()), **summaries(spec, metrics, finite)}
        if spec.holdout_seeds and summary["best"] is not None:
            from grounding_jax.sweep import search

            t1 = time.perf_counter()
            # the held-out key: the run key folded with a constant, a stream its split into
            # runs never gives
            k = jax.random.key(spec.seed) if key is None else key
            summary["heldout"] = search.heldout(
                spec, spec.base() | summary["best"], folder, resume,
                jax.random.fold_in(k, HOLDOUT_STREAM),
                _executor(executor, ray_address, bar, None))
            summary["heldout"]["wall_s"] = time.perf_counter() - t1
    try:
        with Staged(folder).writing() as staged:
            staged.write_text("runs.csv", csv_text(spec, summary))
            write_sweep_figure(spec, summary, folder, staged)
            staged.write_text("sweep.json", json.dumps(summary, indent=1) + "\n")
            np.savez(staged.path("metrics.npz"), finite=finite, **metrics)
    except OSError as e:
        raise SweepError(f"out: cannot write the results in {folder} ({e.strerror or e}); "
                         "the earlier results there and the checkpoints are kept") from None
    return summary


def check_size(spec: SweepSpec) -> None:
    """Refuse, before anything compiles or is written, a sweep whose largest batch (a static
    group of a grid, a search's trials) would not fit in memory, by its adapter's estimate
    of a run's memory (``Adapter.run_bytes``; modules without one are not checked).

    Raises:
        SweepError: with the estimate, the memory there is, and how to run it in parts.
    """
    found = adapter(spec.module)
    if found.run_bytes is None:
        return
    if spec.search == "grid":
        batches = [(g, static, len(idx) * spec.seeds) for g, (static, idx)
                   in enumerate(spec.groups())]
    else:
        batches = [(0, spec.groups()[0][0], spec.trials * spec.seeds)]
    budget, what = memory_budget()
    for g, static, rows in batches:
        each = found.run_bytes(module_config(spec, static), spec)
        if rows * each <= MEMORY_SHARE * budget:
            continue
        fits = max(int(MEMORY_SHARE * budget // each), 1)
        where = f"static group {g}" if len(batches) > 1 else "its batch"
        raise SweepError(
            f"grid: {rows} runs in {where} would take about {gigabytes(rows * each)} "
            f"({gigabytes(each)} a run, estimated), more than {MEMORY_SHARE:.0%} of "
            f"{what} ({gigabytes(budget)}); run it in parts of at most {fits} runs: split "
            "the grid's values over several sweep files (or --set a part of them), or fewer "
            "seeds")


def _clear_checkpoints(where: pathlib.Path) -> None:
    """``--overwrite``'s deletion of a sweep's checkpoints. A ``checkpoints`` that is a
    symbolic link (to a scratch disk, say) stays: the groups' folders inside its target go."""
    if not where.is_symlink():
        if where.exists():
            shutil.rmtree(where)
        return
    if not where.is_dir():
        raise SweepError(f"overwrite: {where} is a symbolic link to "
                         f"{os.readlink(where)!r}, which is not a folder; remove the link or "
                         "point it at a folder")
    for group in where.iterdir():
        if group.name.startswith("group") and group.name[5:].isdigit():
            shutil.rmtree(group)


def _executor(executor: str, ray_address: str | None, bar, config: Any) -> Callable:
    """``execute(spec, run_keys, out, resume) -> group results``: every static group of a
    grid spec trained here or as Ray tasks, with the static ``config`` if given."""
    def execute(spec: SweepSpec, run_keys: np.ndarray, out: pathlib.Path, resume: bool):
        groups = spec.groups()
        if executor == "ray":
            return _run_ray(spec, groups, run_keys, out, resume, ray_address, bar,
                            adapter(spec.module).length, config)
        return [run_group(spec, g, run_keys, out, resume, bar.update, config)
                for g in range(len(groups))]

    return execute


def _run_search(spec: SweepSpec, folder: pathlib.Path, resume: bool, executor: str,
                ray_address: str | None, show_progress: bool, key: jax.Array | None) -> dict:
    from tqdm.auto import tqdm

    from grounding_jax.sweep import search
    from grounding_jax.sweep.summary import search_csv, write_search_figure

    if resume and not (folder / "checkpoints").is_dir():
        print(f"note: nothing to resume in {folder} (no checkpoint was completed); "
              "starting from the beginning", file=sys.stderr, flush=True)
    found = adapter(spec.module)
    config = module_config(spec, spec.groups()[0][0])  # holds every point of the space
    length = found.length(spec.base())
    total = (spec.trials + spec.holdout_seeds // max(spec.seeds, 1)) * spec.seeds * length
    t0 = time.perf_counter()
    with tqdm(total=total, unit=found.unit.rstrip("s"), desc=f"{spec.name} ({spec.search})",
              disable=not show_progress, dynamic_ncols=True, smoothing=0.1) as bar:
        remote = None
        if executor == "ray":
            def remote(fn: Callable, calls: list[tuple]) -> list:
                ray = _ray(ray_address)
                task = ray.remote(fn)
                out = ray.get([task.remote(*args) for args in calls])
                bar.update(bar.total - bar.n)
                return out

        found_search = search.run_search(spec, folder, resume, key,
                                         _executor(executor, ray_address, bar, config), bar,
                                         remote)
    summary = {"name": spec.name, "source": spec.source, "spec": spec.to_json(),
               "search": spec.search, "executor": executor,
               "devices": jax.local_device_count(), "wall_s": time.perf_counter() - t0,
               "metric": spec.metric, "lower_is_better": spec.metric in found.lower_is_better,
               "diverged_trials": sum(t["diverged"] for t in found_search["trials"]),
               **found_search}
    try:
        with Staged(folder).writing() as staged:
            staged.write_text("runs.csv", search_csv(spec, summary))
            write_search_figure(spec, summary, folder, staged)
            staged.write_text("sweep.json", json.dumps(summary, indent=1) + "\n")
    except OSError as e:
        raise SweepError(f"out: cannot write the results in {folder} ({e.strerror or e}); "
                         "the earlier results there and the checkpoints are kept") from None
    return summary


def _run_ray(spec, groups, run_keys, folder, resume, address, bar, per_run, config=None
             ) -> list[dict]:
    ray = _ray(address)
    task = ray.remote(_ray_task)
    pending = {task.remote(spec, g, run_keys, str(folder), resume, config): g
               for g in range(len(groups))}
    results = []
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        g = pending.pop(ready[0])
        results.append(ray.get(ready[0]))
        s, idx = groups[g]
        bar.update(len(idx) * spec.seeds * per_run(s))
    return results


def _ray(address: str | None):
    """Ray, connected (to ``address``, or the running cluster, else a local one)."""
    try:
        import ray
    except ImportError:
        raise SweepError("executor: 'ray' needs Ray: pip install 'grounding-jax[ray]'") from None
    if not ray.is_initialized():
        ray.init(address=address)
    return ray


def _ray_task(spec: SweepSpec, group: int, run_keys: np.ndarray, folder: str,
              resume: bool, config: Any = None) -> dict:
    """A Ray worker's share: one static group (checkpoints in the shared output folder)."""
    from grounding_jax.core.jaxcache import enable_compilation_cache

    enable_compilation_cache()  # the worker is a process of ours, as the CLI is
    return jax.device_get(run_group(spec, group, run_keys, pathlib.Path(folder), resume,
                                    config=config))
