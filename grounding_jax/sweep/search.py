"""Searches over a sweep's ``[space]``: random draws, Optuna's samplers, asynchronous
successive halving (ASHA) and population-based training (PBT), each trained as vmapped
batches with the grid's checkpoints, locks and identity checks.

A *trial* is one configuration, trained with ``seeds`` runs (one row of the batch each); its
value at an evaluation is the mean over its runs of the sweep's metric (a success rate, or a
curve's mean over the last tenth of the episodes so far). A trial with a run whose numbers
are not finite is flagged ``diverged`` and ranked last.

The sweep's key is split once at the top into the search's own key (the draws, the samplers'
seeds, PBT's choices), the trials' run keys and the held-out key, which the search never sees.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import sys
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core.checkpoint import Checkpointer, CheckpointError
from grounding_jax.core.io import atomic_write_text, code_fingerprint, library_versions
from grounding_jax.sweep.batching import assemble, batch_sharding, chunk_stops, restore_to_resume
from grounding_jax.sweep.space import perturb, sample
from grounding_jax.sweep.spec import SweepError, SweepSpec, adapter, module_config
from grounding_jax.sweep.summary import summaries


@dataclasses.dataclass
class Trial:
    """One configuration of a search and what became of it.

    Attributes:
        index: its number in the search (0, 1, ...).
        params: its searched fields (for PBT: those in force at the end).
        evaluations: ``[(units trained, value or None)]`` at every evaluation.
        units: episodes (epochs) each of its runs trained.
        rl_steps: environment steps its runs took together (units, for a module without
            steps).
        status: ``"completed"`` (trained to the end) or ``"stopped"``.
        reason: why it stopped where it did.
        diverged: a run's numbers were not finite.
        schedule: PBT only: ``[(units, params)]`` from each change on, its lineage's.
        run_values: each run's value at the last evaluation.
    """

    index: int
    params: dict[str, Any]
    evaluations: list = dataclasses.field(default_factory=list)
    units: int = 0
    rl_steps: int = 0
    status: str = "queued"
    reason: str = ""
    diverged: bool = False
    schedule: list = dataclasses.field(default_factory=list)
    run_values: list = dataclasses.field(default_factory=list)

    @property
    def value(self) -> float | None:
        """The value at its last evaluation (None: diverged or never evaluated)."""
        return None if self.diverged or not self.evaluations else self.evaluations[-1][1]


def _keys(spec: SweepSpec, key: jax.Array | None) -> tuple[jax.Array, np.ndarray, jax.Array]:
    """The one split: (the search's key, the trials' run keys [trials * seeds] as raw data,
    the held-out key)."""
    key = jax.random.key(spec.seed) if key is None else key
    k_search, k_runs, k_holdout = jax.random.split(key, 3)
    runs = np.asarray(jax.random.key_data(jax.random.split(k_runs, spec.trials * spec.seeds)))
    return k_search, runs, k_holdout


def _rng(key: jax.Array) -> np.random.Generator:
    """The search's host-side random numbers, from its key."""
    return np.random.default_rng(np.asarray(jax.random.key_data(key)).tolist())


def _sign(spec: SweepSpec) -> int:
    """+1 where lower is better, -1 where higher is (values are ranked by ``sign * value``)."""
    return 1 if spec.metric in adapter(spec.module).lower_is_better else -1


def _rank_key(spec: SweepSpec) -> Callable[[float | None], float]:
    sign = _sign(spec)
    return lambda v: math.inf if v is None or not math.isfinite(v) else sign * v


def listed(spec: SweepSpec, points: list[dict[str, Any]], seeds: int | None = None
           ) -> SweepSpec:
    """A grid spec whose points are ``points`` (their searched fields), one after another."""
    fields = list(spec.space) or list(spec.grid)
    return dataclasses.replace(
        spec, search="grid", design="list", grid={k: [p[k] for p in points] for k in fields},
        space={}, trials=0, holdout_seeds=0, asha={}, pbt={}, optuna={},
        seeds=spec.seeds if seeds is None else seeds)


