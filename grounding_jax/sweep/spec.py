"""Sweep files: the spec, its validation, and the adapters through which the runner knows
modules.

Hyperparameter sweeps from TOML files: ``python -m grounding_jax.sweep FILE [--set k=v]``.

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

Instead of a grid, ``search = "random" | "optuna" | "asha" | "pbt"`` searches a ``[space]``
of ranges (`space`) with ``trials`` configurations, and
``holdout_seeds`` retrains the winner on fresh seeds (`search`)::

    search = "asha"
    trials = 27
    holdout_seeds = 8
    [space]
    actor_lr = { log = [1e-4, 1e-1] }
    sigma = { uniform = [0.05, 0.3] }
    [asha]
    eta = 3
    rungs = [150, 450, 1200]
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import pathlib
import tomllib
from collections.abc import Callable, Mapping, Sequence
from importlib import metadata
from typing import Any

from grounding_jax.core.checks import FLOAT32_MAX, Rule


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

    def __repr__(self) -> str:
        accepted = f"one of {self.choices}" if self.choices else self.rule
        return (f"Field({self.kind} {self.type.__name__}, default {self.default!r}"
                + (f", {accepted}" if accepted else "") + ")")




def field_from(kind: str, rule: Rule, default: Any) -> Field:
    """A field checked by its dataclass's own rule (one table serves both).

    Args:
        kind: ``"static"`` (grouped: one compile per value) or ``"traced"`` (vmapped).
        rule: the dataclass's rule for the value.
        default: the value when a sweep does not set it.
    """
    return Field(kind, rule.type, default, rule.text, rule.holds)


def traced_fields(rules: dict[str, Rule], defaults: Any, names: Sequence[str] | None = None
                  ) -> dict[str, Field]:
    """Traced fields named ``names`` (default: all of ``rules``), their defaults read from
    the dataclass instance ``defaults``."""
    return {n: field_from("traced", rules[n], getattr(defaults, n)) for n in (names or rules)}


@dataclasses.dataclass(frozen=True)
class Adapter:
    """What the sweep runner needs from one module; the runner itself does not branch on
    modules, and imports none: adapters are registered from above (`register`, or the
    ``grounding_jax.sweep_adapters`` entry point group, which names the package's own).

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
        success: the names of those rates (metrics ``success_<name>``).
        lower_is_better: the metrics where lower is better (for the others higher is).
        saved_like: ``saved_like(config, keys, n_evals) -> the structure of a group's
            checkpoint`` with an ``"agents"`` entry, for `
            trained_agents`; None: its agents cannot be read back.
        pieces: ``pieces(config) -> Pieces`` for one group's static config, or None: the
            module trains in one piece (grid, random and Optuna searches only).
        run_bytes: ``run_bytes(config, spec) -> bytes`` one run of a group takes while its
            batch trains (an estimate: a grid too big for memory is refused before anything
            compiles); None: not estimated.
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
    success: tuple[str, ...] = ()
    lower_is_better: frozenset[str] = frozenset()
    saved_like: Callable[..., Any] | None = None
    pieces: Callable[[Any], Pieces] | None = None
    run_bytes: Callable[[Any, Any], int] | None = None


@dataclasses.dataclass(frozen=True)
class Pieces:
    """How a module trains a batch of runs piece by piece, which ASHA and PBT need: runs
    start, stop, take new hyperparameters and copy each other's agents at chunk ends.

    Attributes:
        start: ``start(keys, hp) -> state``: fresh runs, one per key (a pytree whose leaves
            have a leading run axis; its ``"agent"`` entry is what PBT copies from run to run,
            the rest -- each run's own random stream and counters -- stays with the run).
        advance: ``advance(state, hp, units) -> (state, metrics)``: every run trains ``units``
            more episodes (epochs) with its own hyperparameters ``hp`` (batched like
            ``Adapter.hyper``'s); ``metrics`` are per-unit curves ``{name: [runs, units]}``.
        rates: ``rates(state, hp) -> {name: [runs]}``: the success rates of ``Adapter.success``
            (None: the module has none).
    """

    start: Callable[..., Any]
    advance: Callable[..., tuple]
    rates: Callable[..., dict] | None = None


#: the entry point group where packages name their adapters (``name = "module:ADAPTER"``)
ENTRY_POINTS = "grounding_jax.sweep_adapters"
_REGISTRY: dict[str, Adapter] = {}
_LOADED = [False]


def register(name: str, adapter: Adapter) -> None:
    """Make ``module = "<name>"`` sweeps run through ``adapter`` (replaces an earlier one)."""
    if not isinstance(adapter, Adapter):
        raise TypeError(f"adapter: expected an Adapter, got {type(adapter).__name__}")
    _REGISTRY[name] = adapter


def adapters() -> dict[str, Adapter]:
    """The registered adapters by module name; the entry points' are loaded on first use."""
    if not _LOADED[0]:
        for ep in metadata.entry_points(group=ENTRY_POINTS):
            if ep.name not in _REGISTRY:  # one registered in the program comes first
                _REGISTRY[ep.name] = ep.load()
        _LOADED[0] = True  # only once all loaded: a failed load is raised again next time
    return _REGISTRY


def adapter(module: str) -> Adapter:
    """The adapter of ``module``.

    Raises:
        SweepError: none registered under that name (the message lists those that are).
    """
    found = adapters()
    if module not in found:
        raise SweepError(f"module: unknown module {module!r}; accepted values: "
                         f"{tuple(found)} (is the package installed? pip install -e .)")
    return found[module]


class _View(Mapping):
    """A read-only view of one attribute of every registered adapter (``FIELDS["al"]``)."""

    def __init__(self, attr: str) -> None:
        self._attr = attr

    def __getitem__(self, module: str) -> Any:
        if module not in adapters():
            raise KeyError(module)
        return getattr(adapters()[module], self._attr)

    def __iter__(self):
        return iter(adapters())

    def __len__(self) -> int:
        return len(adapters())

    def __repr__(self) -> str:
        lines = []
        for module in self:
            lines.append(f"{module}:")
            lines += [f"  {name}: {value!r}" for name, value in self[module].items()]
        return "\n".join(lines)


#: the sweepable fields and the plottable metrics of every registered module
FIELDS: Mapping[str, dict[str, Field]] = _View("fields")
METRICS: Mapping[str, dict[str, str]] = _View("metrics")
TOP_KEYS = {"name": str, "module": str, "figure": str, "title": str, "description": str,
            "seeds": int, "metric": str, "x": str, "chunk": int, "seed": int, "paper": str,
            "params": dict, "grid": dict, "eval_at": list, "design": str,
            "search": str, "trials": int, "holdout_seeds": int, "space": dict,
            "asha": dict, "pbt": dict, "optuna": dict}
#: how a grid becomes points: every combination, or one field at a time around a base point
#: ("list": the grid's columns zipped, point i taking the i-th value of each -- how a search
#: hands its drawn points to the runner)
DESIGNS = ("product", "axes")
#: how points are chosen: a grid, or a search over ``[space]``
SEARCHES = ("grid", "random", "optuna", "asha", "pbt")
#: the keys of each strategy's own table, with their types
SECTION_KEYS = {"asha": {"eta": int, "rungs": list, "batch": int, "brackets": int},
                "pbt": {"interval": int, "fraction": float, "resample": float},
                "optuna": {"sampler": str, "batch": int}}
#: Optuna samplers by name
SAMPLERS = ("tpe", "cmaes", "gp")


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
    search: str = "grid"
    trials: int = 0
    holdout_seeds: int = 0
    space: dict[str, Any] = dataclasses.field(default_factory=dict)  # name -> space.Dim
    asha: dict[str, Any] = dataclasses.field(default_factory=dict)
    pbt: dict[str, Any] = dataclasses.field(default_factory=dict)
    optuna: dict[str, Any] = dataclasses.field(default_factory=dict)

    def base(self) -> dict[str, Any]:
        """Every field of the module at its default, with ``[params]`` applied."""
        return {k: f.default for k, f in FIELDS[self.module].items()} | self.params

    def evaluations(self) -> tuple[int, ...]:
        """Episode counts at which AL success rates are measured: ``eval_at`` plus the end,
        or none when neither ``eval_at`` nor a ``success_*`` metric asks for them."""
        found = adapter(self.module)
        if not found.evaluates or not (self.eval_at or self.metric.startswith("success_")):
            return ()
        return tuple(sorted(set(self.eval_at) | {found.length(self.points()[0])}))

    def points(self) -> list[dict[str, Any]]:
        """The grid's points, as full assignments of the module's fields: every combination
        (``design = "product"``), or (``"axes"``) the base point -- each grid field at its
        first value -- then each field's other values, one field changed at a time; the
        grid's columns zipped (``"list"``). A search's spec (``search`` other than grid) gives
        the points that bound its space (the module config built for them holds any point
        the search may draw)."""
        base = self.base()
        if self.search != "grid":
            from grounding_jax.sweep.space import bounds

            return [base | b for b in bounds(self.space)]
        keys = list(self.grid)
        if self.design == "list":
            return [base | {k: self.grid[k][i] for k in keys}
                    for i in range(len(self.grid[keys[0]]))]
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
        """The spec as parse_spec accepts it back (tuples as lists; a grid's spec without
        the search keys it does not use, as before there were searches)."""
        out = {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v
               for f in dataclasses.fields(self) if f.name != "source"}
        out["space"] = {n: d.to_json() for n, d in self.space.items()}
        unused = (("search", "grid"), ("trials", 0), ("holdout_seeds", 0), ("space", {}),
                  ("asha", {}), ("pbt", {}), ("optuna", {}))
        return {k: v for k, v in out.items() if (k, v) not in unused}


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
    if module not in adapters():
        raise _err(source, "module", f"unknown module {module!r}; accepted values: "
                                     f"{tuple(adapters())}")
    adapter_ = adapter(module)
    fields = FIELDS[module]
    params, grid = dict(data.get("params", {})), dict(data.get("grid", {}))
    search = data.get("search", "grid")
    if search not in SEARCHES:
        raise _err(source, "search", f"unknown strategy {search!r}; accepted values: "
                                     f"{SEARCHES}")
    if search != "grid" and grid:
        raise _err(source, f"grid.{next(iter(grid))}", f"search = {search!r} draws its points "
                   "from [space]: give this field a range or choices there (or set search = "
                   "\"grid\")")
    if not grid and search == "grid":
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
    found = _parse_search(source, data, module, params, search)
    swept = grid if search == "grid" else found["space"]
    x = data.get("x", next(iter(swept)))
    if x not in swept:
        where = "grid" if search == "grid" else "space"
        raise _err(source, "x", f"{x!r} is not a {where} field; {where} fields: {list(swept)}")
    design = data.get("design", "product")
    if design not in DESIGNS:
        raise _err(source, "design", f"unknown value {design!r}; accepted values: {DESIGNS}")
    eval_at = data.get("eval_at", [])
    if eval_at and not adapter_.evaluates:
        raise _err(source, "eval_at", "only AL sweeps evaluate success rates")
    if not all(isinstance(e, int) and not isinstance(e, bool) and e >= 1 for e in eval_at):
        raise _err(source, "eval_at", f"must be a list of episode counts >= 1, got {eval_at!r}")
    name = data.get("name", pathlib.Path(source).stem if source != "<dict>" else "sweep")
    spec = SweepSpec(name=name, module=module, figure=data.get("figure", name),
                     title=data.get("title", name), seeds=seeds, metric=metric, x=x,
                     chunk=chunk, seed=data.get("seed", 0), params=params, grid=grid,
                     source=source, description=data.get("description", ""),
                     paper=data.get("paper", ""), eval_at=tuple(sorted(set(eval_at))),
                     design=design, search=search, **found)
    if search != "grid":
        _check_schedule(spec)
    if adapter_.evaluates and (eval_at or metric.startswith("success_")):
        lengths = {adapter_.length(p) for p in spec.points()}
        if len(lengths) > 1:
            raise _err(source, "grid", "success evaluation needs one episode count for all "
                                       f"points; phase1/phase2_episodes give {sorted(lengths)}")
        if eval_at and max(eval_at) > min(lengths):
            raise _err(source, "eval_at", f"{max(eval_at)} is past the run's {min(lengths)} "
                                          "episodes; accepted: 1..episodes")
    for static, _ in spec.groups():  # the module's own checks (cross-field rules)
        try:
            module_config(spec, static)
        except ValueError as e:
            raise SweepError(f"{source}: {e}") from None
    return spec


def _parse_search(source: str, data: dict, module: str, params: dict, search: str) -> dict:
    """The search keys of a sweep (``trials``, ``holdout_seeds``, ``[space]`` and the
    strategy's own table), checked; SweepError names the bad key."""
    from grounding_jax.sweep.space import parse_dim

    holdout = data.get("holdout_seeds", 0)
    if holdout < 0:
        raise _err(source, "holdout_seeds", f"must be an integer >= 0, got {holdout!r}")
    out: dict[str, Any] = {"holdout_seeds": holdout}
    given = [k for k in ("trials", "space", *SECTION_KEYS) if k in data]
    if search == "grid":
        if given:
            raise _err(source, given[0], f"only for a search (search = one of "
                                         f"{SEARCHES[1:]}); a grid sweeps [grid]")
        return out
    trials = data.get("trials", 16)
    if trials < 1:
        raise _err(source, "trials", f"must be an integer >= 1, got {trials!r}")
    fields = FIELDS[module]
    table = data.get("space", {})
    if not table:
        raise _err(source, "space", f"empty: search = {search!r} needs at least one field "
                                    "with a range or choices")
    space = {}
    for name, entry in table.items():
        if name not in fields:
            raise _err(source, f"space.{name}", f"unknown field for module {module!r}; "
                                                f"accepted fields: {sorted(fields)}")
        if fields[name].kind != "traced":
            traced = sorted(k for k, f in fields.items() if f.kind == "traced")
            raise _err(source, f"space.{name}", "a static field (it changes the compiled "
                       "program, so it cannot vary inside one batch, nor be perturbed there); "
                       f"set it in [params] or sweep it with a grid; searchable (traced) "
                       f"fields: {traced}")
        if name in params:
            raise _err(source, f"space.{name}", "also set in [params]; set it in one place")
        space[name] = parse_dim(name, entry, fields[name].type,
                                lambda key, v: _check_value(source, module, key, v),
                                lambda key, msg: _err(source, key, msg))
    # a file may hold every strategy's table (each is checked); the search's own is used
    tables = {k: _section(source, k, data.get(k, {}), trials, k == search)
              for k in SECTION_KEYS if k in data or k == search}
    if search in ("asha", "pbt") and adapter(module).pieces is None:
        raise _err(source, "search", f"{search!r} trains runs piece by piece and moves them "
                   f"inside the batch; module {module!r} trains in one piece: use one of "
                   "('grid', 'random', 'optuna')")
    out |= {"trials": trials, "space": space}
    if search in SECTION_KEYS:
        out[search] = tables[search]
    return out


def _section(source: str, name: str, table: Any, trials: int, active: bool) -> dict:
    """One strategy's table, checked, with its defaults (``active``: the search's own)."""
    if not isinstance(table, dict):
        raise _err(source, name, f"must be a table ([{name}] with one key per line), got "
                                 f"{table!r}")
    opts = dict(table)
    for k, v in opts.items():
        want = SECTION_KEYS[name].get(k)
        if want is None:
            raise _err(source, f"{name}.{k}", f"unknown key; accepted keys: "
                                                f"{sorted(SECTION_KEYS[name])}")
        ok = (isinstance(v, (int, float)) and not isinstance(v, bool) if want is float else
              isinstance(v, want) and not (want is int and isinstance(v, bool)))
        if not ok:
            raise _err(source, f"{name}.{k}", f"expected {want.__name__}, got {v!r}")
    if name == "asha":
        opts.setdefault("eta", 3)
        if opts["eta"] < 2:
            raise _err(source, "asha.eta", f"must be an integer >= 2 (the share 1/eta of the "
                                           f"runs at a rung that go on), got {opts['eta']!r}")
        opts.setdefault("batch", max(1, math.ceil(trials / opts["eta"])))
        opts.setdefault("brackets", 1)
        if opts["brackets"] < 1 or (active and opts["brackets"] > trials):
            raise _err(source, "asha.brackets", f"must be an integer in [1, trials = "
                                                f"{trials}], got {opts['brackets']!r}")
        if opts["batch"] < 1:
            raise _err(source, "asha.batch", f"must be an integer >= 1, got {opts['batch']!r}")
    elif name == "pbt":
        opts.setdefault("fraction", 0.25)
        opts.setdefault("resample", 0.25)
        if not 0 < opts["fraction"] <= 0.5:
            raise _err(source, "pbt.fraction", f"must be in (0, 0.5] (the bottom and the top "
                                               f"share), got {opts['fraction']!r}")
        if not 0 <= opts["resample"] <= 1:
            raise _err(source, "pbt.resample", f"must be in [0, 1], got {opts['resample']!r}")
        if active and trials < 2:
            raise _err(source, "trials", f"PBT needs a population of at least 2, got {trials}")
    elif name == "optuna":
        opts.setdefault("sampler", "tpe")
        opts.setdefault("batch", 8)
        if opts["sampler"] not in SAMPLERS:
            raise _err(source, "optuna.sampler", f"unknown sampler {opts['sampler']!r}; "
                                                 f"accepted values: {SAMPLERS}")
        if opts["batch"] < 1:
            raise _err(source, "optuna.batch", f"must be an integer >= 1, got "
                                               f"{opts['batch']!r}")
        if active:
            _check_optuna(source, opts["sampler"])
    return opts


def _check_optuna(source: str, sampler: str) -> None:
    """Optuna (and, for its sampler, cmaes or torch) can be imported, before anything runs."""
    needs = {"tpe": [], "cmaes": ["cmaes"], "gp": ["torch", "scipy"]}[sampler]
    import importlib.util

    for name in ["optuna", *needs]:
        if importlib.util.find_spec(name) is None:
            raise _err(source, "optuna.sampler" if name != "optuna" else "search",
                       f"{sampler!r} needs the package {name!r}: pip install {name}")


def _check_schedule(spec: SweepSpec) -> None:
    """ASHA's rungs and PBT's interval against the run's length and ``chunk``."""
    source, found = spec.source, adapter(spec.module)
    length = found.length(spec.base())
    chunks = length // spec.chunk
    if spec.search == "asha":
        rungs = spec.asha.get("rungs")
        if rungs is None:  # every eta-th of the length, on chunk ends
            rungs, r = [length], length
            while (r := r / spec.asha["eta"]) >= spec.chunk:
                rungs.insert(0, max(spec.chunk, round(r / spec.chunk) * spec.chunk))
            rungs = sorted(set(rungs))
            spec.asha["rungs"] = rungs
        if len(rungs) > max(chunks, 1):
            raise _err(source, "asha.rungs", f"{len(rungs)} rungs but the run has only "
                       f"{chunks} chunks ({length} {found.unit} / chunk {spec.chunk}); a rung "
                       "is ranked at a chunk's end: fewer rungs or a smaller chunk")
        if not all(isinstance(r, int) and not isinstance(r, bool) for r in rungs) \
                or sorted(set(rungs)) != rungs or not rungs:
            raise _err(source, "asha.rungs", f"must be increasing {found.unit} counts, got "
                                             f"{rungs!r}")
        bad = [r for r in rungs if r % spec.chunk or r < 1]
        if bad:
            raise _err(source, "asha.rungs", f"{bad[0]} is not a multiple of chunk "
                       f"{spec.chunk} (runs are ranked at chunk ends)")
        if spec.asha["brackets"] > len(rungs):
            raise _err(source, "asha.brackets", f"{spec.asha['brackets']} brackets but "
                       f"{len(rungs)} rungs: bracket b is first ranked at rung b, so at most "
                       "one bracket per rung")
        if rungs[-1] != length:
            raise _err(source, "asha.rungs", f"the last rung must be the run's length "
                       f"({length} {found.unit}), got {rungs[-1]}: the runs that pass every "
                       "rung train to the end")
    if spec.search == "pbt":
        spec.pbt.setdefault("interval", max(spec.chunk, (length // 8) // spec.chunk
                                            * spec.chunk))
        interval = spec.pbt["interval"]
        if interval < 1 or interval % spec.chunk:
            raise _err(source, "pbt.interval", f"must be a multiple of chunk {spec.chunk} "
                       f"(members are ranked at chunk ends), got {interval!r}")
        if interval >= length:
            raise _err(source, "pbt.interval", f"must be shorter than the run ({length} "
                       f"{found.unit}), got {interval}")
        if length % spec.chunk:
            raise _err(source, "chunk", f"PBT needs chunks that divide the run ({length} "
                                        f"{found.unit}), got {spec.chunk}")
    if spec.search == "asha" and length % spec.chunk:
        raise _err(source, "chunk", f"ASHA needs chunks that divide the run ({length} "
                                    f"{found.unit}), got {spec.chunk}")


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
        section, dot, sub = key.partition(".")
        if dot and section in ("space", *SECTION_KEYS) and sub:
            if not isinstance(data.get(section, {}), dict):
                raise _err(source, section, f"must be a table, got {data[section]!r}")
            data[section] = {**data.get(section, {}), sub: value}
        elif key in data["grid"]:
            data["grid"][key] = value if isinstance(value, list) else [value]
        elif key in TOP_KEYS and key not in ("params", "grid", "space", *SECTION_KEYS):
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



def module_config(spec: SweepSpec, static: dict[str, Any]):
    """The static config of the group with static values ``static`` (the adapter's)."""
    return adapter(spec.module).config(spec.points(), static)
