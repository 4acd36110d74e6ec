"""Hyperparameter sweeps from TOML files: the spec (`spec`, a
search's space in `space`), the runner
(`runner`; searches in `search`) and the
summaries (`summary`); ``python -m grounding_jax.sweep FILE`` runs
one.

The public names are imported on first use, so that the command line takes over SIGINT
before JAX loads.
"""

from __future__ import annotations

from grounding_jax.core._lazy import lazy_names

_LAZY = {
    **{n: "grounding_jax.sweep.spec" for n in (
        "SweepError", "SweepSpec", "Field", "Adapter", "register", "adapter", "adapters",
        "field_from", "traced_fields", "parse_spec", "apply_overrides", "load_spec",
        "module_config", "FIELDS", "METRICS", "TOP_KEYS", "DESIGNS", "SEARCHES", "Pieces")},
    **{n: "grounding_jax.sweep.runner" for n in (
        "run", "run_group", "split_run_keys", "trained_agents", "identity", "EXECUTORS")},
    **{n: "grounding_jax.sweep.batching" for n in ("chunk_stops", "restore_to_resume")},
    **{n: "grounding_jax.sweep.search" for n in ("Trial", "best_trial")},
    **{n: "grounding_jax.sweep.summary" for n in ("point_label", "summaries")},
    # the command line (python -m grounding_jax.sweep), callable in a process of your own
    **{n: "grounding_jax.sweep.__main__" for n in ("main", "resume_command")},
}


__getattr__, __dir__ = lazy_names("grounding_jax.sweep", _LAZY, globals())


__all__ = sorted(_LAZY)
