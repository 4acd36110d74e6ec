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

from grounding_jax.core._checks import FLOAT32_MAX, Rule


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
    modules, and imports none: adapters are registered from above (:func:`register`, or the
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
            checkpoint`` with an ``"agents"`` entry, for :func:`~grounding_jax.sweep.runner.
            trained_agents`; None: its agents cannot be read back.
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


#: the sweepable fields and the plottable metrics of every registered module
FIELDS: Mapping[str, dict[str, Field]] = _View("fields")
METRICS: Mapping[str, dict[str, str]] = _View("metrics")
TOP_KEYS = {"name": str, "module": str, "figure": str, "title": str, "description": str,
            "seeds": int, "metric": str, "x": str, "chunk": int, "seed": int, "paper": str,
            "params": dict, "grid": dict, "eval_at": list, "design": str}
#: how a grid becomes points: every combination, or one field at a time around a base point
DESIGNS = ("product", "axes")


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
        found = adapter(self.module)
        if not found.evaluates or not (self.eval_at or self.metric.startswith("success_")):
            return ()
        return tuple(sorted(set(self.eval_at) | {found.length(self.points()[0])}))

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
    if module not in adapters():
        raise _err(source, "module", f"unknown module {module!r}; accepted values: "
                                     f"{tuple(adapters())}")
    adapter_ = adapter(module)
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
                     design=design)
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



def module_config(spec: SweepSpec, static: dict[str, Any]):
    """The static config of the group with static values ``static`` (the adapter's)."""
    return adapter(spec.module).config(spec.points(), static)
