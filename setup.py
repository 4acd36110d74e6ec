"""The package's one compiled part: the C MuJoCo physics step as an XLA FFI handler.

It is optional: where no C++ compiler is found the install goes on without it, and the physics
runs through the ``ctypes`` handler instead (``grounding_jax.sim.physics``). Everything else
about the package is in ``pyproject.toml``.
"""

import sys

from setuptools import Extension, setup

unix = sys.platform != "win32"
setup(ext_modules=[Extension(
    "grounding_jax.sim._mjstep", ["grounding_jax/sim/_mjstep.cc"],
    extra_compile_args=["-O2", "-std=c++17"] if unix else ["/O2", "/std:c++17"],
    extra_link_args=["-pthread"] if unix else [], optional=True)])
