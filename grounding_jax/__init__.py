"""grounding_jax: Farkaš, Malík & Rebrová (2012) -- iCub learns to point, touch, push and name.

Importing the package changes no JAX setting. ``train.py``, the sweep and experiment CLIs and
the benchmarks switch on JAX's persistent compilation cache with
:func:`enable_compilation_cache`; call it yourself to share compiles between your runs.
"""

from __future__ import annotations

import importlib
import os
import pathlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from grounding_jax.env import Env, EnvConfig, EnvParams, State, Task, make_env, make_task
    from grounding_jax.trained import Robot, load

__version__ = "0.1.0"

#: the public names, imported on first use: ``import grounding_jax`` stays light, so that a
#: command-line tool (``python -m grounding_jax.sweep``) can take over SIGINT before JAX loads
_LAZY = {**{n: "grounding_jax.env" for n in ("Env", "EnvConfig", "EnvParams", "State", "Task",
                                             "make_env", "make_task")},
         "Robot": "grounding_jax.trained", "load": "grounding_jax.trained"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'grounding_jax' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))

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
    # each compile in under 0.5 s, and together they cost ~20 s in every process (README)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return str(path)


__all__ = ["Env", "EnvConfig", "EnvParams", "State", "Task", "make_env", "make_task",
           "Robot", "load", "enable_compilation_cache", "__version__"]
