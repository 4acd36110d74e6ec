"""Hyperparameter sweeps from TOML files: ``python -m grounding_jax.sweep FILE [--set k=v]``.

A sweep file names a module (``"al"`` or ``"tl"``), a grid, the fixed values and the figure::

    module = "al"
    figure = "fig8a"
    title = "Fig 8A: critic learning rate"
    seeds = 5
    metric = "td_error"        # what the figure plots (see METRICS)
    x = "critic_lr"            # the swept field on the x axis (default: the first grid key)
    chunk = 50                 # episodes between progress updates and checkpoints (AL)

    [params]                   # fixed values of any field (see FIELDS)
    phase2_episodes = 350

    [grid]                     # swept fields: every combination is a point
    critic_lr = [0.0001, 0.001, 0.01, 0.1]

How it runs: every key and value is checked against the module's fields before anything is
compiled. Points are grouped by their *static* fields (TL hidden size, episode counts, backend:
one compile per group; AL hidden sizes are traced, see FIELDS); within a group every point x
seed is one row of a ``vmap``ped batch whose *traced* fields (learning rates, sigma, ...) are
arrays, and the batch axis is sharded over all local devices. The run keys come from one
``jax.random.key(seed)`` split once into points x seeds, so a run's result does not depend on
the grouping, the devices or the executor.
AL groups train in a host loop over chunks of episodes (progress bar, an orbax checkpoint after
each chunk; ``--resume`` continues bit-identically); TL groups are checkpointed when done. Runs
whose parameters or metrics are not finite are flagged ``diverged`` and left out of the means.
``--executor ray`` sends each group to a Ray cluster as a task.

Writes ``<out>/<name>/``: ``sweep.json`` (spec, per-point summaries, curves), ``runs.csv``
(one row per run), ``<figure>.png`` / ``<figure>.json``, and ``checkpoints/``.
"""

from __future__ import annotations

if __name__ == "__main__":  # before the heavy imports: an early Ctrl-C exits cleanly
    from grounding_jax import _guard as _early

    _early.quiet_start(["python", "-m", "grounding_jax.sweep"])

import argparse
import contextlib
import csv
import dataclasses
import hashlib
import io
import itertools
import json
import math
import pathlib
import shutil
import sys
import time
import tomllib
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax import _guard, al, al_experiments, beyond, cacla, env, physics, tl, tl_data
from grounding_jax._checks import FLOAT32_MAX, Rule
from grounding_jax._io import Staged, code_fingerprint, library_versions, pyplot, write_figure
from grounding_jax.checkpoint import Checkpointer, CheckpointError
from grounding_jax.env import EnvConfig, EnvParams

EXECUTORS = ("local", "ray")


class SweepError(ValueError):
    """A bad sweep file or override; the message names the file and the key."""


@dataclasses.dataclass(frozen=True)
class Field:
    """One sweepable field: static (changes compiled code: grouped) or traced (vmapped)."""

    kind: str
    type: type
    default: Any
    rule: str = ""
    ok: Callable[[Any], bool] | None = None
    choices: tuple | None = None


_DH, _EC = al.ALHyper(), EnvConfig()
#: the learner AL sweeps train (its traced fields are sweep fields, read from its rule table)
_LEARNER = cacla.LEARNER
_LH = _LEARNER.hyper_type()
_EP, _TH, _TC = EnvParams(), tl.TLHyper(), tl.TLConfig()


def _ruled(kind: str, rule: Rule, default: Any) -> Field:
    """A field checked by its dataclass's own rule (one table serves both)."""
    return Field(kind, rule.type, default, rule.text, rule.holds)


def _traced(rule: Rule, default: Any) -> Field:
    return _ruled("traced", rule, default)


def _static(rule: Rule, default: Any) -> Field:
    return _ruled("static", rule, default)


def _traced_from(rules: dict[str, Rule], defaults: Any, names: Sequence[str] | None = None
                 ) -> dict[str, Field]:
    return {n: _traced(rules[n], getattr(defaults, n)) for n in (names or rules)}


#: the traced AL fields a sweep may set, by the dataclass they belong to (the hidden sizes
#: are the sweep's own: they become ``actor_units``/``critic_units``)
_AL_SWEPT = {
    # all the learner's but the phase switch (the schedule sets it) and the units in use
    "learner": tuple(n for n in _LEARNER.hyper_rules
                     if n not in ("phase1", "actor_units", "critic_units")),
    "al": tuple(al.HYPER_RULES),  # ALHyper's own
    "env": ("action_scale", "touch_other_penalty", "touch_target_penalty",
            "touch_moved_penalty", "touch_bonus", "start_noise"),  # EnvParams
}

_FIELDS: dict[str, dict[str, Field]] = {
    "al": {
        # traced: the networks are built at the sweep's largest sizes with the unused units at
        # zero weights, where they stay (cacla.init) -- one batch instead of one per size, which
        # pays because an AL step's cost hardly grows with the batch (physics call overhead)
        "actor_hidden": _traced(cacla.CONFIG_RULES["actor_hidden"], 40),
        "critic_hidden": _traced(cacla.CONFIG_RULES["critic_hidden"], 20),
        "var": Field("static", bool, False),
        "phase1_episodes": _static(al.CONFIG_RULES["phase1_episodes"], 150),
        "phase2_episodes": _static(al.CONFIG_RULES["phase2_episodes"], 300),
        "backend": Field("static", str, _EC.backend, choices=physics.BACKENDS),
        "substeps": _static(env.CONFIG_RULES["substeps"], _EC.substeps),
        "episode_length": _static(env.CONFIG_RULES["episode_length"], _EC.episode_length),
        "random_layout": Field("static", bool, True),
        # "random": the free family (objects anywhere, the actor told the target's (x, y))
        "placement": Field("static", str, "fixed", choices=al.PLACEMENTS),
        **_traced_from(_LEARNER.hyper_rules, _LH, _AL_SWEPT["learner"]),
        **_traced_from(al.HYPER_RULES, _DH, _AL_SWEPT["al"]),
        **_traced_from(env.PARAM_RULES, _EP, _AL_SWEPT["env"]),
    },
    "tl": {
        # the hidden size could be traced (padded + masked), but one compile per size was
        # measured faster (benchmarks/tl_throughput.py), so it is a group key
        "hidden": _static(tl.HYPER_RULES["hidden"], _TH.hidden),
        "epochs": _static(tl.CONFIG_RULES["epochs"], _TC.epochs),
        "eval_every": _static(tl.CONFIG_RULES["eval_every"], _TC.eval_every),
        "noise_mode": Field("static", str, _TC.noise_mode, choices=tl.NOISE_MODES),
        **_traced_from(tl.HYPER_RULES, _TH,
                       ("lr", "replication", "noise", "image_scale", "target_scale")),
    },
}

