"""One part of a run computed on its own thread, beside the others.

JAX releases the GIL while XLA compiles and computes, so a part that only runs networks (the
TL's experiments) fills the cores that the physics parts leave idle while they trace,
compile, or step small batches. Results do not change: each part has its own key and its own
compiled programs, and a program computes the same numbers on whichever thread runs it.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from grounding_jax.core import compiles, guard


class Cancelled(Exception):  # noqa: N818 (a request, not a fault)
    """Raised inside a part, at one of its checkpoints, when the run around it has failed."""


class Beside:
    """``fn(*args, stop=event)`` run on a daemon thread from construction.

    `fn` should call `check` on ``stop`` between its steps (it raises `Cancelled`).
    Use it as a context manager: leaving the block with an error stops the part at its next
    check and waits for it (files it writes stay whole: they are written by rename), except
    on an interrupt, which leaves at once (the command line ends the process).
    """

    def __init__(self, name: str, fn: Callable[..., Any], *args: Any) -> None:
        self.name = name
        self.wall_s: float | None = None
        self.compile_s: float | None = None
        self._stop = threading.Event()
        self._value: Any = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(fn, args), name=name,
                                        daemon=True)
        self._thread.start()

    def _run(self, fn: Callable[..., Any], args: tuple) -> None:
        started, before = time.perf_counter(), compiles.thread_seconds()
        try:
            self._value = fn(*args, stop=self._stop)
        except BaseException as e:  # handed to the caller's thread by result()
            self._error = e
        finally:
            self.wall_s = time.perf_counter() - started
            # a thread id can be reused: count only this thread's own compiling
            self.compile_s = sum(compiles.thread_seconds().values()) - sum(before.values())

    def result(self) -> Any:
        """Wait for the part; its return value, or its error raised here."""
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._value

    def __enter__(self) -> Beside:
        return self

    def __exit__(self, kind, error, tb) -> None:
        if error is None:
            return
        self._stop.set()
        if not isinstance(error, (KeyboardInterrupt, guard.Interrupted)):
            self._thread.join()


def check(stop: threading.Event | None) -> None:
    """Raise `Cancelled` if `stop` is set (a part's checkpoint between its steps)."""
    if stop is not None and stop.is_set():
        raise Cancelled("stopped: the run around this part failed")
