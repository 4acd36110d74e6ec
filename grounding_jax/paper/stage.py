"""Stages: one experiment, one file, run by ``train.py`` after the paper's parts.

A `Stage` is a name, a typed config (a frozen dataclass whose defaults are the quick
profile's; ``profiles`` changes fields for the others), ``run(key, inputs, out, config) ->
dict`` (its metrics, JSON-able: they land in ``metrics.json`` under ``stages.<name>.result``)
and ``report(metrics, config) -> str`` (its section of ``REPORT.md``, Markdown).

The package's own stages are the modules of `grounding_jax.paper.stages` (each defines
``STAGE``); another package adds its own through the ``grounding_jax.stages`` entry-point
group (``name = "package.module:STAGE"``) or `register`. Every stage's key is derived from
the run's one key and the stage's name (`stage_key`): adding a stage leaves the others'
results as they were. ``python train.py --set <stage>.<field>=<value>`` changes a field,
``--only <stage>`` runs one stage again on the modules a whole run saved.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import pathlib
import pkgutil
import re
import time
import types
import typing
import zlib
from collections.abc import Callable, Mapping
from importlib import metadata
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import jax

ENTRY_POINTS = "grounding_jax.stages"
_NAME = re.compile(r"[a-z][a-z0-9_]*")
_REGISTRY: dict[str, Stage] = {}
_LOADED = [False]


@dataclasses.dataclass(frozen=True)
class Inputs:
    """What a stage gets from the run before it (read it, do not change it)."""

    #: the folder of the saved robot: ``grounding_jax.load(inputs.modules)``
    modules: pathlib.Path
    profile: str
    backend: str
    seed: int
    #: ``metrics.json``'s fields of the parts run before (``al``, ``an``, ``beyond``, ...)
    results: Mapping[str, Any] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class Stage:
    """One experiment of a run (see the module doc)."""

    name: str
    title: str
    config: type
    run: Callable[[jax.Array, Inputs, pathlib.Path, Any], dict]
    report: Callable[[dict, Any], str]
    profiles: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not _NAME.fullmatch(self.name):
            raise ValueError(f"name: {self.name!r} is not accepted; accepted: lowercase "
                             "letters, digits and _, starting with a letter")
        if not (isinstance(self.config, type) and dataclasses.is_dataclass(self.config)):
            raise TypeError(f"config: expected a dataclass type, got {self.config!r}")
        for profile in self.profiles:  # a profile's bad field fails at registration
            self.make_config(profile)

    def make_config(self, profile: str, changes: Mapping[str, Any] | None = None) -> Any:
        """The stage's config for ``profile`` with ``changes`` (field -> value, or the text
        of a command line's ``--set``).

        Raises:
            ValueError: an unknown field (the message lists the accepted ones) or a bad value
                (it names the field).
        """
        values = dict(self.profiles.get(profile, {}))
        values.update(changes or {})
        hints = typing.get_type_hints(self.config)
        accepted = [f.name for f in dataclasses.fields(self.config)]
        parsed = {}
        for field, value in values.items():
            if field not in accepted:
                raise ValueError(f"--set {self.name}.{field}: unknown field; accepted fields "
                                 f"of stage {self.name!r}: {accepted}")
            parsed[field] = _coerce(f"{self.name}.{field}", hints[field], value)
        try:
            return self.config(**parsed)
        except (TypeError, ValueError) as e:
            raise ValueError(f"--set {self.name}: {e}") from None


def _coerce(field: str, hint: Any, value: Any) -> Any:
    """``value`` (a JSON value, or command-line text) as the type ``hint`` names."""
    if typing.get_origin(hint) is tuple:
        item = typing.get_args(hint)[0]
        if isinstance(value, str):
            value = [v for v in value.split(",") if v.strip()]
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"--set {field}: expected a comma-separated list, got {value!r}")
        return tuple(_coerce(field, item, v) for v in value)
    if isinstance(hint, types.UnionType) or hint not in (int, float, bool, str):
        raise TypeError(f"{field}: field type {hint!r} is not accepted; accepted: int, float, "
                        "bool, str and tuple[<one of those>, ...]")
    if hint is bool:
        text = str(value).strip().lower()
        if text not in ("true", "false", "1", "0"):
            raise ValueError(f"--set {field}: expected true or false, got {value!r}")
        return text in ("true", "1")
    try:
        out = hint(value.strip() if isinstance(value, str) else value)
    except (TypeError, ValueError):
        raise ValueError(f"--set {field}: expected {hint.__name__}, got {value!r}") from None
    if hint is int and isinstance(value, float) and value != out:
        raise ValueError(f"--set {field}: expected int, got {value!r}")
    return out


def register(stage: Stage) -> None:
    """Run ``stage`` in every run of this process (replaces one of the same name)."""
    if not isinstance(stage, Stage):
        raise TypeError(f"stage: expected a Stage, got {type(stage).__name__}")
    stages()
    _REGISTRY[stage.name] = stage


def stages() -> dict[str, Stage]:
    """The registered stages by name, in the order they run (by name): the package's own
    (the modules of `grounding_jax.paper.stages`) and the entry points', loaded on first
    use."""
    if not _LOADED[0]:
        from grounding_jax.paper import stages as own

        found = [importlib.import_module(f"{own.__name__}.{m.name}").STAGE
                 for m in pkgutil.iter_modules(own.__path__)]
        found += [ep.load() for ep in metadata.entry_points(group=ENTRY_POINTS)]
        for s in found:
            _REGISTRY.setdefault(s.name, s)  # one registered in the program comes first
        _LOADED[0] = True
    return dict(sorted(_REGISTRY.items()))


def configs(profile: str, items: list[str]) -> dict[str, Any]:
    """Every stage's config for ``profile`` with the command line's ``<stage>.<field>=<value>``
    changes ``items``.

    Raises:
        ValueError: an unknown stage or field, or a bad value (named in the message).
    """
    known = stages()
    changes: dict[str, dict[str, str]] = {name: {} for name in known}
    for item in items:
        target, sep, value = item.partition("=")
        name, dot, field = target.partition(".")
        if not sep or not dot:
            raise ValueError(f"--set {item!r}: expected <stage>.<field>=<value>")
        if name not in known:
            raise ValueError(f"--set {item!r}: unknown stage {name!r}; accepted stages: "
                             f"{list(known)}")
        changes[name][field] = value
    return {name: s.make_config(profile, changes[name]) for name, s in known.items()}


def stage_key(key: jax.Array, name: str) -> jax.Array:
    """The stage's key: derived from the run's stage key and the stage's name only."""
    import jax

    return jax.random.fold_in(key, zlib.crc32(name.encode()) & 0x7FFFFFFF)


