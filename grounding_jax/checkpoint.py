"""Checkpoints: an orbax ``CheckpointManager`` per folder, with the run's config as JSON beside.

Layout of a checkpoint folder::

    <dir>/config.json     what produced it: {"kind", "version", "config"}
    <dir>/steps/<step>/   orbax checkpoints (written atomically by orbax: a run killed while
                          saving leaves only a temporary folder, which is never read)

A folder is only ever opened for the config it was written with, by the package version that
wrote it; anything else is refused with :class:`CheckpointError` before a byte is written.
PRNG keys are stored as their raw ``key_data`` (uint32) and wrapped again on restore.
"""

from __future__ import annotations

import json
import pathlib
from typing import Any

import jax
import numpy as np

from grounding_jax._io import atomic_write_text

CONFIG_FILE = "config.json"


class CheckpointError(RuntimeError):
    """A checkpoint folder that cannot be used: corrupt, or written for another config or
    package version."""


def _version() -> str:
    from grounding_jax import __version__

    return __version__


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
        stored = json.loads(path.read_text())
        kind, version, config = stored["kind"], stored["version"], stored["config"]
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise CheckpointError(f"{path}: corrupt checkpoint config ({e})") from e
    if version != _version():
        raise CheckpointError(f"{path}: written by grounding_jax {version}, this is "
                              f"{_version()}; refusing to mix versions (rerun, or install "
                              f"grounding_jax=={version} to load it)")
    return {"kind": kind, "version": version, "config": config}


class Checkpointer:
    """Save and restore pytrees of arrays at integer steps in one folder.

    Args:
        directory: the checkpoint folder (created if missing).
        kind: what is stored (``"sweep-group"``, ``"modules"``, ...), checked on reopen.
        config: JSON-able config of the run; a folder written for another config is refused.
        max_to_keep: checkpoints kept (older ones are deleted after a newer one is complete).
    """

    def __init__(self, directory: str | pathlib.Path, kind: str, config: dict,
                 max_to_keep: int = 2) -> None:
        import orbax.checkpoint as ocp

        self.directory = pathlib.Path(directory).absolute()
        config = json.loads(json.dumps(config))  # tuples -> lists, as stored
        if (self.directory / CONFIG_FILE).exists():
            stored = read_config(self.directory)
            if stored["kind"] != kind:
                raise CheckpointError(f"{self.directory}: holds a {stored['kind']!r} "
                                      f"checkpoint, not {kind!r}")
            bad = _diff(stored["config"], config)
            if bad:
                raise CheckpointError(f"{self.directory}: written for another config (fields "
                                      f"that differ: {', '.join(bad)}); use another folder or "
                                      "the original settings")
        else:
            self.directory.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.directory / CONFIG_FILE, json.dumps(
                {"kind": kind, "version": _version(), "config": config}, indent=2) + "\n")
        self._ocp = ocp
        self.manager = ocp.CheckpointManager(
            self.directory / "steps",
            options=ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=True,
                                                 enable_async_checkpointing=False))

    def latest_step(self) -> int | None:
        """The newest complete checkpoint's step, or None."""
        return self.manager.latest_step()

    def save(self, step: int, tree: Any) -> None:
        """Write ``tree`` at ``step`` (blocking; atomic)."""
        self.manager.save(step, args=self._ocp.args.StandardSave(_to_storable(tree)))
        self.manager.wait_until_finished()

    def restore(self, step: int, like: Any) -> Any:
        """The tree saved at ``step``, with the structure, shapes and dtypes of ``like``.

        Raises:
            CheckpointError: unreadable files, or arrays that do not match ``like``.
        """
        target = _to_storable(like)
        abstract = jax.tree.map(_abstract, target)
        where = self.directory / "steps" / str(step)
        try:
            tree = self.manager.restore(step, args=self._ocp.args.StandardRestore(abstract))
        except Exception as e:  # orbax/tensorstore raise many types for damaged files
            raise CheckpointError(f"{where}: cannot read the checkpoint as this run expects it "
                                  f"({type(e).__name__}: {str(e)[:300]}); its files are left "
                                  "as they are") from e
        got = jax.tree.structure(tree)
        if got != jax.tree.structure(target):
            raise CheckpointError(f"{where}: stored tree {got} does not match the expected one")
        for a, b in zip(jax.tree.leaves(tree), jax.tree.leaves(abstract), strict=True):
            if np.shape(a) != b.shape or np.asarray(a).dtype != b.dtype:
                raise CheckpointError(f"{where}: stored array {np.shape(a)} "
                                      f"{np.asarray(a).dtype} does not match the expected "
                                      f"{b.shape} {b.dtype}")
        return _from_storable(tree, like)

    def close(self) -> None:
        self.manager.close()


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
