"""Checkpoints: an orbax ``CheckpointManager`` per folder, with the run's config as JSON beside
and a manifest of checksums in every step.

Layout of a checkpoint folder::

    <dir>/config.json                  what produced it: {"kind", "version", "config",
                                       "written_by"}; written once, when the folder is made,
                                       and never rewritten
    <dir>/steps/<step>/                an orbax checkpoint (written atomically by orbax: a run
                                       killed while saving leaves a temporary folder, which
                                       is never read)
    <dir>/steps/<step>/manifest.json   written after orbax commits the step: the SHA-256 of
                                       every file of the step, of every array's bytes, of
                                       config.json, and of the manifest itself
    <dir>/damaged/<step>-<time>/       steps a resumed run set aside (never deleted)

orbax checksums only its own index, not the array data, so a flipped byte in an array file
restores silently; the manifest catches it. A step is *intact* when its manifest is whole,
names this config.json, every file matches, and every restored array has the bytes that were
saved. `Checkpointer.restore` refuses anything else with a `DamagedStepError`
that names the step, the arrays and the files; `Checkpointer.restore_latest` can fall
back to the newest intact step (a resumed sweep does, and says so; ``load`` does not).

A folder is only ever opened for the config it was written with, by the package version that
wrote it; anything else is refused with `CheckpointError` before a byte is written.
PRNG keys are stored as their raw ``key_data`` (uint32) and wrapped again on restore.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pathlib
import shutil
import sys
import time
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from grounding_jax.core import guard, orbax_quiet
from grounding_jax.core.io import atomic_write_text, code_fingerprint, library_versions

CONFIG_FILE = "config.json"
MANIFEST = "manifest.json"
#: the manifest's format (a manifest of another format is not trusted)
MANIFEST_FORMAT = 1


class CheckpointError(RuntimeError):
    """A checkpoint folder that cannot be used: corrupt, or written for another config or
    package version."""


class DamagedStepError(CheckpointError):
    """One step of a checkpoint folder failed its checks (``step``: which)."""

    def __init__(self, message: str, step: int) -> None:
        super().__init__(message)
        self.step = step


def _version() -> str:
    from grounding_jax.core._version import __version__

    return __version__


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _diff(stored: Any, current: Any, prefix: str = "") -> list[str]:
    """Dotted names of the fields that differ between two JSON values."""
    if isinstance(stored, dict) and isinstance(current, dict):
        out = []
        for k in sorted(set(stored) | set(current)):
            name = f"{prefix}.{k}" if prefix else str(k)
            if k not in stored or k not in current:
                out.append(name)
            else:
                out += _diff(stored[k], current[k], name)
        return out
    if (isinstance(stored, list) and isinstance(current, list) and len(stored) == len(current)
            and any(isinstance(v, (dict, list)) for v in stored)):
        return [d for i, (a, b) in enumerate(zip(stored, current, strict=True))
                for d in _diff(a, b, f"{prefix}[{i}]")]
    return [] if stored == current else [prefix or "(root)"]


def read_config(directory: str | pathlib.Path) -> dict:
    """The ``config.json`` of a checkpoint folder, checked for the package version.

    Raises:
        CheckpointError: missing or unreadable file, or another package version.
    """
    path = pathlib.Path(directory) / CONFIG_FILE
    if not path.is_file():
        raise CheckpointError(f"{path}: no checkpoint config here (is {directory} a "
                              "checkpoint folder?)")
    try:
        stored = json.loads(path.read_bytes().decode("utf-8"))
        kind, version, config = stored["kind"], stored["version"], stored["config"]
        if not isinstance(config, dict) or not isinstance(kind, str):
            raise TypeError("'kind' must be a string and 'config' an object")
    except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as e:
        raise CheckpointError(f"{path}: corrupt checkpoint config ({type(e).__name__}: "
                              f"{str(e)[:200]}); refusing to use or rewrite it") from e
    if version != _version():
        raise CheckpointError(f"{path}: written by grounding_jax {version}, this is "
                              f"{_version()}; refusing to mix versions (rerun, or install "
                              f"grounding_jax=={version} to load it)")
    return {"kind": kind, "version": version, "config": config,
            "written_by": stored.get("written_by", {})}


def written_by() -> dict:
    """What writes a checkpoint now: package version, code fingerprint, library versions."""
    return {"version": _version(), "code": code_fingerprint(), "libraries": library_versions()}


def array_digests(tree: Any) -> dict[str, dict]:
    """Per leaf of a pytree of arrays (keyed by its path): shape, dtype and the SHA-256 of
    its bytes (C order)."""
    out = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        a = np.ascontiguousarray(np.asarray(leaf))
        out[jax.tree_util.keystr(path)] = {"shape": list(a.shape), "dtype": str(a.dtype),
                                           "sha256": _sha256(a.tobytes())}
    return out


def _file_digests(folder: pathlib.Path) -> dict[str, dict]:
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file() and p.name != MANIFEST:
            data = p.read_bytes()
            out[p.relative_to(folder).as_posix()] = {"size": len(data), "sha256": _sha256(data)}
    return out


def _sealed(body: dict) -> dict:
    return body | {"manifest_sha256": _sha256(json.dumps(body, sort_keys=True).encode())}


class Checkpointer:
    """Save and restore pytrees of arrays at integer steps in one folder.

    Args:
        directory: the checkpoint folder (created if missing, unless ``read_only``).
        kind: what is stored (``"sweep-group"``, ``"modules"``, ...), checked on reopen.
        config: JSON-able config of the run; a folder written for another config is refused.
        max_to_keep: checkpoints kept (older ones are deleted after a newer one is complete).
        read_only: open an existing folder to read it; nothing is created or written.
        ignore: top-level config fields not compared on reopen (e.g. a reader that accepts
            arrays written by other code).
    """

    def __init__(self, directory: str | pathlib.Path, kind: str, config: dict,
                 max_to_keep: int = 2, read_only: bool = False,
                 ignore: tuple[str, ...] = ()) -> None:
        import orbax.checkpoint as ocp

        self.directory = pathlib.Path(directory).absolute()
        self._ocp = ocp
        self.manager = None
        config = json.loads(json.dumps(config))  # tuples -> lists, as stored
        path = self.directory / CONFIG_FILE
        steps = self.directory / "steps"
        if path.exists() or read_only:
            stored = read_config(self.directory)
            if stored["kind"] != kind:
                raise CheckpointError(f"{self.directory}: holds a {stored['kind']!r} "
                                      f"checkpoint, not {kind!r}")
            bad = _diff({k: v for k, v in stored["config"].items() if k not in ignore},
                        {k: v for k, v in config.items() if k not in ignore})
            if bad:
                shown = ", ".join(bad[:12]) + (f" and {len(bad) - 12} more" if len(bad) > 12
                                               else "")
                raise CheckpointError(f"{self.directory}: written for another config (fields "
                                      f"that differ: {shown}); use another folder or "
                                      "the original settings")
        elif steps.exists() and any(steps.iterdir()):
            raise CheckpointError(f"{self.directory}: holds checkpoints but no config.json; "
                                  "they cannot be identified, so they are neither used nor "
                                  "given a new config (delete the folder to start over)")
        else:
            try:
                self.directory.mkdir(parents=True, exist_ok=True)
                atomic_write_text(path, json.dumps(
                    {"kind": kind, "version": _version(), "config": config,
                     "written_by": written_by()}, indent=2) + "\n")
            except OSError as e:
                raise CheckpointError(f"{path}: could not be written ({e.strerror or e}); "
                                      "nothing else was written") from e
        self._config_sha = _sha256(path.read_bytes())
        if read_only and not steps.is_dir():
            raise CheckpointError(f"{self.directory}: config.json but no complete checkpoint")
        self.read_only = read_only
        self.max_to_keep = max_to_keep
        # old steps are pruned here (after the new one is sealed), not by orbax: with a light
        # initialisation orbax does not read the steps a killed run left, so it could not
        self.manager = ocp.CheckpointManager(
            steps, options=ocp.CheckpointManagerOptions(
                max_to_keep=None, create=not read_only,
                cleanup_tmp_directories=not read_only,  # what a killed save left
                lightweight_initialize=True,  # steps are listed and checked here, not by orbax
                enable_async_checkpointing=False))

    def __enter__(self) -> Checkpointer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def steps(self) -> list[int]:
        """Every committed step in the folder, newest first (intact or not)."""
        folder = self.directory / "steps"
        if not folder.is_dir():
            return []
        return sorted((int(p.name) for p in folder.iterdir() if p.name.isdigit()),
                      reverse=True)

    def latest_step(self) -> int | None:
        """The newest committed step, or None (see `restore_latest` for the newest
        intact one)."""
        steps = self.steps()
        return steps[0] if steps else None

    def save(self, step: int, tree: Any) -> None:
        """Write ``tree`` at ``step`` and seal it with its manifest (blocking; atomic).

        Raises:
            CheckpointError: the step could not be written (e.g. a full disk); the steps
                written before it are left as they were.
        """
        storable = _to_storable(tree)
        arrays = array_digests(storable)
        where = self.directory / "steps" / str(step)
        kept = self.latest_step()
        with guard.deferred():  # an interrupt lands after the step is sealed, not inside
            try:
                with orbax_quiet.stderr_held():
                    self.manager.save(step, args=self._ocp.args.StandardSave(storable))
                    self.manager.wait_until_finished()
                atomic_write_text(where / MANIFEST, json.dumps(_sealed(
                    {"format": MANIFEST_FORMAT, "step": int(step),
                     "config_sha256": self._config_sha, "arrays": arrays,
                     "files": _file_digests(where)}), indent=1) + "\n")
                for old in self.steps()[self.max_to_keep:]:  # older than the kept ones
                    shutil.rmtree(self.directory / "steps" / str(old))
            except Exception as e:  # orbax/tensorstore raise many types for an I/O failure
                orbax_quiet.quiet_failed_io()
                kept_msg = (f"step {kept} is kept as it was" if kept is not None else
                            "no earlier step existed")
                why = orbax_quiet.io_reason(e)
                raise CheckpointError(f"{where}: could not be written ({why}); {kept_msg}"
                                      ) from e

    def seal(self, step: int, like: Any) -> None:
        """Write the manifest of a step saved before manifests existed, from its files as
        they are now (trusting them: do it only for files you know are whole, e.g. ones
        under version control).

        Raises:
            CheckpointError: the step already has a manifest, or cannot be read as ``like``.
        """
        where = self.directory / "steps" / str(step)
        if (where / MANIFEST).exists():
            raise CheckpointError(f"{where}: already sealed; a manifest is never rewritten")
        abstract = jax.tree.map(_abstract, _to_storable(like))
        orbax_quiet.install_quiet_hook()
        try:
            tree = self.manager.restore(step, args=self._ocp.args.StandardRestore(abstract))
        except Exception as e:
            orbax_quiet.quiet_failed_io()
            raise CheckpointError(f"{where}: cannot be read ({type(e).__name__}: "
                                  f"{str(e)[:300]})") from e
        atomic_write_text(where / MANIFEST, json.dumps(_sealed(
            {"format": MANIFEST_FORMAT, "step": int(step), "config_sha256": self._config_sha,
             "arrays": array_digests(tree), "files": _file_digests(where)}), indent=1) + "\n")

    def check_sealed(self, step: int) -> None:
        """Raise `DamagedStepError` unless ``step`` has a whole manifest that names
        this folder's config.json (a cheap check before `restore`'s full one)."""
        self._manifest(step)

    def _manifest(self, step: int) -> dict:
        where = self.directory / "steps" / str(step)
        path = where / MANIFEST
        if not path.is_file():
            raise DamagedStepError(f"{where}: not sealed (no {MANIFEST}: the run stopped "
                                   "between writing the step and sealing it, the manifest "
                                   "was deleted, or the step predates manifests -- then "
                                   "Checkpointer.seal, or for trained modules `python -m "
                                   "grounding_jax.robot.seal DIR`, seals it as it is)", step)
        try:
            m = json.loads(path.read_bytes().decode("utf-8"))
            body = {k: v for k, v in m.items() if k != "manifest_sha256"}
            ok = m["manifest_sha256"] == _sha256(json.dumps(body, sort_keys=True).encode())
        except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError,
                AttributeError) as e:
            raise DamagedStepError(f"{where}/{MANIFEST}: unreadable ({type(e).__name__})",
                                   step) from e
        if not ok or m.get("format") != MANIFEST_FORMAT or m.get("step") != step:
            raise DamagedStepError(f"{where}/{MANIFEST}: damaged (its checksum does not "
                                   "match its contents)", step)
        if m["config_sha256"] != self._config_sha:
            raise DamagedStepError(f"{self.directory / CONFIG_FILE}: edited after step "
                                   f"{step} was saved (its checksum differs from the one "
                                   "the step recorded)", step)
        return m

    def restore(self, step: int, like: Any) -> Any:
        """The tree saved at ``step``, with the structure, shapes and dtypes of ``like``,
        after checking the step against its manifest. ``like`` may be a function of the
        manifest's ``arrays`` (path -> shape, dtype) that returns it, for arrays whose shape
        only the step knows.

        Raises:
            DamagedStepError: the step is not sealed, or a file or an array differs from its
                checksum (the error names them).
            CheckpointError: arrays that do not match ``like``.
        """
        manifest = self._manifest(step)
        if callable(like):  # a tree whose shapes the step itself records
            like = like(manifest["arrays"])
        where = self.directory / "steps" / str(step)
        files = _file_digests(where)
        bad_files = sorted(n for n in set(files) | set(manifest["files"])
                           if files.get(n) != manifest["files"].get(n))
        target = _to_storable(like)
        abstract = jax.tree.map(_abstract, target)
        readable = all(n in files and n in manifest["files"]
                       and files[n]["size"] == manifest["files"][n]["size"]
                       and "/d/" in f"/{n}" and "ocdbt." in n for n in bad_files)
        if not readable:  # files missing, resized or in orbax's index: not worth a read
            raise DamagedStepError(f"{where}: damaged; files that differ from the manifest: "
                                   f"{', '.join(bad_files)}", step)
        orbax_quiet.install_quiet_hook()  # pytest and other tools may have replaced the hook since
        try:
            tree = self.manager.restore(step, args=self._ocp.args.StandardRestore(abstract))
        except Exception as e:  # orbax/tensorstore raise many types for damaged files
            orbax_quiet.quiet_failed_io()
            if bad_files:
                raise DamagedStepError(f"{where}: damaged: cannot be read ({type(e).__name__})"
                                       f"; files that differ from the manifest: "
                                       f"{', '.join(bad_files)}", step) from e
            raise CheckpointError(f"{where}: cannot read the checkpoint as this run expects "
                                  f"it ({type(e).__name__}: {str(e)[:300]}); its files are "
                                  "left as they are") from e
        got = jax.tree.structure(tree)
        if got != jax.tree.structure(target):
            raise CheckpointError(f"{where}: stored tree {got} does not match the expected one")
        for a, b in zip(jax.tree.leaves(tree), jax.tree.leaves(abstract), strict=True):
            if np.shape(a) != b.shape or np.asarray(a).dtype != b.dtype:
                raise CheckpointError(f"{where}: stored array {np.shape(a)} "
                                      f"{np.asarray(a).dtype} does not match the expected "
                                      f"{b.shape} {b.dtype}")
        arrays = array_digests(tree)
        bad_arrays = sorted(n for n in set(arrays) | set(manifest["arrays"])
                            if arrays.get(n) != manifest["arrays"].get(n))
        if bad_arrays or bad_files:
            what = []
            if bad_arrays:
                what.append(f"arrays whose bytes differ from their saved checksum: "
                            f"{', '.join(bad_arrays)}")
            if bad_files:
                what.append(f"files that differ from the manifest: {', '.join(bad_files)}")
            raise DamagedStepError(f"{where}: damaged; {'; '.join(what)}", step)
        return _from_storable(tree, like)

    def restore_latest(self, like: Any, fallback: bool = False,
                       say: Callable[[str], None] | None = None) -> tuple[int, Any] | None:
        """The newest step and its tree, or None when there is no step at all.

        Args:
            like: as for `restore`.
            fallback: a damaged newest step is skipped for the newest intact one (said
                through ``say``); else it is refused.
            say: where the fallback is reported (default: standard error).

        Raises:
            DamagedStepError: the newest step is damaged and ``fallback`` is off.
            CheckpointError: no step is intact (the error lists each step's fault).
        """
        say = say or (lambda msg: print(msg, file=sys.stderr, flush=True))
        faults = []
        for step in self.steps():
            try:
                return step, self.restore(step, like)
            except DamagedStepError as e:
                if not fallback:
                    raise
                faults.append(str(e))
                say(f"warning: {e}; trying the step before it")
        if faults:
            raise CheckpointError(f"{self.directory}: no intact step: " + " | ".join(faults))
        return None

    def set_aside_after(self, step: int | None) -> list[pathlib.Path]:
        """Move every step newer than ``step`` (all steps if None) to ``<dir>/damaged/``, so
        that a resumed run can write those steps again; nothing is deleted. Returns where
        they went."""
        moved = []
        for s in self.steps():
            if step is None or s > step:
                dest = self.directory / "damaged" / f"{s}-{time.strftime('%Y%m%dT%H%M%S')}"
                dest.parent.mkdir(exist_ok=True)
                os.replace(self.directory / "steps" / str(s), dest)
                moved.append(dest)
        if moved:
            self.manager.reload()
        return moved

    def close(self) -> None:
        """Wait for pending saves and release the checkpoint manager."""
        if self.manager is not None:
            with contextlib.suppress(Exception):
                self.manager.close()
            self.manager = None


def _abstract(x: Any) -> jax.ShapeDtypeStruct:
    """Shape and dtype of an array, a numpy scalar or a ShapeDtypeStruct."""
    if isinstance(x, (jax.Array, jax.ShapeDtypeStruct)):
        return jax.ShapeDtypeStruct(x.shape, x.dtype)
    a = np.asarray(x)
    return jax.ShapeDtypeStruct(a.shape, a.dtype)


def _is_key(x: Any) -> bool:
    return (isinstance(x, (jax.Array, jax.ShapeDtypeStruct))
            and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key))


def _to_storable(tree: Any) -> Any:
    """Typed PRNG keys -> their uint32 key data (orbax stores plain arrays)."""
    return jax.tree.map(lambda x: (jax.eval_shape(jax.random.key_data, x)
                                   if isinstance(x, jax.ShapeDtypeStruct) else
                                   jax.random.key_data(x)) if _is_key(x) else x, tree)


def _from_storable(tree: Any, like: Any) -> Any:
    def wrap(x, ref):
        impl = jax.random.key_impl(ref) if isinstance(ref, jax.Array) else None  # None: default
        return jax.random.wrap_key_data(x, impl=impl)

    return jax.tree.map(lambda x, ref: wrap(x, ref) if _is_key(ref) else x, tree, like)
