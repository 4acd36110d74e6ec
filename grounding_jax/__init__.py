"""grounding_jax: Farkaš, Malík & Rebrová (2012) -- iCub learns to point, touch, push and name.

Importing the package changes no JAX setting. ``train.py``, the sweep and experiment CLIs and
the benchmarks switch on JAX's persistent compilation cache with
`enable_compilation_cache`; call it yourself to share compiles between your runs.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from grounding_jax.robot.trained import Robot, load, save
    from grounding_jax.sim.env import Env, EnvConfig, EnvParams, State, Task, make_env, make_task
    from grounding_jax.sim.render import frames, write_video

from grounding_jax.core._lazy import lazy_names
from grounding_jax.core._version import __version__
from grounding_jax.core.jaxcache import enable_compilation_cache

#: the public names, imported on first use: ``import grounding_jax`` stays light, so that a
#: command-line tool (``python -m grounding_jax.sweep``) can take over SIGINT before JAX loads
_LAZY = {**{n: "grounding_jax.sim.env" for n in ("Env", "EnvConfig", "EnvParams", "State", "Task",
                                             "make_env", "make_task")},
         "Robot": "grounding_jax.robot.trained", "load": "grounding_jax.robot.trained",
         "save": "grounding_jax.robot.trained",
         "frames": "grounding_jax.sim.render", "write_video": "grounding_jax.sim.render"}


__getattr__, __dir__ = lazy_names("grounding_jax", _LAZY, globals())


__all__ = ["Env", "EnvConfig", "EnvParams", "State", "Task", "make_env", "make_task",
           "Robot", "load", "save", "frames", "write_video", "enable_compilation_cache",
           "__version__"]
