"""JAX's persistent compilation cache, switched on by the package's command-line tools."""

from __future__ import annotations

import os
import pathlib

_CACHE_OFF = ("off", "0", "false", "none")


def enable_compilation_cache(path: str | os.PathLike | None = None) -> str | None:
    """Switch on JAX's persistent compilation cache (a global JAX setting).

    Args:
        path: the cache folder; default ``$GROUNDING_JAX_CACHE``, else
            ``~/.cache/grounding_jax/jax``. ``GROUNDING_JAX_CACHE=off`` (or ``0``, ``false``,
            ``none``) leaves JAX's settings alone when no ``path`` is given.

    Returns:
        The folder in use, or None when switched off.
    """
    if path is None:
        where = os.environ.get("GROUNDING_JAX_CACHE", "")
        if where.lower() in _CACHE_OFF:
            return None
        path = where or pathlib.Path.home() / ".cache" / "grounding_jax" / "jax"
    path = pathlib.Path(path)
    path.mkdir(parents=True, exist_ok=True)
    import jax

    jax.config.update("jax_compilation_cache_dir", str(path))
    # cache every compile, even the short ones: a quick train.py run makes ~600 programs that
    # each compile in under 0.5 s, and together they cost ~20 s in every process
    # (docs/reproduction.md)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return str(path)
