"""Input checks shared by the configs and the sweep runner: clear ValueErrors that name the
field. Each dataclass keeps one table of `Rule` s -- traced values in ``HYPER_RULES`` /
``PARAM_RULES`` (read by its ``validate``), static config fields in ``CONFIG_RULES`` (read by
its ``__post_init__``) -- and the sweep runner's field checks read the same tables."""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Callable
from typing import Any

import jax
import numpy as np


def require_int(name: str, value: Any, minimum: int) -> int:
    """Return ``value`` if it is an integer >= ``minimum``; else ValueError naming ``name``."""
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{name}: must be an integer >= {minimum}, got {value!r}")
    return int(value)


@dataclasses.dataclass(frozen=True)
class Rule:
    """What a traced field accepts.

    Attributes:
        text: the accepted values, as an error message says them ("> 0", "in [0, 1]").
        ok: elementwise predicate on a float array (a scalar, or a batch of values).
        type: the Python type a sweep file gives it (float, or int for counts and flags).
    """

    text: str
    ok: Callable[[np.ndarray], Any]
    type: type = float

    def holds(self, value: Any) -> bool:
        """Every element finite, within float32's range (traced values are float32) and
        accepted."""
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            return False
        return bool(np.all(np.isfinite(arr)) and np.all(np.abs(arr) <= FLOAT32_MAX)
                    and np.all(self.ok(arr)))

    def refusal(self, value: Any) -> str:
        """Why ``value`` is refused, as an error message ends: ``must be <rule>, got v``
        (or, for a value beyond float32, that it must fit in float32)."""
        try:
            arr = np.asarray(value, dtype=float)
            big = bool(np.any(np.isfinite(arr) & (np.abs(arr) > FLOAT32_MAX)))
        except (TypeError, ValueError):
            big = False
        if big:
            return (f"must be {self.text} and fit in float32 (|x| <= {FLOAT32_MAX:.4g}), "
                    f"got {value!r}")
        return f"must be {self.text}, got {value!r}"


#: the largest float32: traced values beyond it overflow to inf inside ``jit``
FLOAT32_MAX = float(np.finfo(np.float32).max)

POSITIVE = Rule("> 0", lambda v: v > 0)
NON_NEGATIVE = Rule(">= 0", lambda v: v >= 0)
UNIT_CLOSED = Rule("in [0, 1]", lambda v: (v >= 0) & (v <= 1))
UNIT_OPEN_LEFT = Rule("in (0, 1]", lambda v: (v > 0) & (v <= 1))
FLAG = Rule("0 or 1", lambda v: (v == 0) | (v == 1), int)
FINITE = Rule("a finite number", lambda v: np.ones_like(v, bool))


def integer_at_least(n: int, text: str = "") -> Rule:
    """An integer >= ``n`` (the value may be stored as a float in a batch)."""
    return Rule(text or f"an integer >= {n}", lambda v: (v >= n) & (v == np.round(v)), int)


def check_config(obj: Any, rules: dict[str, Rule]) -> None:
    """ValueError naming the first static field of a config that breaks its rule (a field
    whose rule counts needs a Python integer, not a bool or a float; any other field a real
    number, not a bool or a string)."""
    for name, rule in rules.items():
        v = getattr(obj, name)
        kind = (int, np.integer) if rule.type is int else numbers.Real
        if isinstance(v, bool) or not isinstance(v, kind) or not rule.holds(v):
            raise ValueError(f"{name}: {rule.refusal(v)}")


def check_rules(obj: Any, rules: dict[str, Rule]) -> None:
    """ValueError naming the first field of ``obj`` whose concrete value breaks its rule
    (traced values are skipped: they were checked before tracing)."""
    for name, rule in rules.items():
        v = getattr(obj, name)
        if isinstance(v, jax.core.Tracer):
            continue
        if not rule.holds(v):
            raise ValueError(f"{name}: {rule.refusal(v)}")