#: the per-run metrics a figure may plot: AL -- per-episode training metrics (the summary is
#: the mean over the last tenth of the episodes); TL -- the final value after training
_METRICS = {
    "al": {"td_error": "critic's RMS TD error per episode",
           "final_reward": "reward at the episode's last step",
           "return": "sum of rewards over the episode",
           "final_point_l1": "L1 distance to the pointing pose at the episode's end",
           # evaluated at ``eval_at`` episodes (the greedy actor, the criteria):
           **{f"success_{k}": f"success rate: {v}" for k, v in (
               ("point", "point from home"), ("touch", "touch from home"),
               ("push", "push from home"), ("rand_point", "point from random starts"),
               ("mean", "mean of point, touch, push and random-start point"))}},
    "tl": {"test_acc": "test accuracy", "train_acc": "training accuracy",
           "test_rmse": "test RMSE per output unit", "train_rmse": "training RMSE"},
}
#: metrics where lower is better (for the others higher is)
LOWER_IS_BETTER = frozenset({"td_error", "final_point_l1", "test_rmse", "train_rmse"})
TOP_KEYS = {"name": str, "module": str, "figure": str, "title": str, "description": str,
            "seeds": int, "metric": str, "x": str, "chunk": int, "seed": int, "paper": str,
            "params": dict, "grid": dict, "eval_at": list, "design": str}
#: how a grid becomes points: every combination, or one field at a time around a base point
DESIGNS = ("product", "axes")
#: the random starts of the success evaluation are drawn from this fixed key -- the same
#: evaluation set for every run and sweep, as a test set is
EVAL_SEED = 0


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """A validated sweep: fixed ``params`` and swept ``grid`` over the module's fields."""

    name: str
    module: str
    figure: str
    title: str
    seeds: int
    metric: str
    x: str
    chunk: int
    seed: int
    params: dict[str, Any]
    grid: dict[str, list]
    source: str = "<dict>"
    description: str = ""
    paper: str = ""
    eval_at: tuple[int, ...] = ()
    design: str = "product"

    def evaluations(self) -> tuple[int, ...]:
        """Episode counts at which AL success rates are measured: ``eval_at`` plus the end,
        or none when neither ``eval_at`` nor a ``success_*`` metric asks for them."""
        adapter = ADAPTERS[self.module]
        if not adapter.evaluates or not (self.eval_at or self.metric.startswith("success_")):
            return ()
        return tuple(sorted(set(self.eval_at) | {adapter.length(self.points()[0])}))

    def points(self) -> list[dict[str, Any]]:
        """The grid's points, as full assignments of the module's fields: every combination
        (``design = "product"``), or (``"axes"``) the base point -- each grid field at its
        first value -- then each field's other values, one field changed at a time."""
        base = {k: f.default for k, f in FIELDS[self.module].items()} | self.params
        keys = list(self.grid)
        if self.design == "axes":
            centre = base | {k: self.grid[k][0] for k in keys}
            return [centre] + [centre | {k: v} for k in keys for v in self.grid[k][1:]]
        return [base | dict(zip(keys, combo, strict=True))
                for combo in itertools.product(*(self.grid[k] for k in keys))]

    def groups(self) -> list[tuple[dict[str, Any], list[int]]]:
        """Points grouped by their static fields: [(static values, point indices)], in order
        of first appearance -- one compile each."""
        static = [k for k, f in FIELDS[self.module].items() if f.kind == "static"]
        out: dict[tuple, list[int]] = {}
        pts = self.points()
        for i, p in enumerate(pts):
            out.setdefault(tuple(p[k] for k in static), []).append(i)
        return [({k: pts[idx[0]][k] for k in static}, idx) for idx in out.values()]

    def to_json(self) -> dict:
        """The spec as parse_spec accepts it back (tuples as lists)."""
        return {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v
                for f in dataclasses.fields(self) if f.name != "source"}


def _err(source: str, key: str, msg: str) -> SweepError:
    return SweepError(f"{source}: {key}: {msg}")


def _check_value(source: str, module: str, key: str, value: Any) -> Any:
    field = FIELDS[module][key.rpartition(".")[2]]
    ok_type = (isinstance(value, bool) if field.type is bool else
               isinstance(value, int) and not isinstance(value, bool) if field.type is int else
               isinstance(value, (int, float)) and not isinstance(value, bool)
               if field.type is float else isinstance(value, str))
    if not ok_type:
        raise _err(source, key, f"expected {field.type.__name__}, got {value!r} "
                                f"({type(value).__name__})")
    if field.type is float:
        value = float(value)
        if not math.isfinite(value):
            raise _err(source, key, f"must be finite, got {value!r}")
    if field.choices is not None and value not in field.choices:
        raise _err(source, key, f"unknown value {value!r}; accepted values: {field.choices}")
    if field.ok is not None and not field.ok(value):
        if field.type is float and abs(value) > FLOAT32_MAX:
            raise _err(source, key, f"must be {field.rule} and fit in float32 (|x| <= "
                                    f"{FLOAT32_MAX:.4g}: traced values are float32), got "
                                    f"{value!r}")
        raise _err(source, key, f"must be {field.rule}, got {value!r}")
    return value


