"""grounding_jax: Farkaš, Malík & Rebrová (2012) -- iCub learns to point, touch, push and name.

Importing the package switches on JAX's persistent compilation cache, in
``$GROUNDING_JAX_CACHE`` (default ``~/.cache/grounding_jax/jax``); set
``GROUNDING_JAX_CACHE=off`` to leave JAX's own setting alone.
"""

from __future__ import annotations

import os
import pathlib

__version__ = "0.1.0"


def _enable_compilation_cache() -> str | None:
    where = os.environ.get("GROUNDING_JAX_CACHE", "")
    if where.lower() in ("off", "0", "false", "none"):
        return None
    path = pathlib.Path(where or pathlib.Path.home() / ".cache" / "grounding_jax" / "jax")
    path.mkdir(parents=True, exist_ok=True)
    import jax

    jax.config.update("jax_compilation_cache_dir", str(path))
    # cache every compile that takes noticeable time, not only the slowest ones
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return str(path)


COMPILATION_CACHE_DIR = _enable_compilation_cache()

from grounding_jax.env import (  # noqa: E402
    Env,
    EnvConfig,
    EnvParams,
    State,
    Task,
    make_env,
    make_task,
)
from grounding_jax.trained import Robot, load  # noqa: E402

__all__ = ["Env", "EnvConfig", "EnvParams", "State", "Task", "make_env", "make_task",
           "Robot", "load", "COMPILATION_CACHE_DIR", "__version__"]
