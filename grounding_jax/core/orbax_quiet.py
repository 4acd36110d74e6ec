"""orbax's echoes of a failed checkpoint write or read, held back: the failure is raised once,
as a clear error, instead of being preceded by its helper threads' tracebacks, log records and
unraisable exceptions (about 300 lines for a full disk)."""

from __future__ import annotations

import contextlib
import errno
import os
import sys
from collections.abc import Callable, Iterator

_failed_reads = [0]  # restores that failed in this process


def _echo_of_a_failed_read(unraisable) -> bool:
    """When tensorstore cannot read a damaged file, orbax's restore raises (and the step is
    refused with a clear error), but the read's other coroutines are closed unfinished and
    their futures' callbacks hit the closed asyncio loop: Python then prints their
    "Exception ignored ... Event loop is closed" tracebacks, with nothing left to act on."""
    if not _failed_reads[0]:
        return False
    e, obj = unraisable.exc_value, unraisable.object
    code = getattr(obj, "cr_code", None)
    return ((isinstance(e, RuntimeError) and str(e) == "Event loop is closed")
            or (code is not None and f"{os.sep}orbax{os.sep}" in code.co_filename))


def _quiet_closed_loop(previous: Callable) -> Callable:
    """An unraisable-exception hook that drops the echoes of a failed read
    (`_echo_of_a_failed_read`) and passes everything else to the previous hook."""

    def hook(unraisable) -> None:
        if not _echo_of_a_failed_read(unraisable):
            previous(unraisable)

    hook._grounding_jax = True  # type: ignore[attr-defined]
    return hook


def install_quiet_hook() -> None:
    if not getattr(sys.unraisablehook, "_grounding_jax", False):
        sys.unraisablehook = _quiet_closed_loop(sys.unraisablehook)


class _EchoFilter:
    """Drops, once a checkpoint write or read has failed, the records orbax's helper threads
    and asyncio log about it after the failure was raised (a thread that finishes late, a
    task whose exception nobody retrieved): the failure itself is raised once."""

    def filter(self, record) -> bool:
        if not _failed_reads[0]:
            return True
        text = record.getMessage()
        return not (record.name == "asyncio" or "_SignalingThread" in text
                    or "RESOURCE_EXHAUSTED" in text or f"{os.sep}orbax{os.sep}" in
                    record.pathname)


_ECHO_FILTER = _EchoFilter()


def quiet_failed_io() -> None:
    """After a failed orbax write or read, its echoes are dropped from now on: the unraisable
    exceptions of its unfinished coroutines (`_echo_of_a_failed_read`), its helper
    threads' log records and their "Event loop is closed" exceptions."""
    import logging
    import threading

    _failed_reads[0] += 1
    install_quiet_hook()
    for name in ("absl", "asyncio"):
        if _ECHO_FILTER not in logging.getLogger(name).filters:
            logging.getLogger(name).addFilter(_ECHO_FILTER)
    if not getattr(threading.excepthook, "_grounding_jax", False):
        previous = threading.excepthook

        def hook(args) -> None:
            if not (isinstance(args.exc_value, RuntimeError)
                    and str(args.exc_value) == "Event loop is closed"):
                previous(args)

        hook._grounding_jax = True  # type: ignore[attr-defined]
        threading.excepthook = hook


@contextlib.contextmanager
def stderr_held() -> Iterator[None]:
    """Hold what is written to stderr (file descriptor 2: Python's and C's) inside the block;
    pass it on if the block succeeds, drop it if it raises. A failed orbax write prints its
    helper threads' tracebacks there before the failure reaches us, and the failure is
    raised once, as a CheckpointError, instead."""
    import tempfile

    with contextlib.suppress(Exception):
        sys.stderr.flush()
    saved = os.dup(2)
    ok = False
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
            ok = True
        finally:
            with contextlib.suppress(Exception):
                sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            if ok:
                held.seek(0)
                data = held.read()
                if data:
                    os.write(2, data)


def io_reason(e: BaseException) -> str:
    """What went wrong with a checkpoint's files, in a few words."""
    text = str(e)
    code = getattr(e, "errno", None)
    if code == errno.ENOSPC or "No space left" in text or "os_error_code='28'" in text:
        return "no space left on the device"
    if code == errno.EFBIG or "File too large" in text or "os_error_code='27'" in text:
        return "File too large: the file size limit was reached (a full disk)"
    if isinstance(e, OSError) and e.strerror:
        return e.strerror
    return f"{type(e).__name__}: {text[:300]}"