def parse_spec(data: dict, source: str = "<dict>") -> SweepSpec:
    """Validate a sweep (as parsed from TOML) and return it; SweepError names the bad key.

    Nothing is compiled or written here.
    """
    unknown = sorted(set(data) - set(TOP_KEYS))
    if unknown:
        raise _err(source, unknown[0], f"unknown key; accepted keys: {sorted(TOP_KEYS)}")
    for k, t in TOP_KEYS.items():
        if k in data and not (isinstance(data[k], t) and not (t is int and
                                                               isinstance(data[k], bool))):
            raise _err(source, k, f"expected {t.__name__}, got {data[k]!r}")
    module = data.get("module")
    if module not in ADAPTERS:
        raise _err(source, "module", f"unknown module {module!r}; accepted values: "
                                     f"{tuple(ADAPTERS)}")
    adapter = ADAPTERS[module]
    fields = FIELDS[module]
    params, grid = dict(data.get("params", {})), dict(data.get("grid", {}))
    if not grid:
        raise _err(source, "grid", "empty: give at least one field with a list of values")
    for section, table in (("params", params), ("grid", grid)):
        for k in table:
            if k not in fields:
                raise _err(source, f"{section}.{k}", f"unknown field for module {module!r}; "
                                                     f"accepted fields: {sorted(fields)}")
    for k in set(params) & set(grid):
        raise _err(source, f"grid.{k}", "also set in [params]; set it in one place")
    for k, v in params.items():
        params[k] = _check_value(source, module, f"params.{k}", v)
    for k, vs in grid.items():
        if not isinstance(vs, list) or not vs:
            raise _err(source, f"grid.{k}", f"must be a non-empty list of values, got {vs!r}")
        grid[k] = [_check_value(source, module, f"grid.{k}", v) for v in vs]
        if len(set(map(repr, grid[k]))) != len(grid[k]):
            raise _err(source, f"grid.{k}", f"repeated values in {vs!r}")
    seeds = data.get("seeds", 5)
    if seeds < 1:
        raise _err(source, "seeds", f"must be an integer >= 1, got {seeds!r}")
    chunk = data.get("chunk", 50)
    if chunk < 1:
        raise _err(source, "chunk", f"must be an integer >= 1, got {chunk!r}")
    metric = data.get("metric", next(iter(METRICS[module])))
    if metric not in METRICS[module]:
        raise _err(source, "metric", f"unknown metric {metric!r} for module {module!r}; "
                                     f"accepted values: {tuple(METRICS[module])}")
    x = data.get("x", next(iter(grid)))
    if x not in grid:
        raise _err(source, "x", f"{x!r} is not a grid field; grid fields: {list(grid)}")
    design = data.get("design", "product")
    if design not in DESIGNS:
        raise _err(source, "design", f"unknown value {design!r}; accepted values: {DESIGNS}")
    eval_at = data.get("eval_at", [])
    if eval_at and not adapter.evaluates:
        raise _err(source, "eval_at", "only AL sweeps evaluate success rates")
    if not all(isinstance(e, int) and not isinstance(e, bool) and e >= 1 for e in eval_at):
        raise _err(source, "eval_at", f"must be a list of episode counts >= 1, got {eval_at!r}")
    name = data.get("name", pathlib.Path(source).stem if source != "<dict>" else "sweep")
    spec = SweepSpec(name=name, module=module, figure=data.get("figure", name),
                     title=data.get("title", name), seeds=seeds, metric=metric, x=x,
                     chunk=chunk, seed=data.get("seed", 0), params=params, grid=grid,
                     source=source, description=data.get("description", ""),
                     paper=data.get("paper", ""), eval_at=tuple(sorted(set(eval_at))),
                     design=design)
    if adapter.evaluates and (eval_at or metric.startswith("success_")):
        lengths = {adapter.length(p) for p in spec.points()}
        if len(lengths) > 1:
            raise _err(source, "grid", "success evaluation needs one episode count for all "
                                       f"points; phase1/phase2_episodes give {sorted(lengths)}")
        if eval_at and max(eval_at) > min(lengths):
            raise _err(source, "eval_at", f"{max(eval_at)} is past the run's {min(lengths)} "
                                          "episodes; accepted: 1..episodes")
    for static, _ in spec.groups():  # the module's own checks (cross-field rules)
        try:
            _module_config(spec, static)
        except ValueError as e:
            raise SweepError(f"{source}: {e}") from None
    return spec


def _parse_value(text: str) -> Any:
    """An override's value: TOML syntax (1, 0.5, true, "s", [1, 2]); bare ``a,b`` is a list;
    anything else is a string."""
    for candidate in (text, f"[{text}]"):
        try:
            return tomllib.loads(f"v = {candidate}")["v"]
        except tomllib.TOMLDecodeError:
            continue
    return text


def apply_overrides(data: dict, overrides: Sequence[str], source: str) -> dict:
    """``key=value`` overrides: a grid field gets a new list, a top-level key a new value,
    any other field a new value in [params] -- or, given a list (``a,b``), joins the grid."""
    for section in ("params", "grid"):
        if not isinstance(data.get(section, {}), dict):
            raise _err(source, section, f"must be a table ([{section}] with one field per "
                                        f"line), got {data[section]!r}")
    data = {**data, "params": dict(data.get("params", {})), "grid": dict(data.get("grid", {}))}
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise _err(source, f"--set {item!r}", "expected KEY=VALUE")
        value = _parse_value(text)
        if key in data["grid"]:
            data["grid"][key] = value if isinstance(value, list) else [value]
        elif key in TOP_KEYS and key not in ("params", "grid"):
            data[key] = value
        elif isinstance(value, list):
            data["params"].pop(key, None)
            data["grid"][key] = value
        else:
            data["params"][key] = value
    return data