def run(stage: Stage, key: jax.Array, inputs: Inputs, out: pathlib.Path, config: Any
        ) -> dict:
    """``stage`` run into ``out`` (its folder) with its key from ``key``; returns the entry
    ``metrics.json`` keeps under ``stages.<name>``: ``config``, ``result`` and ``wall_s``."""
    t = time.perf_counter()
    result = stage.run(stage_key(key, stage.name), inputs, pathlib.Path(out), config)
    json.dumps(result)  # a result that cannot be written fails here, not after the run
    return {"config": dataclasses.asdict(config), "result": result,
            "wall_s": time.perf_counter() - t}


def run_all(key: jax.Array, inputs: Inputs, out: pathlib.Path, configs: Mapping[str, Any]
            ) -> dict:
    """Every stage of ``configs`` (name -> config, see `configs`) in order, each into
    ``out/<name>``; returns ``metrics.json``'s ``stages`` (name -> `run`'s entry)."""
    known = stages()
    done = {}
    for name, config in configs.items():
        done[name] = run(known[name], key, inputs, pathlib.Path(out) / name, config)
        print(f"stage {name}: {done[name]['wall_s']:.1f} s", flush=True)
    return done


def report_sections(result: Mapping[str, Any]) -> list[str]:
    """The REPORT's sections of the stages in ``result`` (a run's metrics), as lines."""
    lines: list[str] = []
    known = stages()
    for name, entry in (result.get("stages") or {}).items():
        if name not in known:
            lines += ["", f"## Stage `{name}`", "",
                      "Not registered in this installation: its result is in metrics.json."]
            continue
        s = known[name]
        config = s.make_config(result.get("profile", ""), entry["config"])
        lines += ["", f"## {s.title}", "", s.report(entry["result"], config).rstrip()]
    return lines
