"""Counting the XLA programs a process builds, through ``jax.monitoring``.

Every program JAX runs (a ``jit``, or one eager operation) is built once per process: either
compiled by XLA or loaded from the persistent compilation cache. Both go through the same
step, which JAX reports as a ``backend_compile_duration`` event with the program's name;
cache hits are reported apart. The tally is process-wide and only grows.
"""

from __future__ import annotations

import collections
import dataclasses
import threading

_BUILD = "/jax/core/compile/backend_compile_duration"
_STAGES = {"/jax/core/compile/jaxpr_trace_duration": "trace",
           "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower", _BUILD: "build"}
_HIT = "/jax/compilation_cache/cache_hits"
_lock = threading.Lock()
_names: collections.Counter[str] = collections.Counter()
_seconds: collections.Counter[str] = collections.Counter()
_stage_s: collections.Counter[str] = collections.Counter()
_thread_s: collections.defaultdict[int, collections.Counter[str]] = collections.defaultdict(
    collections.Counter)  # JAX reports a compile on the thread that asked for it
_hits = 0
_installed = False


@dataclasses.dataclass(frozen=True)
class Tally:
    """Programs built so far (compiled or loaded from the cache) and what they cost."""

    programs: int
    from_cache: int
    by_name: dict[str, int]
    stages: dict[str, float] = dataclasses.field(default_factory=dict)
    seconds_by_name: dict[str, float] = dataclasses.field(default_factory=dict)

    def __sub__(self, other: Tally) -> Tally:
        names = collections.Counter(self.by_name)
        names.subtract(other.by_name)
        stages = {k: v - other.stages.get(k, 0.0) for k, v in self.stages.items()}
        secs = {k: d for k, v in self.seconds_by_name.items()
                if (d := v - other.seconds_by_name.get(k, 0.0)) > 0}
        return Tally(self.programs - other.programs, self.from_cache - other.from_cache,
                     {k: v for k, v in names.items() if v}, stages, secs)

    def as_dict(self, top: int = 0) -> dict:
        """JSON-ready: the counts, and the ``top`` most frequent program names."""
        out = {"programs": self.programs, "compiled": self.programs - self.from_cache,
               "from_cache": self.from_cache,
               "seconds": {k: round(self.stages.get(k, 0.0), 2)
                           for k in ("trace", "lower", "build")}}
        if top:
            common = collections.Counter(self.by_name).most_common(top)
            out["most_built"] = dict(common)
            slow = collections.Counter(self.seconds_by_name).most_common(top)
            # names as JAX reports them: "f" when traced, "jit_f" lowered, "jit(f)" built
            out["slowest_s"] = {k: round(v, 2) for k, v in slow}
        return out


def _on_duration(event: str, duration: float, **kwargs) -> None:
    stage = _STAGES.get(event)
    if stage is None:
        return
    name = str(kwargs.get("fun_name", "?"))
    with _lock:
        _stage_s[stage] += duration
        _thread_s[threading.get_ident()][stage] += duration
        _seconds[name] += duration  # tracing, lowering and building, by program name
        if event == _BUILD:
            _names[name] += 1


def _on_event(event: str, **kwargs) -> None:
    global _hits
    if event == _HIT:
        with _lock:
            _hits += 1


def install() -> None:
    """Start counting (idempotent; the listeners stay for the process's life)."""
    global _installed
    with _lock:
        if _installed:
            return
        _installed = True
    import jax

    jax.monitoring.register_event_duration_secs_listener(_on_duration)
    jax.monitoring.register_event_listener(_on_event)


def tally() -> Tally:
    """The programs built since `install` was first called."""
    with _lock:
        return Tally(sum(_names.values()), _hits, dict(_names), dict(_stage_s), dict(_seconds))


def thread_seconds(ident: int | None = None) -> dict[str, float]:
    """Seconds spent tracing, lowering and building on one thread (default: this one) since
    `install`: a part run on its own thread is told its compiling apart from the others'."""
    with _lock:
        return dict(_thread_s.get(threading.get_ident() if ident is None else ident, {}))