def load_spec(path: str | pathlib.Path, overrides: Sequence[str] = ()) -> SweepSpec:
    """Read, override and validate a sweep file."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise SweepError(f"{path}: no such sweep file")
    try:
        data = tomllib.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as e:
        raise SweepError(f"{path}: not a UTF-8 text file ({e.reason} at byte {e.start}); "
                         "accepted: a TOML sweep file") from None
    except tomllib.TOMLDecodeError as e:
        raise SweepError(f"{path}: not valid TOML ({e})") from None
    except OSError as e:
        raise SweepError(f"{path}: cannot be read ({e.strerror or e})") from None
    return parse_spec(apply_overrides(data, overrides, str(path)), str(path))


# ----------------------------------------------------------------------------- running groups
def _module_config(spec: SweepSpec, static: dict[str, Any]):
    return ADAPTERS[spec.module].config(spec.points(), static)


def _al_config(pts: list[dict], static: dict[str, Any]) -> al.ALConfig:
    # random placements: the free family, with its networks (beyond.FREE_LEARNER's heads)
    learner = beyond.FREE_LEARNER if static["placement"] == "random" else cacla.CaclaConfig()
    return al.ALConfig(
        env=EnvConfig(backend=static["backend"], substeps=static["substeps"],
                      episode_length=static["episode_length"], task_set=learner.task_set),
        learner=dataclasses.replace(learner, actor_hidden=max(p["actor_hidden"] for p in pts),
                                    critic_hidden=max(p["critic_hidden"] for p in pts),
                                    var=static["var"]),
        phase1_episodes=static["phase1_episodes"],
        phase2_episodes=static["phase2_episodes"], random_layout=static["random_layout"],
        placement=static["placement"])


def _tl_config(pts: list[dict], static: dict[str, Any]) -> tl.TLConfig:
    clean = all(p["noise"] == 0 for p in pts)
    return tl.TLConfig(epochs=static["epochs"], eval_every=static["eval_every"],
                       noise_mode=static["noise_mode"], max_hidden=static["hidden"],
                       max_replication=max(p["replication"] for p in pts),
                       pixel_budget=int(tl_data.load().bitmaps.sum(1).max()) if clean else 0)


def _column(rows: list[dict], k: str, dtype) -> jnp.ndarray:
    return jnp.asarray([r[k] for r in rows], dtype)


def _hyper(spec: SweepSpec, rows: list[dict]):
    """The traced fields of a batch of rows as arrays with a leading batch axis."""
    return ADAPTERS[spec.module].hyper(rows)


def _al_hyper(rows: list[dict]) -> al.ALHyper:
    f32 = jnp.float32
    lh = _LEARNER.hyper_type(**{k: _column(rows, k, f32) for k in _AL_SWEPT["learner"]},
                             actor_units=_column(rows, "actor_hidden", jnp.int32),
                             critic_units=_column(rows, "critic_hidden", jnp.int32))
    env_params = EnvParams(**{k: _column(rows, k, f32) for k in _AL_SWEPT["env"]})
    return al.ALHyper(learner=lh, env=env_params,
                      **{k: _column(rows, k, f32) for k in _AL_SWEPT["al"]})


def _batch_sharding(batch: int):
    """(sharding of a leading batch axis over all local devices, padding rows needed)."""
    devices = jax.local_devices()
    mesh = jax.sharding.Mesh(np.asarray(devices), ("batch",))
    return (jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch")),
            (-batch) % len(devices))


def _pad(tree, pad: int):
    return jax.tree.map(lambda x: jnp.concatenate([x, jnp.repeat(x[:1], pad, 0)])
                        if pad and jnp.ndim(x) else x,
                        tree)


def _finite_rows(tree, batch: int) -> np.ndarray:
    """Per row: every float leaf of the tree finite."""
    ok = np.ones(batch, bool)
    for leaf in jax.tree.leaves(tree):
        a = np.asarray(leaf)
        if np.issubdtype(a.dtype, np.floating):
            ok &= np.isfinite(a.reshape(batch, -1)).all(1)
    return ok


def run_group(spec: SweepSpec, group: int, run_keys: np.ndarray, out: pathlib.Path | None,
              resume: bool = False, progress: Callable[[int], None] | None = None
              ) -> dict[str, np.ndarray]:
    """Train one static group: its points x seeds as one sharded, vmapped batch.

    Args:
        spec: the sweep.
        group: index into ``spec.groups()``.
        run_keys: raw key data ``[points * seeds, ...]`` of the *whole* sweep (row
            ``point * seeds + seed``).
        out: the sweep's output folder (checkpoints under ``out/checkpoints``); None: none.
        resume: continue from this group's checkpoint if there is one.
        progress: called with the number of run-episodes (AL) or run-epochs (TL) just done.

    Returns:
        ``metrics`` (each ``[rows, ...]``), ``finite`` ``[rows]`` and ``rows`` (indices into
        points x seeds).
    """
    static, _ = spec.groups()[group]
    rows = _group_rows(spec, group)
    points = spec.points()
    batch_rows = [points[r // spec.seeds] for r in rows]
    cfg = _module_config(spec, static)
    keys = jax.random.wrap_key_data(jnp.asarray(run_keys[rows]))
    hp = _hyper(spec, batch_rows)
    sharding, pad = _batch_sharding(len(rows))
    keys, hp = _pad((keys, hp), pad)
    ck = None
    if out is not None:
        try:
            ck = _checkpointer(spec, group, run_keys, out)
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
        metrics, params = ADAPTERS[spec.module].train(cfg, keys, hp, spec, sharding, ck,
                                                      report)
    finally:
        if ck is not None:
            ck.close()
    metrics = jax.tree.map(lambda x: np.asarray(x)[: len(rows)], metrics)
    finite = (_finite_rows(jax.tree.map(lambda x: np.asarray(x)[: len(rows)], params),
                           len(rows)) & _finite_rows(metrics, len(rows)))
    return {"metrics": metrics, "finite": finite, "rows": rows}


def _group_rows(spec: SweepSpec, group: int) -> np.ndarray:
    """The runs of a static group: indices into points x seeds (row ``point * seeds + seed``)."""
    return np.asarray([p * spec.seeds + s for p in spec.groups()[group][1]
                       for s in range(spec.seeds)])


def _run_keys(spec: SweepSpec, key: jax.Array | None = None) -> np.ndarray:
    """Raw key data of every run: ``key`` (default ``jax.random.key(spec.seed)``) split once
    into points x seeds."""
    key = jax.random.key(spec.seed) if key is None else key
    return np.asarray(jax.random.key_data(jax.random.split(key, len(spec.points())
                                                           * spec.seeds)))


def identity(spec: SweepSpec, group: int, run_keys: np.ndarray) -> dict:
    """What a static group's checkpoints belong to: the spec, every point's whole assignment
    (defaults included), the group's static config and the traced values of each of its runs
    (every field of the hyperparameter pytree, defaults included), the run keys, the device
    count, the code's fingerprint and the library versions. A resumed run must match it
    exactly (``Checkpointer`` names the fields that differ)."""
    static, idx = spec.groups()[group]
    rows = _group_rows(spec, group)
    points = spec.points()
    hp = _hyper(spec, [points[r // spec.seeds] for r in rows])
    traced = {jax.tree_util.keystr(path): np.asarray(leaf).tolist()
              for path, leaf in jax.tree_util.tree_flatten_with_path(hp)[0]}
    cfg = _module_config(spec, static)
    return {"spec": spec.to_json(), "group": group, "static": static,
            "points": [points[i] for i in idx],
            "config": json.loads(json.dumps(dataclasses.asdict(cfg), default=repr)),
            "traced": traced, "rows": rows.tolist(), "devices": jax.local_device_count(),
            "run_keys": hashlib.sha256(run_keys.tobytes()).hexdigest(),
            "code": code_fingerprint(), "libraries": library_versions()}


def _checkpointer(spec: SweepSpec, group: int, run_keys: np.ndarray, out: pathlib.Path,
                  read_only: bool = False) -> Checkpointer:
    # a reader takes the arrays as they were trained, by whatever code; a resumed run must
    # continue with the code and libraries it began with
    return Checkpointer(out / "checkpoints" / f"group{group}", f"sweep-{spec.module}",
                        identity(spec, group, run_keys), read_only=read_only,
                        ignore=("code", "libraries") if read_only else ())


def _restore_to_resume(ck: Checkpointer, like: Any) -> tuple[int, Any] | None:
    """The newest intact step of a group (a damaged newer one is set aside, said on stderr),
    or None when the group has no step yet."""
    found = ck.restore_latest(like, fallback=True)
    if found is not None:
        for where in ck.set_aside_after(found[0]):
            print(f"warning: resuming from step {found[0]}; the damaged step was moved to "
                  f"{where}", file=sys.stderr, flush=True)
    return found


def _al_saved_like(cfg: al.ALConfig, keys: jax.Array, n_evals: int) -> dict:
    """The structure of an AL group's checkpoint (shapes only)."""
    n = keys.shape[0]
    like_agents = jax.eval_shape(lambda k: jax.vmap(lambda kk: al.schedule(kk, cfg)[0])(k),
                                 keys)  # shapes only: the units in use do not change them
    like_m = jax.eval_shape(lambda k: jax.vmap(al.make_train(
        dataclasses.replace(cfg, phase1_episodes=0, phase2_episodes=1)),
        in_axes=(0, None))(k, al.ALHyper())[1], keys)
    like_m = {k: jax.ShapeDtypeStruct((n, cfg.episodes), v.dtype) for k, v in like_m.items()}
    like = {"agents": like_agents, "metrics": like_m, "keys": keys, "episode": np.int64(0)}
    if n_evals:  # orbax stores no empty arrays
        like["evals"] = np.zeros((len(al_experiments.SUCCESS_METRICS), n, n_evals), np.float32)
    return like


