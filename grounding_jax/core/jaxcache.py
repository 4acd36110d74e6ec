"""JAX's persistent compilation cache, switched on by the package's command-line tools."""

from __future__ import annotations

import os
import pathlib
import sys
import tempfile
import uuid

_CACHE_OFF = ("off", "0", "false", "none")


def _writable(path: pathlib.Path) -> str | None:
    """None if ``path`` can be created and written to, else why not (one phrase)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".probe-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        return e.strerror or str(e)
    return None


def _fallback_root() -> pathlib.Path:
    return pathlib.Path(tempfile.gettempdir()) / f"grounding_jax-{os.getuid()}"


def _matplotlib_fallback() -> list[str]:
    """Point matplotlib at a temporary config folder when its own cannot be written (a
    read-only home): it would otherwise print two long warnings of its own on import."""
    if "MPLCONFIGDIR" in os.environ or "matplotlib" in sys.modules:
        return []
    base = os.environ.get("XDG_CONFIG_HOME") or pathlib.Path.home() / ".config"
    if _writable(pathlib.Path(base) / "matplotlib") is None:
        return []
    folder = _fallback_root() / "matplotlib"
    if _writable(folder) is not None:
        return []  # matplotlib makes a temporary folder itself, and says so
    os.environ["MPLCONFIGDIR"] = str(folder)
    return [f"matplotlib's config folder cannot be written; using {folder}"]


def enable_compilation_cache(path: str | os.PathLike | None = None) -> str | None:
    """Switch on JAX's persistent compilation cache (a global JAX setting).

    Args:
        path: the cache folder; default `$GROUNDING_JAX_CACHE`, else
            `~/.cache/grounding_jax/jax`. `GROUNDING_JAX_CACHE=off` (or `0`, `false`,
            `none`) leaves JAX's settings alone when no `path` is given.

    A folder that cannot be written (a read-only home, a full disk) is not fatal: the cache
    moves to a folder under the system's temporary directory, with one warning line on
    stderr, and if that cannot be written either the run goes on without a cache (matplotlib's
    config folder likewise, through `MPLCONFIGDIR`).

    Returns:
        The folder in use, or None when switched off.
    """
    moved = _matplotlib_fallback()
    if path is None:
        where = os.environ.get("GROUNDING_JAX_CACHE", "")
        off = where.lower() in _CACHE_OFF
        path = None if off else where or pathlib.Path.home() / ".cache" / "grounding_jax" / "jax"
    path = None if path is None else pathlib.Path(path)
    why = None if path is None else _writable(path)
    if why is not None:
        fallback = _fallback_root() / "jax"
        used = fallback if _writable(fallback) is None else None
        moved.insert(0, f"the compilation cache {path} cannot be written ({why}); "
                     + (f"using {fallback} instead" if used else "running without one")
                     + " (set GROUNDING_JAX_CACHE to a writable folder, or =off)")
        path = used
    if moved:
        print("warning: " + "; ".join(moved), file=sys.stderr, flush=True)
    if path is None:
        return None
    import jax

    jax.config.update("jax_compilation_cache_dir", str(path))
    # cache every compile, even the short ones: a quick train.py run makes ~600 programs that
    # each compile in under 0.5 s, and together they cost ~20 s in every process
    # (docs/reproduction.md)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return str(path)
