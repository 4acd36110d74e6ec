"""One writer per output folder, and interrupts that end a run cleanly.

`folder_lock` holds an OS lock (``fcntl.flock`` on ``<folder>/.lock``) while a sweep,
``train.py`` or `grounding_jax.robot.trained.save` writes to a folder; the kernel releases it
when the process dies, however it dies, so a killed run never leaves a stale lock. A second
writer is refused before it touches anything, with the holder's pid.

`handle_interrupts` turns SIGTERM into `Interrupted` (SIGINT already raises
``KeyboardInterrupt``) for the command-line tools; `deferred` holds both signals back
while a checkpoint is being sealed, so an interrupt never lands between orbax's commit and the
manifest that makes a step usable.
"""

from __future__ import annotations

import contextlib
import os
import pathlib
import signal
import threading
from collections.abc import Iterator

LOCK_FILE = ".lock"


class FolderBusyError(RuntimeError):
    """Another process is writing to the folder."""


class Interrupted(Exception):  # noqa: N818 (a signal, not a fault)
    """The run was asked to stop by a signal (``signum``)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


_held: dict[pathlib.Path, list] = {}  # lock path -> [fd, depth]: re-entrant in one process


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike, what: str = "a run") -> Iterator[None]:
    """Hold ``folder``'s writer lock for the block (the folder is created if missing).

    Args:
        folder: the output folder.
        what: what this process is, for the message a second writer gets.

    Raises:
        FolderBusyError: another process holds the lock (the message names its pid).
        OSError: the folder cannot be created or the lock file cannot be opened.
    """
    import fcntl

    folder = pathlib.Path(folder).absolute()
    path = folder / LOCK_FILE
    if path in _held:
        _held[path][1] += 1
        try:
            yield
        finally:
            _held[path][1] -= 1
        return
    folder.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "unknown"
        os.close(fd)
        raise FolderBusyError(f"{folder}: another writer holds it ({holder}); wait for it "
                              "to finish or stop it -- nothing here was touched") from None
    except BaseException:
        os.close(fd)
        raise
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"pid {os.getpid()}: {what}\n".encode(), 0)
    _held[path] = [fd, 1]
    try:
        yield
    finally:
        del _held[path]
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
        os.close(fd)  # closing the descriptor releases the lock


_deferring = [0]
_pending: list[int] = []


def _raise_for(signum: int) -> None:
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Interrupted(signum)


def _handler(signum, frame) -> None:
    if _deferring[0]:
        _pending.append(signum)
        return
    _raise_for(signum)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """SIGINT/SIGTERM received inside the block take effect when it ends (only while
    `handle_interrupts` is on; otherwise the block changes nothing), on the main thread
    whichever thread's block held them back."""
    _deferring[0] += 1
    try:
        yield
    finally:
        _deferring[0] -= 1
        if not _deferring[0] and _pending:
            signum = _pending[0]
            _pending.clear()
            if threading.current_thread() is threading.main_thread():
                _raise_for(signum)
            else:  # a part on its own thread (core.beside) sealed a file: the run stops
                signal.pthread_kill(threading.main_thread().ident, signum)


@contextlib.contextmanager
def handle_interrupts() -> Iterator[None]:
    """For a command-line tool's main: SIGINT raises ``KeyboardInterrupt`` and SIGTERM
    `Interrupted`, each deferred while a checkpoint is sealed (`deferred`)."""
    old = {s: signal.signal(s, _handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def resume_command(prog: list[str], argv: list[str] | None = None) -> str:
    """The command line that continues this one: ``prog`` with the same arguments, and
    ``--resume`` instead of ``--overwrite``."""
    import shlex
    import sys

    args = [a for a in (sys.argv[1:] if argv is None else argv) if a != "--overwrite"]
    if "--resume" not in args:
        args.append("--resume")
    return shlex.join([*prog, *args])


def quiet_start(prog: list[str]) -> None:
    """A command-line tool's first call, before its heavy imports: SIGINT or SIGTERM while it
    starts (nothing written yet) exits at once with 130 or 143 and the command to run again,
    instead of a ``KeyboardInterrupt`` traceback from inside an import. Its main then takes
    over with `handle_interrupts`."""
    import sys

    def handler(signum, frame) -> None:
        print(f"\ninterrupted ({signal.Signals(signum).name}) while starting: nothing was "
              f"written; continue with:\n  {resume_command(prog)}", file=sys.stderr,
              flush=True)
        os._exit(128 + signum)

    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, handler)


def exit_code(e: BaseException) -> int:
    """The shell's code for a run ended by a signal: 128 + its number (130 SIGINT, 143
    SIGTERM)."""
    return 128 + (e.signum if isinstance(e, Interrupted) else signal.SIGINT)


def leave(code: int) -> None:
    """End an interrupted command-line run now, with ``code``, skipping the interpreter's
    clean-up: the interrupt may have landed while JAX still runs a dispatched computation
    (dispatch is asynchronous) that calls into the physics thread pool, and tearing the
    modules down under it crashed the process (SIGSEGV) after the message was printed.
    Everything the run wrote is already on disk (checkpoints are sealed before an interrupt
    takes effect); the kernel releases the folder lock."""
    import sys

    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)