def trained_agents(spec: SweepSpec, out: str | pathlib.Path = "results/sweeps",
                   seed: int | None = None, key: jax.Array | None = None):
    """The AL agents of a finished (or interrupted) sweep, from its checkpoints.

    Args:
        spec: the sweep, as it was run.
        out: the parent folder it was run under.
        seed: the seed it was run with, if not ``spec.seed``.
        key: the key it was run with, if :func:`run` was given one.

    Returns:
        A list with, per point (``spec.points()`` order): ``(episode, agents [seeds],
        hp)`` -- the latest checkpointed episode of its group, its runs' agents and their
        hyperparameters (``al.ALHyper``, one row per run).
    """
    if spec.module != "al":
        raise SweepError(f"{spec.source}: module: trained_agents reads AL sweeps, not "
                         f"{spec.module!r}")
    spec = spec if seed is None else dataclasses.replace(spec, seed=seed)
    n_pts = len(spec.points())
    run_keys = _run_keys(spec, key)
    folder = pathlib.Path(out) / spec.name
    found: dict[int, tuple] = {}
    for g, (static, idx) in enumerate(spec.groups()):
        where = folder / "checkpoints" / f"group{g}"
        if not (where / "steps").is_dir():
            raise CheckpointError(f"{where}: no checkpoint; run the sweep first")
        rows = _group_rows(spec, g)
        keys = jax.random.wrap_key_data(jnp.asarray(run_keys[rows]))
        _, pad = _batch_sharding(len(rows))
        keys = _pad(keys, pad)
        cfg = _module_config(spec, static)
        with _checkpointer(spec, g, run_keys, folder, read_only=True) as ck:
            latest = ck.restore_latest(_al_saved_like(cfg, keys, len(spec.evaluations())))
        if latest is None:
            raise CheckpointError(f"{where}: no checkpoint; run the sweep first")
        step, saved = latest
        for j, p in enumerate(idx):
            take = slice(j * spec.seeds, (j + 1) * spec.seeds)
            found[p] = (step, jax.tree.map(lambda x, t=take: x[t], saved["agents"]),
                        _hyper(spec, [spec.points()[p]] * spec.seeds))
    return [found[p] for p in range(n_pts)]


def chunk_stops(episodes: int, chunk: int) -> list[int]:
    """Chunk ends: equal chunks of the largest divisor of ``episodes`` that is <= ``chunk``
    (one compiled shape), unless that divisor is under half of ``chunk`` -- then chunks of
    ``chunk`` and a shorter last one (a second compile)."""
    size = max(d for d in range(1, min(chunk, episodes) + 1) if episodes % d == 0)
    if size < min(chunk, episodes) / 2:
        size = chunk
    return list(range(size, episodes, size)) + [episodes]


def _run_al(cfg: al.ALConfig, keys, hp, spec: SweepSpec, sharding, ck, progress):
    """Train a group in chunks of ``spec.chunk`` episodes; at each of ``spec.evaluations()``
    (episode counts) the success rates of every run are measured (the evaluation hook) and
    returned as metrics ``success_<name>`` ``[runs, len(evaluations)]``."""
    evaluations = spec.evaluations()
    stops = sorted(set(chunk_stops(cfg.episodes, spec.chunk)) | set(evaluations))
    start = None
    n = keys.shape[0]
    names = al_experiments.SUCCESS_METRICS
    evals = np.full((len(names), n, len(evaluations)), np.nan, np.float32)
    rates = al_experiments.make_success_rates(cfg.env) if evaluations else None
    found = None if ck is None or not ck.steps() else _restore_to_resume(
        ck, _al_saved_like(cfg, keys, len(evaluations)))
    if found is not None:
        saved = found[1]
        if not np.array_equal(jax.random.key_data(saved["keys"]), jax.random.key_data(keys)):
            raise CheckpointError(f"{ck.directory}: stored run keys differ from this run's")
        start = (int(saved["episode"]), saved["agents"], saved["metrics"])
        if evaluations:
            evals = np.asarray(saved["evals"], np.float32)
        if progress:
            progress(n * start[0])
    done = [start[0] if start else 0]

    def on_stop(episode, agents, metrics):
        if episode in evaluations:
            r = rates(agents, jax.random.key(EVAL_SEED), hp.env)
            for i, k in enumerate(names):
                evals[i, :, evaluations.index(episode)] = r[k]
        if ck is not None:
            tree = {"agents": agents, "metrics": metrics, "keys": keys,
                    "episode": np.int64(episode)}
            ck.save(episode, tree | ({"evals": evals} if evaluations else {}))
        if progress:
            progress(n * (episode - done[0]))
        done[0] = episode

    agents, metrics = al.train_in_chunks(cfg, keys, hp, stops, on_stop, start, sharding)
    if evaluations:
        metrics = {**metrics, **{f"success_{k}": evals[i] for i, k in enumerate(names)}}
    return metrics, agents