def _curve_value(curve: np.ndarray, upto: int) -> np.ndarray:
    """Per run: the mean of a curve's last tenth of its first ``upto`` units."""
    return np.asarray(curve, np.float64)[:, upto - max(1, upto // 10): upto].mean(1)


def _trial_value(values: np.ndarray, finite: np.ndarray) -> float | None:
    """A trial's value from its runs' (None when a run diverged)."""
    return float(np.mean(values)) if finite.all() and np.isfinite(values).all() else None


def _steps(metrics: dict[str, np.ndarray], units: int) -> np.ndarray:
    """Per run: environment steps taken in its first ``units`` episodes (``units``, where
    the module counts no steps)."""
    if "steps" in metrics:
        return np.asarray(metrics["steps"])[:, :units].sum(1).astype(np.int64)
    n = next(iter(metrics.values())).shape[0]
    return np.full(n, units, np.int64)


def trials_from_group(spec: SweepSpec, derived: SweepSpec, metrics: dict[str, np.ndarray],
                      finite: np.ndarray, first: int) -> list[Trial]:
    """Trials of a whole-run group (random, Optuna, grid): one per point of ``derived``,
    evaluated at every chunk end (a curve metric) or at the sweep's evaluations (a success
    rate)."""
    found = adapter(spec.module)
    length = found.length(derived.points()[0])
    out = []
    for j, p in enumerate(derived.points()):
        rows = slice(j * derived.seeds, (j + 1) * derived.seeds)
        ok = finite[rows]
        t = Trial(first + j, {k: p[k] for k in derived.grid}, units=length,
                  rl_steps=int(_steps({k: v[rows] for k, v in metrics.items()}, length).sum()),
                  status="completed", reason="trained to the end", diverged=not ok.all())
        if spec.metric.startswith("success_"):
            rates = np.asarray(metrics[spec.metric])[rows]
            per_run = [(e, rates[:, i]) for i, e in enumerate(derived.evaluations())]
        elif found.curves:
            curve = np.asarray(metrics[spec.metric])[rows]
            per_run = [(e, _curve_value(curve, e))
                       for e in chunk_stops(length, spec.chunk)]
        else:
            per_run = [(length, np.asarray(metrics[f"final_{spec.metric}"])[rows])]
        t.evaluations = [(e, _trial_value(v, ok)) for e, v in per_run]
        t.run_values = [float(v) for v in per_run[-1][1]]
        out.append(t)
    return out


# --------------------------------------------------------------------------- whole-run strategies
def run_random(spec: SweepSpec, folder: pathlib.Path, resume: bool, keys: tuple,
               execute: Callable) -> list[Trial]:
    """``trials`` points drawn from the space, trained as one grid of points."""
    k_search, run_keys, _ = keys
    rng = _rng(k_search)
    derived = listed(spec, [sample(spec.space, rng) for _ in range(spec.trials)])
    results = execute(derived, run_keys, folder, resume)
    metrics, finite = assemble(results, spec.trials * spec.seeds)
    return trials_from_group(spec, derived, metrics, finite, 0)


def run_optuna(spec: SweepSpec, folder: pathlib.Path, resume: bool, keys: tuple,
               execute: Callable) -> list[Trial]:
    """Optuna's ask-and-tell: ``batch`` trials asked at once, trained as one batch, told
    back. The study lives in ``<folder>/study.db`` (SQLite): ``optuna-dashboard
    sqlite:///<folder>/study.db`` reads it, and a killed search resumes from it. Each batch's
    sampler is seeded from its own part of the search's key, so a resumed search asks what an
    uninterrupted one would."""
    import optuna

    from grounding_jax.sweep.space import optuna_distribution

    k_search, run_keys, _ = keys
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    size = spec.optuna["batch"]
    n_batches = math.ceil(spec.trials / size)
    seeds = [int(np.asarray(jax.random.key_data(k)).sum() % (2 ** 31))
             for k in jax.random.split(k_search, n_batches)]
    direction = "minimize" if _sign(spec) == 1 else "maximize"
    study = optuna.create_study(storage=f"sqlite:///{folder / 'study.db'}",
                                study_name=spec.name, direction=direction, load_if_exists=True)
    if study.trials and not resume:
        raise CheckpointError(f"{folder / 'study.db'}: holds a study of an earlier run; pass "
                              "--resume to continue it or --overwrite to start over")
    dists = {n: optuna_distribution(d) for n, d in spec.space.items()}
    running_state = optuna.trial.TrialState.RUNNING
    out: list[Trial] = []
    for b in range(n_batches):
        first, last = b * size, min(spec.trials, (b + 1) * size)
        where = folder / "checkpoints" / "batches" / f"b{b}"
        mine = sorted((t for t in study.trials if t.user_attrs.get("batch") == b),
                      key=lambda t: t.user_attrs["trial"])
        running = [t for t in mine if t.state == running_state]
        if (where / "trials.json").is_file():  # trained; maybe not yet told
            records = [Trial(**r) for r in json.loads((where / "trials.json").read_text())]
            numbers = [t.number for t in sorted(mine, key=lambda t: t.number)][-len(records):]
        else:
            if len(running) != last - first or len(mine) != len(running):  # none, or cut
                for t in running:
                    study.tell(t.number, state=optuna.trial.TrialState.FAIL)
                study.sampler = _sampler(spec.optuna["sampler"], seeds[b])
                running = []
                for i in range(first, last):
                    asked = study.ask(dists)
                    asked.set_user_attr("batch", b)
                    asked.set_user_attr("trial", i)
                    running.append(asked)
            numbers = [t.number for t in running]
            params = [{n: t.params[n] for n in spec.space} for t in running]
            derived = listed(spec, params)
            rows = slice(first * spec.seeds, last * spec.seeds)
            results = execute(derived, run_keys[rows], where, True)
            metrics, finite = assemble(results, (last - first) * spec.seeds)
            records = trials_from_group(spec, derived, metrics, finite, first)
            atomic_write_text(where / "trials.json",
                              json.dumps([_record(t) for t in records]) + "\n")
        for t, number in zip(records, numbers, strict=True):
            if t.value is None:
                study.tell(number, state=optuna.trial.TrialState.FAIL, skip_if_finished=True)
            else:
                study.tell(number, t.value, skip_if_finished=True)
        out += records
    return out


def _sampler(name: str, seed: int):
    import optuna

    if name == "cmaes":
        return optuna.samplers.CmaEsSampler(seed=seed)
    if name == "gp":
        return optuna.samplers.GPSampler(seed=seed)
    return optuna.samplers.TPESampler(seed=seed, constant_liar=True)


def _record(t: Trial) -> dict:
    """A trial as JSON (tuples as lists)."""
    return json.loads(json.dumps(dataclasses.asdict(t)))


# ------------------------------------------------------------------------ piece-by-piece strategies
class _Batch:
    """A batch of slots, each training one trial's ``seeds`` runs piece by piece; the rows
    are moved on the host (as numpy, keys as their raw data) between pieces."""

    def __init__(self, spec: SweepSpec, n_slots: int, run_keys: np.ndarray,
                 points: list[dict]) -> None:
        self.spec, self.found = spec, adapter(spec.module)
        static, _ = spec.groups()[0]
        self.config = module_config(spec, static)  # holds every point of the space
        self.pieces = self.found.pieces(self.config)
        self.seeds = spec.seeds
        self.n_slots = n_slots
        self.sharding, pad = batch_sharding(n_slots * self.seeds)
        self.rows = n_slots * self.seeds + pad
        self.points = points  # per trial
        self.run_keys = run_keys  # per trial x seed
        self.slot_trial = [-1] * n_slots
        self.slot_params: list[dict] = [points[0]] * n_slots
        self.run_values: dict[int, list[float]] = {}

    def rows_of(self, slot: int) -> slice:
        return slice(slot * self.seeds, (slot + 1) * self.seeds)

    def hyper(self):
        base = self.spec.base()
        rows = [base | self.slot_params[s] for s in range(self.n_slots)
                for _ in range(self.seeds)]
        rows += [rows[0]] * (self.rows - len(rows))
        return self.found.hyper(rows)

    def fresh(self, trial_of_slot: list[int]) -> dict:
        """Fresh runs for every slot (the keys of its trial, an idle slot trial 0's; the
        hyperparameters in ``slot_params``)."""
        idx = [max(t, 0) * self.seeds + s for t in trial_of_slot for s in range(self.seeds)]
        idx += [idx[0]] * (self.rows - len(idx))
        keys = jax.random.wrap_key_data(jnp.asarray(self.run_keys[idx]))
        state = self.pieces.start(keys, self.hyper())
        self.key_paths = _key_paths(state)
        return _to_host(state)

    def advance(self, host: dict, units: int) -> tuple[dict, dict[str, np.ndarray]]:
        state = jax.device_put(_to_device(host, self.key_paths), self.sharding)
        hp = jax.tree.map(lambda x: jax.device_put(x, self.sharding) if jnp.ndim(x) else x,
                          self.hyper())
        state, metrics = self.pieces.advance(state, hp, units)
        return _to_host(state), {k: np.asarray(v) for k, v in metrics.items()}

    def rates(self, host: dict) -> dict[str, np.ndarray]:
        state = _to_device(host, self.key_paths)
        return {k: np.asarray(v) for k, v in self.pieces.rates(state, self.hyper()).items()}

    def values(self, host: dict, curves: np.ndarray | None, trials: list[int],
               upto: dict[int, int], finite_rows: np.ndarray) -> dict[int, float | None]:
        """The metric of each slot's trial (given by slot) now."""
        if self.spec.metric.startswith("success_"):
            r = self.rates(host)[self.spec.metric[len("success_"):]]
        out = {}
        for slot in trials:
            rows = self.rows_of(slot)
            t = self.slot_trial[slot]
            v = (r[rows] if self.spec.metric.startswith("success_") else
                 _curve_value(curves[t], upto[t]))
            out[slot] = _trial_value(v, finite_rows[rows])
            self.run_values[slot] = [float(x) if ok else math.nan
                                     for x, ok in zip(v, finite_rows[rows], strict=True)]
        return out


def _to_host(tree) -> dict:
    return jax.tree.map(lambda x: np.asarray(jax.random.key_data(x)) if _is_key(x)
                        else np.asarray(x), tree)


def _is_key(x) -> bool:
    return isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _key_paths(tree) -> set[str]:
    return {jax.tree_util.keystr(p) for p, x in jax.tree_util.tree_flatten_with_path(tree)[0]
            if _is_key(x)}


def _to_device(host: dict, key_paths: set[str]):
    return jax.tree_util.tree_map_with_path(
        lambda p, x: jax.random.wrap_key_data(jnp.asarray(x))
        if jax.tree_util.keystr(p) in key_paths else jnp.asarray(x), host)


def _finite_rows(host: dict, n: int) -> np.ndarray:
    ok = np.ones(n, bool)
    for leaf in jax.tree.leaves(host["agent"]):
        if np.issubdtype(leaf.dtype, np.floating):
            ok &= np.isfinite(leaf.reshape(leaf.shape[0], -1)).all(1)[:n]
    return ok


def _put_rows(host: dict, src: dict, rows: np.ndarray, src_rows: np.ndarray) -> dict:
    """``host`` with ``rows`` replaced by ``src``'s ``src_rows``."""
    def put(a, b):
        a = a.copy()
        a[rows] = b[src_rows]
        return a
    return jax.tree.map(put, host, src)


def _identity(spec: SweepSpec, config: Any, run_keys: np.ndarray) -> dict:
    """What a search's checkpoints belong to: the spec, the module config, the run keys, the
    device count, the code and the libraries (a resumed search must match it exactly)."""
    import hashlib

    return {"spec": spec.to_json(), "config": json.loads(json.dumps(
        dataclasses.asdict(config), default=repr)), "devices": jax.local_device_count(),
        "run_keys": hashlib.sha256(run_keys.tobytes()).hexdigest(),
        "code": code_fingerprint(), "libraries": library_versions()}


def _guard(where: pathlib.Path, spec: SweepSpec, ident: dict) -> Checkpointer:
    try:
        return Checkpointer(where, f"search-{spec.module}", ident)
    except CheckpointError as e:
        raise CheckpointError(f"{e}; --overwrite deletes this sweep's checkpoints and "
                              "starts over") from None


class _Saver:
    """The population's checkpoint: the runs' state, the paused trials' bank, the curves and
    the host's bookkeeping (JSON bytes), saved together at every piece's end."""

    def __init__(self, spec: SweepSpec, folder: pathlib.Path, config, run_keys: np.ndarray,
                 resume: bool, name: str = "population") -> None:
        self.ck = _guard(folder / "checkpoints" / name, spec, _identity(spec, config,
                                                                           run_keys))
        if self.ck.latest_step() is not None and not resume:
            self.ck.close()
            raise CheckpointError(f"{self.ck.directory}: holds a checkpoint of an earlier run; "
                                  "pass --resume to continue it or --overwrite to start over")

    def save(self, step: int, arrays: dict, host: dict) -> None:
        blob = np.frombuffer(json.dumps(host).encode(), np.uint8)
        self.ck.save(step, {**arrays, "host": blob})

    def restore(self, arrays_like: dict) -> tuple[dict, dict] | None:
        def like(stored: dict) -> dict:
            n = stored["['host']"]["shape"][0]
            return {**arrays_like, "host": np.zeros(n, np.uint8)}

        found = restore_to_resume(self.ck, like) if self.ck.steps() else None
        if found is None:
            return None
        tree = found[1]
        host = json.loads(np.asarray(tree.pop("host")).tobytes().decode())
        return {k: jax.tree.map(np.asarray, v) for k, v in tree.items()}, host

    def close(self) -> None:
        self.ck.close()


def run_asha(spec: SweepSpec, folder: pathlib.Path, resume: bool, keys: tuple,
             progress: Callable[[int], None], bracket: int = 0) -> list[Trial]:
    """Asynchronous successive halving: ``batch`` slots train trials a chunk at a time; a
    trial reaching a rung pauses there, and a free slot takes the best paused trial that is
    in the top 1/eta of all the trials that reached its rung (the highest rung first), else
    the next new trial -- so the bottom 1 - 1/eta at each rung stop, the batch stays full and
    nothing compiles again. A slot left with no work idles (its rows are not counted).

    With ``brackets`` > 1, bracket ``b`` (of trials ``b, b + brackets, ...``) is ranked first
    at rung ``b``: the later brackets stop fewer trials early (Hyperband's hedge). Brackets
    are independent (``--executor ray`` runs them side by side). Returns the bracket's
    trials."""
    k_search, run_keys, _ = keys
    rng = _rng(k_search)
    points = [sample(spec.space, rng) for _ in range(spec.trials)]  # every bracket's alike
    n_brackets = spec.asha.get("brackets", 1)
    members = list(range(bracket, spec.trials, n_brackets))
    eta, rungs = spec.asha["eta"], list(spec.asha["rungs"])[bracket:]
    n_slots = min(spec.asha["batch"], len(members))
    b = _Batch(spec, n_slots, run_keys, points)
    trials = [Trial(i, points[i]) for i in range(spec.trials)]
    metric_curve = not spec.metric.startswith("success_")
    length = rungs[-1]
    curves = np.zeros((spec.trials, spec.seeds, length if metric_curve else 1), np.float32)
    # host bookkeeping (all JSON): slots, queue, the values each rung has seen
    book = {"slot_trial": [-1] * n_slots, "next": 0, "arrived": [{} for _ in rungs],
            "promoted": [[] for _ in rungs], "piece": 0, "members": members}
    host = b.fresh([0] * n_slots)
    bank = jax.tree.map(lambda x: np.zeros((spec.trials * spec.seeds, *x.shape[1:]), x.dtype),
                        host)
    saver = _Saver(spec, folder, b.config, run_keys, resume,
                   "population" if n_brackets == 1 else f"bracket{bracket}")
    try:
        found = saver.restore({"state": host, "bank": bank, "curves": curves})
        if found is not None:
            arrays, saved = found
            host, bank, curves = arrays["state"], arrays["bank"], arrays["curves"]
            book = saved["book"]
            trials = [Trial(**t) for t in saved["trials"]]
            progress(sum(trials[i].units for i in members) * spec.seeds)
        else:
            book, host = _asha_assign(spec, b, book, trials, host, bank, rungs, eta)
        while any(t >= 0 for t in book["slot_trial"]):
            b.slot_trial = list(book["slot_trial"])
            b.slot_params = [trials[t].params if t >= 0 else points[0] for t in b.slot_trial]
            host, m = b.advance(host, spec.chunk)
            live = [s for s, t in enumerate(b.slot_trial) if t >= 0]
            reached = []
            for s in live:
                t = trials[b.slot_trial[s]]
                rows = b.rows_of(s)
                if metric_curve:
                    curves[t.index, :, t.units:t.units + spec.chunk] = m[spec.metric][rows]
                t.units += spec.chunk
                t.rl_steps += int(_steps({k: v[rows] for k, v in m.items()},
                                         spec.chunk).sum())
                if t.units in rungs:
                    reached.append(s)
            progress(len(live) * spec.seeds * spec.chunk)
            if reached:
                finite = _finite_rows(host, n_slots * spec.seeds)
                values = b.values(host, curves, reached, {t.index: t.units for t in trials},
                                  finite)
                for s in reached:
                    t = trials[b.slot_trial[s]]
                    k = rungs.index(t.units)
                    t.evaluations.append((t.units, values[s]))
                    t.run_values = b.run_values[s]
                    t.diverged = t.diverged or values[s] is None
                    book["arrived"][k][str(t.index)] = values[s]
                    rows = b.rows_of(s)
                    trial_rows = np.arange(t.index * spec.seeds, (t.index + 1) * spec.seeds)
                    bank = _put_rows(bank, host, trial_rows, np.arange(rows.start, rows.stop))
                    book["slot_trial"][s] = -1
                    if k == len(rungs) - 1:
                        t.status, t.reason = "completed", "trained to the end"
                    else:
                        t.status = "paused"
                book, host = _asha_assign(spec, b, book, trials, host, bank, rungs, eta)
            book["piece"] += 1
            saver.save(book["piece"], {"state": host, "bank": bank, "curves": curves},
                       {"book": book, "trials": [_record(t) for t in trials]})
    finally:
        saver.close()
    for t in (trials[i] for i in members):
        if t.status == "paused":
            k = rungs.index(t.units)
            n = len(book["arrived"][k])
            t.status = "stopped"
            t.reason = (f"rung at {t.units} {adapter(spec.module).unit}: not in the top "
                        f"1/{eta} of the {n} trials that reached it")
        elif t.status == "queued":
            t.reason = "never started"
    return [trials[i] for i in members]


def asha_bracket(spec: SweepSpec, folder: str, resume: bool, key_data: np.ndarray,
                 run_keys: np.ndarray, bracket: int) -> list[dict]:
    """One ASHA bracket in a process of its own (a Ray task): its trials as records."""
    from grounding_jax.core.jaxcache import enable_compilation_cache

    enable_compilation_cache()
    keys = (jax.random.wrap_key_data(jnp.asarray(key_data)), run_keys, None)
    return [_record(t) for t in run_asha(spec, pathlib.Path(folder), resume, keys,
                                         lambda n: None, bracket)]


def _asha_assign(spec, b: _Batch, book: dict, trials: list[Trial], host: dict, bank: dict,
                 rungs: list[int], eta: int) -> tuple[dict, dict]:
    """Give every free slot work: the best promotable paused trial, else a new one."""
    sort = _rank_key(spec)
    loads: dict[int, tuple[str, int]] = {}
    for s in range(b.n_slots):
        if book["slot_trial"][s] >= 0:
            continue
        pick = None
        for k in range(len(rungs) - 2, -1, -1):
            arrived = book["arrived"][k]
            ranked = sorted(arrived, key=lambda i: (sort(arrived[i]), int(i)))
            top = ranked[: len(arrived) // eta]
            ok = [int(i) for i in top if int(i) not in book["promoted"][k]
                  and trials[int(i)].status == "paused" and arrived[i] is not None]
            if ok:
                pick = ("bank", ok[0])
                book["promoted"][k].append(ok[0])
                break
        if pick is None and book["next"] < len(book["members"]):
            pick = ("new", book["members"][book["next"]])
            book["next"] += 1
        if pick is None:
            continue
        book["slot_trial"][s] = pick[1]
        trials[pick[1]].status = "running"
        loads[s] = pick
    if loads:
        for s, (_, t) in loads.items():
            b.slot_params[s] = trials[t].params
        new = [loads[s][1] if s in loads and loads[s][0] == "new" else 0
               for s in range(b.n_slots)]
        fresh = b.fresh(new) if any(p[0] == "new" for p in loads.values()) else None
        for s, (where, t) in loads.items():
            rows = np.arange(b.rows_of(s).start, b.rows_of(s).stop)
            if where == "new":
                host = _put_rows(host, fresh, rows, rows)
            else:
                host = _put_rows(host, bank, rows, np.arange(t * spec.seeds,
                                                             (t + 1) * spec.seeds))
    return book, host


def run_pbt(spec: SweepSpec, folder: pathlib.Path, resume: bool, keys: tuple,
            progress: Callable[[int], None], schedule: list | None = None,
            name: str = "population") -> list[Trial]:
    """Population-based training: ``trials`` members train side by side; every ``interval``
    episodes the bottom ``fraction`` copy the agents and hyperparameters of members drawn
    from the top ``fraction``, then perturb them (`perturb`)
    -- all inside the batch, nothing compiled again. Each member's lineage is recorded.

    With ``schedule`` (``[(units, params)]``) it instead replays that schedule on ``spec``'s
    runs as one member, without copying (the held-out check of a PBT result)."""
    k_search, run_keys, _ = keys
    rng = _rng(k_search)
    n = 1 if schedule else spec.trials
    points = [dict(schedule[0][1])] if schedule else [sample(spec.space, rng)
                                                      for _ in range(n)]
    interval, length = spec.pbt.get("interval", spec.chunk), adapter(spec.module).length(
        spec.base())
    b = _Batch(spec, n, run_keys, points)
    trials = [Trial(i, dict(points[i]), status="running",
                    schedule=[(0, dict(points[i]))]) for i in range(n)]
    metric_curve = not spec.metric.startswith("success_")
    curves = np.zeros((n, spec.seeds, length if metric_curve else 1), np.float32)
    b.slot_trial = list(range(n))
    b.slot_params = [t.params for t in trials]
    host = b.fresh(list(range(n)))
    book = {"piece": 0, "events": []}
    saver = _Saver(spec, folder, b.config, run_keys, resume, name)
    try:
        found = saver.restore({"state": host, "curves": curves})
        if found is not None:
            arrays, saved = found
            host, curves, book = arrays["state"], arrays["curves"], saved["book"]
            trials = [Trial(**t) for t in saved["trials"]]
            rng.bit_generator.state = saved["rng"]
            progress(trials[0].units * n * spec.seeds)
        while trials[0].units < length:
            b.slot_params = [t.params for t in trials]
            host, m = b.advance(host, spec.chunk)
            for t in trials:
                rows = b.rows_of(t.index)
                if metric_curve:
                    curves[t.index, :, t.units:t.units + spec.chunk] = m[spec.metric][rows]
                t.units += spec.chunk
                t.rl_steps += int(_steps({k: v[rows] for k, v in m.items()},
                                         spec.chunk).sum())
            progress(n * spec.seeds * spec.chunk)
            units = trials[0].units
            if units % interval == 0 or units == length:
                finite = _finite_rows(host, n * spec.seeds)
                window = {t.index: units for t in trials}
                values = b.values(host, curves, list(range(n)), window, finite)
                for t in trials:
                    t.evaluations.append((units, values[t.index]))
                    t.run_values = b.run_values[t.index]
                    t.diverged = values[t.index] is None
                if schedule:
                    later = [p for u, p in schedule if u == units]
                    if later and units < length:
                        trials[0].params = dict(later[-1])
                        trials[0].schedule.append((units, dict(later[-1])))
                elif units < length:
                    host = _exploit(spec, trials, values, host, rng, b, book, units)
            book["piece"] += 1
            saver.save(book["piece"], {"state": host, "curves": curves},
                       {"book": book, "trials": [_record(t) for t in trials],
                        "rng": rng.bit_generator.state})
    finally:
        saver.close()
    for t in trials:
        t.status, t.reason = "completed", "trained to the end"
    if not schedule:
        _lineages(trials, book["events"])
    return trials


def _exploit(spec, trials, values, host, rng, b: _Batch, book, units) -> dict:
    """The bottom ``fraction`` copy a top member's agents and perturbed hyperparameters."""
    sort = _rank_key(spec)
    ranked = sorted(range(len(trials)), key=lambda i: (sort(values[i]), i))
    cut = max(1, int(len(trials) * spec.pbt["fraction"]))
    top, bottom = ranked[:cut], ranked[-cut:]
    src = np.arange(jax.tree.leaves(host["agent"])[0].shape[0])
    for m in bottom:
        donor = int(top[int(rng.integers(len(top)))])
        src[b.rows_of(m)] = np.arange(b.rows_of(donor).start, b.rows_of(donor).stop)
        params = perturb(spec.space, trials[donor].params, rng, spec.pbt["resample"])
        book["events"].append({"units": units, "member": m, "donor": donor,
                               "params": params})
        trials[m].params = params
    host = {**host, "agent": jax.tree.map(lambda x: x[src], host["agent"])}
    return host


def _lineages(trials: list[Trial], events: list[dict]) -> None:
    """Each member's schedule along its lineage: from the end back, a copy at ``units``
    hands the earlier history over to the donor."""
    start = {t.index: dict(t.schedule[0][1]) for t in trials}
    for t in trials:
        member, upto, changes = t.index, math.inf, []
        for e in sorted(events, key=lambda e: -e["units"]):
            if e["member"] == member and e["units"] < upto:
                changes.append((e["units"], e["params"]))
                member, upto = e["donor"], e["units"]
        changes.append((0, start[member]))
        t.schedule = sorted(changes, key=lambda c: c[0])


# --------------------------------------------------------------------------------- the whole search
def best_trial(spec: SweepSpec, trials: list[Trial]) -> Trial | None:
    """The best trial trained to the end (None: all diverged)."""
    sort = _rank_key(spec)
    done = [t for t in trials if t.status == "completed" and t.value is not None]
    return min(done, key=lambda t: (sort(t.value), t.index)) if done else None


def heldout(spec: SweepSpec, params: dict[str, Any], folder: pathlib.Path, resume: bool,
            k_holdout: jax.Array, execute: Callable, schedule: list | None = None,
            progress: Callable[[int], None] = lambda n: None) -> dict:
    """Retrain the chosen configuration (or PBT schedule) on ``holdout_seeds`` fresh runs
    from the held-out key and measure it as the search measured its trials.

    Returns:
        ``{"seeds", "mean", "std", "runs", "diverged"}`` (``mean`` None: every run diverged).
    """
    n = spec.holdout_seeds
    run_keys = np.asarray(jax.random.key_data(jax.random.split(k_holdout, n)))
    if schedule is not None:
        replay = dataclasses.replace(spec, seeds=n, trials=1)
        t = run_pbt(replay, folder, resume, (jax.random.key(0), run_keys, None), progress,
                    schedule=schedule, name="holdout")[0]
        runs = [float(v) for v in t.run_values]
        diverged = [i for i, v in enumerate(runs) if not math.isfinite(v)]
    else:
        fields = list(spec.space) or list(spec.grid)
        derived = listed(spec, [{k: params[k] for k in fields}], seeds=n)
        results = execute(derived, run_keys, folder / "checkpoints" / "holdout", resume)
        metrics, finite = assemble(results, n)
        point = summaries(derived, metrics, finite)["points"][0]
        runs, diverged = point["runs"], point["diverged"]
    ok = [v for i, v in enumerate(runs) if i not in diverged]
    return {"seeds": n, "mean": float(np.mean(ok)) if ok else None,
            "std": float(np.std(ok)) if ok else None, "runs": runs, "diverged": diverged}


def run_search(spec: SweepSpec, folder: pathlib.Path, resume: bool, key: jax.Array | None,
               execute: Callable, bar, remote: Callable | None = None) -> dict:
    """Run the search of ``spec`` and its held-out check; return the search's summary (the
    caller writes it).

    Args:
        execute: ``execute(derived_spec, run_keys, out, resume) -> group results`` trains a
            grid of points (locally or as Ray tasks).
        bar: a progress bar (its ``update`` takes units of runs trained).
        remote: ``remote(fn, [args, ...]) -> [fn(*args), ...]`` run as parallel tasks (Ray),
            for ASHA's brackets; None: one after another here.
    """
    keys = _keys(spec, key)
    # the whole search's identity, before anything is read back (a study, a batch's trials)
    config = module_config(spec, spec.groups()[0][0])
    ident = _identity(spec, config, keys[1]) | {
        "search_key": np.asarray(jax.random.key_data(keys[0])).tolist()}
    _guard(folder / "checkpoints" / "search", spec, ident).close()
    t0 = time.perf_counter()
    if spec.search == "random":
        trials = run_random(spec, folder, resume, keys, execute)
    elif spec.search == "optuna":
        trials = run_optuna(spec, folder, resume, keys, execute)
    elif spec.search == "asha":
        brackets = range(spec.asha.get("brackets", 1))
        if remote is not None and len(brackets) > 1:
            data = np.asarray(jax.random.key_data(keys[0]))
            found = remote(asha_bracket, [(spec, str(folder), resume, data, keys[1], b)
                                          for b in brackets])
            trials = [Trial(**r) for part in found for r in part]
        else:
            trials = [t for b in brackets
                      for t in run_asha(spec, folder, resume, keys, bar.update, b)]
        trials.sort(key=lambda t: t.index)
    elif spec.search == "pbt":
        trials = run_pbt(spec, folder, resume, keys, bar.update)
    else:
        raise SweepError(f"search: unknown strategy {spec.search!r}")
    search_s = time.perf_counter() - t0
    best = best_trial(spec, trials)
    out = {"trials": [_record(t) for t in trials], "search_s": search_s,
           "best": None if best is None else _record(best),
           "budget": {"rl_steps": int(sum(t.rl_steps for t in trials)),
                      adapter(spec.module).unit: int(sum(t.units for t in trials)
                                                     * spec.seeds),
                      "trials_started": sum(t.units > 0 for t in trials)}}
    if best is not None and spec.holdout_seeds:
        t1 = time.perf_counter()
        out["heldout"] = heldout(spec, best.params, folder, resume, keys[2], execute,
                                 schedule=best.schedule if spec.search == "pbt" else None)
        out["heldout"]["wall_s"] = time.perf_counter() - t1
    elif spec.holdout_seeds:
        print("warning: every trial diverged: no held-out check", file=sys.stderr)
    return out
