"""Result files: written whole or not at all, with the library versions they were made with."""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.metadata
import json
import os
import pathlib
import platform
import re
from collections.abc import Iterator

from grounding_jax.core import guard


def _remove_quietly(path: pathlib.Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink()


def atomic_write_bytes(path: pathlib.Path, data: bytes) -> None:
    """Write ``data`` to a hidden temporary beside ``path``, then rename it into place; on any
    error (a full disk, a read-only folder) the temporary is removed and ``path`` is left as
    it was."""
    path = pathlib.Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        _remove_quietly(tmp)
        raise


def atomic_write_text(path: pathlib.Path, text: str) -> None:
    """`atomic_write_bytes` of UTF-8 text."""
    atomic_write_bytes(path, text.encode())


#: a staged file's name: ``.<stem>.staged-<pid>-<n><suffix>``; a commit's journal:
#: ``.staged-<pid>.journal`` (the renames it is making, written before the first of them)
_STAGED = re.compile(r"^\..*\.staged-(\d+)-\d+")
_JOURNAL = re.compile(r"^\.staged-(\d+)\.journal$")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process
        return True
    return True


def recover_staged(folder: pathlib.Path) -> list[str]:
    """Finish or clean up what a writer that died mid-way left in ``folder``: a commit that
    had begun (its journal is there) is completed, so the new set stands whole; staged files
    that never reached a commit are deleted, so the earlier set stands. Only files of
    processes no longer running are touched.

    Returns:
        What was done, one phrase per item (for a note).
    """
    folder = pathlib.Path(folder)
    done: list[str] = []
    if not folder.is_dir():
        return done
    for journal in sorted(folder.glob(".staged-*.journal")):
        m = _JOURNAL.match(journal.name)
        if m is None or _alive(int(m.group(1))):
            continue
        try:
            pairs = json.loads(journal.read_text())
        except (OSError, ValueError):
            pairs = None  # written atomically, so unreadable means not ours: leave it
        if not isinstance(pairs, list):
            continue
        for tmp, final in pairs:
            if (folder / tmp).exists():
                os.replace(folder / tmp, folder / final)
        journal.unlink()
        done.append(f"completed an interrupted commit of {len(pairs)} files")
    left = [p for p in folder.rglob(".*.staged-*") if (m := _STAGED.match(p.name))
            and not _alive(int(m.group(1)))]
    for p in left:
        _remove_quietly(p)
    if left:
        done.append(f"removed {len(left)} staged files an interrupted writer left")
    return done


class Staged:
    """Several result files that replace their earlier versions together: each is written to
    a temporary beside its final name, and only `commit` (after every write succeeded)
    renames them into place, so a full disk mid-way leaves the earlier set whole.

    The renames happen with SIGINT/SIGTERM held back (they take effect once the new set is in
    place), after a journal of them is written: a writer killed mid-commit has its commit
    completed by the next `Staged` on the folder (`recover_staged`), which also
    deletes the staged files of writers that died before committing."""

    def __init__(self, folder: pathlib.Path) -> None:
        self.folder = pathlib.Path(folder)
        self._pending: list[tuple[pathlib.Path, pathlib.Path]] = []
        recover_staged(self.folder)

    def path(self, name: str) -> pathlib.Path:
        """A temporary path for ``name`` (renamed to ``folder/name`` on commit; a name
        staged twice keeps the later file)."""
        final = self.folder / name
        tmp = final.with_name(f".{final.stem}.staged-{os.getpid()}-{len(self._pending)}"
                              f"{final.suffix}")
        for old, _ in [p for p in self._pending if p[1] == final]:
            _remove_quietly(old)
        self._pending = [p for p in self._pending if p[1] != final] + [(tmp, final)]
        return tmp

    def write_text(self, name: str, text: str) -> None:
        """Stage ``text`` as ``folder/name``."""
        tmp = self.path(name)
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())

    def commit(self) -> None:
        """Rename every staged file into place, as one set."""
        if not self._pending:
            return
        journal = self.folder / f".staged-{os.getpid()}.journal"
        rel = [[t.relative_to(self.folder).as_posix(), f.relative_to(self.folder).as_posix()]
               for t, f in self._pending]
        with guard.deferred():
            try:
                atomic_write_text(journal, json.dumps(rel))
            except BaseException:
                self.discard()
                raise
            for tmp, final in self._pending:
                os.replace(tmp, final)
            self._pending = []
            _remove_quietly(journal)

    def discard(self) -> None:
        for tmp, _ in self._pending:
            _remove_quietly(tmp)
        self._pending = []

    @contextlib.contextmanager
    def writing(self) -> Iterator[Staged]:
        """Stage inside the block; commit at its end, discard on any error."""
        try:
            yield self
        except BaseException:
            self.discard()
            raise
        self.commit()


class _Figures:
    """The part of `matplotlib.pyplot` this package draws with, minus pyplot's global list of
    open figures: each figure is a free-standing `matplotlib.figure.Figure`, so figures can be
    drawn on several threads at once (train.py runs the TL's part beside the others)."""

    def __init__(self, plt) -> None:
        self._plt = plt

    @staticmethod
    def subplots(nrows: int = 1, ncols: int = 1, *, figsize=None, **kwargs):
        """`pyplot.subplots`' signature: (figure, axes)."""
        from matplotlib.figure import Figure

        fig = Figure(figsize=figsize)
        return fig, fig.subplots(nrows, ncols, **kwargs)

    @staticmethod
    def close(fig) -> None:
        """Drop the figure's artists (nothing global holds it)."""
        fig.clear()

    def __getattr__(self, name: str):  # colour maps and norms: pyplot's stateless helpers
        return getattr(self._plt, name)


def pyplot() -> _Figures:
    """A thread-safe slice of matplotlib.pyplot on the headless Agg backend (imported on
    first use): `subplots`, `close`, and pyplot's colour maps and norms."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return _Figures(plt)


def write_figure(out: pathlib.Path, name: str, payload: dict, fig,
                 staged: Staged | None = None) -> None:
    """``out/<name>.json`` (the figure's data) and ``out/<name>.png``, each written whole
    (with ``staged``: staged there, renamed on its commit); the figure is closed."""
    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    own = staged is None
    staged = Staged(out) if own else staged
    try:
        staged.write_text(f"{name}.json", json.dumps(payload, indent=2) + "\n")
        fig.savefig(staged.path(f"{name}.png"), dpi=110, bbox_inches="tight", format="png")
        if own:
            staged.commit()
    except BaseException:
        if own:
            staged.discard()
        raise
    finally:
        pyplot().close(fig)


def library_versions() -> dict[str, str]:
    """Python's and the numerical libraries' versions, recorded with a run's numbers: bit-for-
    bit reproduction is only expected under the same ones (results/paper's env check once
    pushed the sphere 19.6 cm; with the libraries installed since, the same code pushes it
    47.9 cm)."""
    out = {"python": platform.python_version()}
    for name in ("jax", "jaxlib", "mujoco", "mujoco-mjx", "numpy", "optax", "flax",
                 "orbax-checkpoint"):
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


@functools.cache
def code_fingerprint() -> str:
    """SHA-256 of the package's source and data files (every ``.py``, ``.xml``, ``.json``
    and ``.npz`` under ``grounding_jax/``, by relative path): what a resumed run must share
    with the run it continues, beside the library versions."""
    root = pathlib.Path(__file__).resolve().parents[1]  # the package, not core/
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if p.suffix in (".py", ".xml", ".json", ".npz") and "__pycache__" not in p.parts:
            h.update(p.relative_to(root).as_posix().encode() + b"\0")
            h.update(hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()