def _run_tl(cfg: tl.TLConfig, keys, hp, spec: SweepSpec, sharding, ck, progress):
    n = keys.shape[0]
    train = jax.jit(jax.vmap(tl.make_train(cfg)))
    found = None if ck is None or not ck.steps() else _restore_to_resume(
        ck, jax.eval_shape(train, keys, hp))
    if found is not None:
        params, metrics = found[1]
    else:
        keys, hp = jax.device_put((keys, hp), sharding)
        params, metrics = jax.block_until_ready(train(keys, hp))
        if ck is not None:
            ck.save(1, (params, metrics))
    if progress:
        progress(n * cfg.epochs)
    return metrics, params


@dataclasses.dataclass(frozen=True)
class Adapter:
    """What the sweep runner needs from one module; the runner itself does not branch on
    modules.

    Attributes:
        fields: the sweepable fields (static ones group the grid, traced ones are vmapped).
        metrics: the per-run metrics a figure may plot, with their descriptions.
        unit: what a run's length counts ("episodes", "epochs").
        length: a point's run length in ``unit``.
        config: ``config(points, static) -> static config`` of one group.
        hyper: ``hyper(rows) -> traced hyperparameters`` with a leading batch axis.
        train: ``train(config, keys, hp, spec, sharding, checkpointer, progress) -> (metrics,
            params)`` for one group.
        curves: metrics are per-episode curves (summarised over the last tenth), else one
            final value per run.
        evaluates: runs can measure success rates at ``eval_at``.
    """

    fields: dict[str, Field]
    metrics: dict[str, str]
    unit: str
    length: Callable[[dict], int]
    config: Callable[[list[dict], dict], Any]
    hyper: Callable[[list[dict]], Any]
    train: Callable[..., tuple]
    curves: bool = False
    evaluates: bool = False


ADAPTERS: dict[str, Adapter] = {
    "al": Adapter(_FIELDS["al"], _METRICS["al"], "episodes",
                  lambda p: p["phase1_episodes"] + p["phase2_episodes"], _al_config, _al_hyper,
                  _run_al, curves=True, evaluates=True),
    "tl": Adapter(_FIELDS["tl"], _METRICS["tl"], "epochs", lambda p: p["epochs"], _tl_config,
                  tl.stack_hyper, _run_tl),
}
MODULES = tuple(ADAPTERS)
FIELDS = {name: a.fields for name, a in ADAPTERS.items()}
METRICS = {name: a.metrics for name, a in ADAPTERS.items()}


