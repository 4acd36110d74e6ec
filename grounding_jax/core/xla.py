"""Compiler options of the package's physics programs.

On the CPU, XLA hands each program to LLVM at optimisation level 2 by default. The programs
that step the C MuJoCo physics (episodes, AL training chunks, success tables, the robot's
`perform`) spend their run time in the physics handler, not in LLVM's code: at level 1 they
compile in about half the time, run as fast and give the same numbers, bit for bit (a whole
quick ``train.py`` run compared leaf by leaf). The networks' own programs (TL, ESN) keep
level 2: at level 1 their float results moved and the TL trained slower. MJX physics is
compiled XLA code, so its programs keep the default too, as does every backend but the CPU.
"""

from __future__ import annotations

from typing import Any

import jax

#: the options of `physics_jit` on the CPU with the C MuJoCo backend
CPU_PHYSICS_OPTIONS: dict[str, Any] = {"xla_backend_optimization_level": 1}


def _backend(env: Any) -> str:
    """The physics backend of an env, its static config, or the backend's name."""
    if isinstance(env, str):
        return env
    return getattr(env, "config", env).backend


def physics_options(env: Any) -> dict[str, Any] | None:
    """The compiler options of a program that steps ``env``'s physics on JAX's default device
    (``env``: an `Env`, its `EnvConfig`, or the backend's name, ``"mujoco"`` or ``"mjx"``):
    `CPU_PHYSICS_OPTIONS` for C MuJoCo on the CPU, else None (XLA's defaults)."""
    if _backend(env) == "mujoco" and jax.default_backend() == "cpu":
        return dict(CPU_PHYSICS_OPTIONS)
    return None


def physics_jit(fun, env: Any, **kwargs: Any):
    """``jax.jit(fun, **kwargs)`` with `physics_options` for ``env``: for a function whose
    work is stepping the physics (an episode, a batch of them, a training chunk)."""
    return jax.jit(fun, compiler_options=physics_options(env), **kwargs)
