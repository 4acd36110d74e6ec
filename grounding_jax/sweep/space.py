"""A search space: the ``[space]`` table of a sweep file, its checks, draws and perturbations.

Each searched field is one of::

    actor_lr = { log = [1e-4, 1e-1] }      # log-uniform in [low, high] (low > 0)
    sigma = { uniform = [0.05, 0.3] }      # uniform in [low, high]
    actor_hidden = { int = [8, 80] }       # an integer in [low, high], both included
    gamma = { choice = [0.0, 0.5] }        # one of the values

Both ends of a range and every choice are checked against the field's own rule (a learning
rate > 0, a discount in [0, 1], ...), so every point a search can reach is a valid one.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

#: the kinds of a searched field
KINDS = ("uniform", "log", "int", "choice")


@dataclasses.dataclass(frozen=True)
class Dim:
    """One searched field.

    Attributes:
        name: the field.
        kind: one of `KINDS`.
        low, high: the range (``uniform``, ``log``, ``int``).
        choices: the values (``choice``).
    """

    name: str
    kind: str
    low: float | int | None = None
    high: float | int | None = None
    choices: tuple = ()

    def to_json(self) -> dict:
        """The ``[space]`` entry it was parsed from."""
        return {self.kind: list(self.choices) if self.kind == "choice" else [self.low, self.high]}


def parse_dim(name: str, entry: Any, field_type: type, check: Callable[[str, Any], Any],
              err: Callable[[str, str], Exception]) -> Dim:
    """Parse one ``[space]`` entry.

    Args:
        name: the field.
        entry: the entry as parsed from TOML (a one-key table).
        field_type: the field's Python type (float, int, bool, str).
        check: ``check(key, value) -> value`` the field's own check (raises on a bad value).
        err: ``err(key, message) -> exception`` naming the file and the key.
    """
    key = f"space.{name}"
    if not isinstance(entry, dict) or len(entry) != 1 or next(iter(entry)) not in KINDS:
        raise err(key, f"expected one of {{ uniform = [low, high] }}, {{ log = [low, high] }}, "
                       f"{{ int = [low, high] }} or {{ choice = [values] }}; got {entry!r}")
    kind, value = next(iter(entry.items()))
    if kind == "choice":
        if not isinstance(value, list) or not value:
            raise err(key, f"choice: needs a non-empty list of values, got {value!r}")
        values = tuple(check(key, v) for v in value)
        if len(set(map(repr, values))) != len(values):
            raise err(key, f"choice: repeated values in {value!r}")
        return Dim(name, kind, choices=values)
    if field_type not in (int, float) or (kind == "int") != (field_type is int):
        accepted = ("int, choice" if field_type is int else "uniform, log, choice"
                    if field_type is float else "choice")
        raise err(key, f"{kind}: not a range of a {field_type.__name__} field; accepted "
                       f"kinds: {accepted}")
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise err(key, f"{kind}: needs [low, high], got {value!r}")
    if kind == "int" and not all(isinstance(v, int) for v in value):
        raise err(key, f"int: needs two integers [low, high], got {value!r}")
    low, high = value
    if not low < high:
        raise err(key, f"{kind}: needs low < high, got [{low!r}, {high!r}]")
    if kind == "log" and low <= 0:
        raise err(key, f"log: needs low > 0 (a log range), got [{low!r}, {high!r}]")
    return Dim(name, kind, check(key, low), check(key, high))


def sample(space: Mapping[str, Dim], rng: np.random.Generator) -> dict[str, Any]:
    """One point drawn from the space (fields in the space's order)."""
    return {n: _draw(d, rng) for n, d in space.items()}


def _draw(d: Dim, rng: np.random.Generator) -> Any:
    if d.kind == "choice":
        return d.choices[int(rng.integers(len(d.choices)))]
    if d.kind == "int":
        return int(rng.integers(d.low, d.high + 1))
    if d.kind == "log":
        return float(math.exp(rng.uniform(math.log(d.low), math.log(d.high))))
    return float(rng.uniform(d.low, d.high))


def perturb(space: Mapping[str, Dim], point: dict[str, Any], rng: np.random.Generator,
            resample: float = 0.25, factors: tuple[float, float] = (0.8, 1.2)
            ) -> dict[str, Any]:
    """PBT's explore step: each field is drawn afresh with probability ``resample``, else a
    range is multiplied by one of ``factors`` (kept inside the range; an integer rounded) and
    a choice moves to a neighbouring value."""
    out = {}
    for n, d in space.items():
        v = point[n]
        if rng.uniform() < resample:
            out[n] = _draw(d, rng)
        elif d.kind == "choice":
            i = d.choices.index(v) + int(rng.choice((-1, 1)))
            out[n] = d.choices[min(max(i, 0), len(d.choices) - 1)]
        else:
            f = factors[int(rng.integers(2))]
            if d.kind == "int":
                # a step of at least 1, so a small integer can move at all
                moved = round(v * f) if round(v * f) != v else v + (1 if f > 1 else -1)
                out[n] = int(min(max(moved, d.low), d.high))
            else:
                out[n] = float(min(max(v * f, d.low), d.high))
    return out


def bounds(space: Mapping[str, Dim]) -> list[dict[str, Any]]:
    """Points that together reach every end of every field (the lows, the highs, each
    choice): a module config built for them holds any point of the space."""
    out = [{n: d.low if d.kind != "choice" else d.choices[0] for n, d in space.items()},
           {n: d.high if d.kind != "choice" else d.choices[-1] for n, d in space.items()}]
    for n, d in space.items():
        out += [out[0] | {n: c} for c in d.choices[1:-1]]
    return out


def optuna_distribution(d: Dim):
    """The Optuna distribution of a field."""
    from optuna import distributions as od

    if d.kind == "choice":
        return od.CategoricalDistribution(list(d.choices))
    if d.kind == "int":
        return od.IntDistribution(int(d.low), int(d.high))
    return od.FloatDistribution(float(d.low), float(d.high), log=d.kind == "log")


def normalised(d: Dim, value: Any) -> float:
    """A value's place in its field, 0 (low, first choice) to 1 (high, last choice)."""
    if d.kind == "choice":
        return d.choices.index(value) / max(len(d.choices) - 1, 1)
    if d.kind == "log":
        return math.log(value / d.low) / math.log(d.high / d.low)
    return (value - d.low) / (d.high - d.low)