# ---------------------------------------------------------------------------------- the sweep
def _summaries(spec: SweepSpec, metrics: dict[str, np.ndarray], finite: np.ndarray) -> dict:
    """Per run value of the plotted metric, per point mean/std over the finite runs, and the
    learning curves (AL)."""
    n_pts = len(spec.points())
    adapter = ADAPTERS[spec.module]
    if spec.metric.startswith("success_"):  # [runs, evaluations]: the last one counts
        curve, window = metrics[spec.metric], None
        value = curve[:, -1]
    elif adapter.curves:
        curve = metrics[spec.metric]  # [runs, episodes of the longest run]
        lengths = np.repeat([adapter.length(p) for p in spec.points()], spec.seeds)
        if np.all(lengths == curve.shape[1]):
            window = max(1, curve.shape[1] // 10)
            value = curve[:, -window:].mean(1)
        else:  # static groups of other lengths (NaN-padded): each run's own last tenth
            window = None
            value = np.asarray([curve[r, n - max(1, n // 10): n].mean()
                                for r, n in enumerate(lengths)], curve.dtype)
    else:  # the final value after training
        curve, value, window = None, metrics[f"final_{spec.metric}"], None
    value = value.reshape(n_pts, spec.seeds)
    ok = finite.reshape(n_pts, spec.seeds)
    pts = []
    for i, p in enumerate(spec.points()):
        v = value[i][ok[i]]
        pts.append({"point": {k: p[k] for k in spec.grid},
                    "mean": float(v.mean()) if v.size else None,
                    "std": float(v.std()) if v.size else None,
                    "runs": [float(x) for x in value[i]],
                    "diverged": [int(s) for s in np.flatnonzero(~ok[i])]})
    ok_pts = [p for p in pts if p["mean"] is not None]
    sign = 1 if spec.metric in LOWER_IS_BETTER else -1
    out = {"metric": spec.metric, "window": window, "points": pts,
           "lower_is_better": sign == 1,
           "best": min(ok_pts, key=lambda p: sign * p["mean"])["point"] if ok_pts else None}
    if curve is not None:
        c = np.asarray(curve, np.float64).reshape(n_pts, spec.seeds, -1)
        out["curves"] = [np.where(ok[i][:, None], c[i], np.nan).tolist() for i in range(n_pts)]
    if spec.evaluations():
        out["evaluations"] = list(spec.evaluations())
        final = {k: np.asarray(metrics[f"success_{k}"])[:, -1].reshape(n_pts, spec.seeds)
                 for k in al_experiments.SUCCESS_METRICS}
        out["success"] = [{"point": p["point"], "rates": {
            k: {"median": float(np.median(v[i])), "min": float(v[i].min()),
                "max": float(v[i].max()), "runs": v[i].tolist()} for k, v in final.items()}}
            for i, p in enumerate(pts)]
    return out


def _csv_text(spec: SweepSpec, summary: dict) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    names = [f"success_{k}" for k in al_experiments.SUCCESS_METRICS] if "success" in summary \
        else []
    names = [k for k in names if k != spec.metric]
    w.writerow([*spec.grid, "seed", spec.metric, "diverged", *names])
    for i, p in enumerate(summary["points"]):
        for s, v in enumerate(p["runs"]):
            extra = [summary["success"][i]["rates"][k[len("success_"):]]["runs"][s]
                     for k in names]
            w.writerow([*p["point"].values(), s, v, int(s in p["diverged"]), *extra])
    return buf.getvalue()


def point_label(spec: SweepSpec, point: dict) -> str:
    """A point's name in figures and tables: its grid values, or for an ``axes`` design the
    one field that differs from the base point (``"base"`` for the base itself)."""
    if spec.design == "axes":
        centre = {k: v[0] for k, v in spec.grid.items()}
        changed = [f"{k}={v}" for k, v in point.items() if v != centre[k]]
        return ", ".join(changed) or "base"
    return ", ".join(f"{k}={v}" for k, v in point.items())


def _figure(spec: SweepSpec, summary: dict, out: pathlib.Path, staged: Staged) -> None:
    plt = pyplot()
    curves = "curves" in summary
    height = max(3.6, 0.3 * len(summary["points"])) if spec.design == "axes" else 3.6
    fig, axes = plt.subplots(1, 2 if curves else 1, figsize=(11 if curves else 5.5, height))
    axes = np.atleast_1d(axes)
    label = METRICS[spec.module][spec.metric]
    others = [k for k in spec.grid if k != spec.x]
    xs = [p["point"][spec.x] for p in summary["points"]]
    if curves:
        ax = axes[0]
        if len(summary["points"]) > 10:  # more lines than the default colour cycle
            ax.set_prop_cycle(color=plt.get_cmap("tab20").colors)
        for p, c, full in zip(summary["points"], summary["curves"], spec.points(),
                              strict=True):
            c = np.asarray(c, float)
            name = point_label(spec, p["point"])
            if not np.isfinite(c).any():
                continue
            if spec.metric.startswith("success_"):  # measured at the evaluation episodes
                ax.plot(summary["evaluations"], np.nanmedian(c, 0), marker="o", label=name)
                continue
            mean = np.nanmean(c[:, : ADAPTERS[spec.module].length(full)], 0)  # unpadded
            k = max(1, mean.size // 25)  # bins of k episodes
            bins = mean[: mean.size // k * k].reshape(-1, k).mean(1)
            ax.plot(np.arange(bins.size) * k + k / 2, bins, label=name)
        stat = "median" if spec.metric.startswith("success_") else "mean"
        ax.set(xlabel="episode", ylabel=spec.metric,
               title=f"learning curves, {stat} over seeds\n({label})")
        ax.legend(fontsize=7)
    ax = axes[-1]
    window = (f"mean of the last {summary['window']} episodes" if summary.get("window")
              else "mean of each run's last tenth" if curves and not
              spec.metric.startswith("success_") else "after training")
    if spec.design == "axes":  # one row per point, the base on top
        ps = summary["points"]
        ys = np.arange(len(ps))[::-1]
        ax.errorbar([np.nan if p["mean"] is None else p["mean"] for p in ps], ys,
                    xerr=[0 if p["std"] is None else p["std"] for p in ps], fmt="o",
                    capsize=3)
        ax.set_yticks(ys, [point_label(spec, p["point"]) for p in ps], fontsize=7)
        ax.set(xlabel=spec.metric, title=f"{label}, {window}\n(mean ± std over "
                                         f"{spec.seeds} seeds; one field changed at a time)")
        others = []
    groups: dict[tuple, list[dict]] = {}
    for p in summary["points"] if spec.design != "axes" else []:
        groups.setdefault(tuple(p["point"][k] for k in others), []).append(p)
    for key, ps in groups.items():
        ps = [p for p in ps if p["mean"] is not None]
        ax.errorbar([p["point"][spec.x] for p in ps], [p["mean"] for p in ps],
                    yerr=[p["std"] for p in ps], marker="o", capsize=3,
                    label=", ".join(f"{k}={v}" for k, v in zip(others, key, strict=True))
                    or None)
    positive = all(isinstance(v, (int, float)) and v > 0 for v in xs)
    if spec.design != "axes":
        if positive and max(xs) / min(xs) >= 100:
            ax.set_xscale("log")
        ax.set(xlabel=spec.x, ylabel=spec.metric,
               title=f"{label}, {window}\n(mean ± std over {spec.seeds} seeds)")
    if others:
        ax.legend(fontsize=7)
    adapter = ADAPTERS[spec.module]
    lengths = sorted({adapter.length(p) for p in spec.points()})
    fig.suptitle(f"{spec.title} ({'/'.join(map(str, lengths))} {adapter.unit})")
    fig.tight_layout()
    write_figure(out, spec.figure, {k: v for k, v in summary.items() if k != "curves"}, fig,
                 staged)


def run(spec: SweepSpec, out: str | pathlib.Path = "results/sweeps", resume: bool = False,
        overwrite: bool = False, executor: str = "local", ray_address: str | None = None,
        seed: int | None = None, show_progress: bool = True, key: jax.Array | None = None
        ) -> dict:
    """Run a sweep and write its results under ``out/<spec.name>``.

    The sweep's folder is locked while the sweep runs (a second writer is refused, with this
    one's pid); its result files (sweep.json, runs.csv, metrics.npz, the figure) replace the
    earlier ones together, only once all of them are written.

    Args:
        spec: a validated sweep (:func:`load_spec`).
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
    with contextlib.ExitStack() as stack:
        try:
            stack.enter_context(_guard.folder_lock(folder, f"sweep {spec.name}"))
        except OSError as e:
            raise SweepError(f"out: cannot write {folder} ({e.strerror or e}); name a "
                             "writable folder with --out") from None
        return _run_locked(spec, folder, resume, overwrite, executor, ray_address,
                           show_progress, key)


def _run_locked(spec: SweepSpec, folder: pathlib.Path, resume: bool, overwrite: bool,
                executor: str, ray_address: str | None, show_progress: bool,
                key: jax.Array | None) -> dict:
    if overwrite and (folder / "checkpoints").exists():
        shutil.rmtree(folder / "checkpoints")
    n_pts = len(spec.points())
    run_keys = _run_keys(spec, key)  # the one split
    groups = spec.groups()
    if resume and not any((folder / "checkpoints" / f"group{g}" / "steps").is_dir()
                          and any((folder / "checkpoints" / f"group{g}" / "steps").iterdir())
                          for g in range(len(groups))):
        print(f"note: nothing to resume in {folder} (no checkpoint was completed); "
              "starting from the beginning", file=sys.stderr, flush=True)
    per_run = ADAPTERS[spec.module].length  # a group's static values hold the run length
    total = sum(len(idx) * spec.seeds * per_run(s) for s, idx in groups)
    t0 = time.perf_counter()
    from tqdm.auto import tqdm

    with tqdm(total=total, unit=ADAPTERS[spec.module].unit.rstrip("s"), desc=spec.name,
              disable=not show_progress, dynamic_ncols=True, smoothing=0.1) as bar:
        if executor == "ray":
            results = _run_ray(spec, groups, run_keys, folder, resume, ray_address, bar, per_run)
        else:
            results = [run_group(spec, g, run_keys, folder, resume, bar.update)
                       for g in range(len(groups))]
    metrics, finite = _assemble(results, n_pts * spec.seeds)
    summary = {"name": spec.name, "source": spec.source, "spec": spec.to_json(),
               "groups": [{"static": s, "points": idx} for s, idx in groups],
               "executor": executor, "devices": jax.local_device_count(),
               "wall_s": time.perf_counter() - t0,
               "diverged_runs": int((~finite).sum()), **_summaries(spec, metrics, finite)}
    try:
        with Staged(folder).writing() as staged:
            staged.write_text("runs.csv", _csv_text(spec, summary))
            _figure(spec, summary, folder, staged)
            staged.write_text("sweep.json", json.dumps(summary, indent=1) + "\n")
            np.savez(staged.path("metrics.npz"), finite=finite, **metrics)
    except OSError as e:
        raise SweepError(f"out: cannot write the results in {folder} ({e.strerror or e}); "
                         "the earlier results there and the checkpoints are kept") from None
    return summary


def _assemble(results: list[dict], n_rows: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The groups' metrics in one array per metric (row ``point * seeds + seed``). Groups of
    other run lengths (a grid over a static length field) give curves of other lengths: the
    shorter ones are padded with NaN."""
    metrics = {}
    for k in results[0]["metrics"]:
        parts = [np.asarray(r["metrics"][k]) for r in results]
        shape = tuple(max(d) for d in zip(*(a.shape[1:] for a in parts), strict=True))
        ragged = any(a.shape[1:] != shape for a in parts)
        dtype = np.result_type(parts[0].dtype, np.float32) if ragged else parts[0].dtype
        arr = np.full((n_rows, *shape), np.nan, dtype) if ragged else np.zeros(
            (n_rows, *shape), dtype)
        for r, a in zip(results, parts, strict=True):
            arr[(r["rows"], *(slice(0, d) for d in a.shape[1:]))] = a
        metrics[k] = arr
    finite = np.zeros(n_rows, bool)
    for r in results:
        finite[r["rows"]] = r["finite"]
    return metrics, finite


def _run_ray(spec, groups, run_keys, folder, resume, address, bar, per_run) -> list[dict]:
    try:
        import ray
    except ImportError:
        raise SweepError("executor: 'ray' needs Ray: pip install 'grounding-jax[ray]'") from None
    if not ray.is_initialized():
        ray.init(address=address)
    task = ray.remote(_ray_task)
    pending = {task.remote(spec, g, run_keys, str(folder), resume): g
               for g in range(len(groups))}
    results = []
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        g = pending.pop(ready[0])
        results.append(ray.get(ready[0]))
        s, idx = groups[g]
        bar.update(len(idx) * spec.seeds * per_run(s))
    return results


def _ray_task(spec: SweepSpec, group: int, run_keys: np.ndarray, folder: str,
              resume: bool) -> dict:
    """A Ray worker's share: one static group (checkpoints in the shared output folder)."""
    import grounding_jax

    grounding_jax.enable_compilation_cache()  # the worker is a process of ours, as the CLI is
    return jax.device_get(run_group(spec, group, run_keys, pathlib.Path(folder), resume))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m grounding_jax.sweep",
                                 description="Run a hyperparameter sweep from a TOML file.")
    ap.add_argument("file", help="sweep file, e.g. sweeps/fig8a_critic_lr.toml")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a key: seeds=2, critic_lr=0.01,0.1, phase2_episodes=100")
    ap.add_argument("--out", default="results/sweeps", help="parent output folder")
    ap.add_argument("--seed", type=int, default=None, help="overrides the file's seed")
    ap.add_argument("--resume", action="store_true", help="continue from the checkpoints")
    ap.add_argument("--overwrite", action="store_true",
                    help="delete the sweep's earlier checkpoints and start over")
    ap.add_argument("--executor", default="local", help=f"one of {EXECUTORS}")
    ap.add_argument("--ray-address", default=None,
                    help="Ray cluster address, e.g. ray://head:10001 (default: local cluster)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    import grounding_jax

    grounding_jax.enable_compilation_cache()
    try:
        with _guard.handle_interrupts():
            if args.executor not in EXECUTORS:
                raise SweepError(f"--executor: unknown value {args.executor!r}; accepted "
                                 f"values: {EXECUTORS}")
            spec = load_spec(args.file, args.set)
            summary = run(spec, args.out, resume=args.resume, overwrite=args.overwrite,
                          executor=args.executor, ray_address=args.ray_address,
                          seed=args.seed, show_progress=not args.no_progress)
    except (SweepError, CheckpointError, _guard.FolderBusyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a disk or folder fault outside the paths above
        print(f"error: {e.filename or args.out}: {e.strerror or e}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, _guard.Interrupted) as e:
        print(f"\ninterrupted ({'SIGINT' if isinstance(e, KeyboardInterrupt) else e}): the "
              "newest complete checkpoint of each group is kept; continue with:\n  "
              f"{resume_command(argv)}", file=sys.stderr, flush=True)
        if argv is None:  # the command line (not a caller's process): end it now
            _guard.leave(_guard.exit_code(e))
        return _guard.exit_code(e)
    folder = pathlib.Path(args.out) / spec.name
    for p in summary["points"]:
        mean = "diverged" if p["mean"] is None else f"{p['mean']:.4g} ± {p['std']:.2g}"
        flag = f"  ({len(p['diverged'])} diverged)" if p["diverged"] else ""
        print(f"{p['point']}: {spec.metric} {mean}{flag}")
    for p in summary.get("success", []):
        print(f"{p['point']}: success of the median run at episode "
              f"{summary['evaluations'][-1]}: " + ", ".join(
                  f"{k} {p['rates'][k]['median']:.2f}" for k in al_experiments.SUCCESS_METRICS))
    print(f"wrote {folder}/ (sweep.json, runs.csv, {spec.figure}.png) in "
          f"{summary['wall_s']:.1f} s")
    return 0


def resume_command(argv: list[str] | None = None) -> str:
    """The command line that continues this one: the same arguments with ``--resume``
    instead of ``--overwrite``."""
    return _guard.resume_command(["python", "-m", "grounding_jax.sweep"], argv)


if __name__ == "__main__":
    sys.exit(main())
