"""``python -m grounding_jax.sweep FILE [--set k=v] [--resume]``: run a sweep file.

The entry point sits above the layers: it takes over SIGINT before the heavy imports, and the
package's own adapters (AL, TL) reach the runner through their entry points.
"""

from __future__ import annotations

if __name__ == "__main__":  # before the heavy imports: an early Ctrl-C exits cleanly
    from grounding_jax.core import guard as _early

    _early.quiet_start(["python", "-m", "grounding_jax.sweep"])

import argparse
import pathlib
import sys

from grounding_jax.core import guard
from grounding_jax.core.checkpoint import CheckpointError
from grounding_jax.sweep.runner import EXECUTORS, run
from grounding_jax.sweep.spec import SweepError, adapter, load_spec


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m grounding_jax.sweep",
                                 description="Run a hyperparameter sweep from a TOML file.")
    ap.add_argument("file", help="sweep file, e.g. sweeps/fig8a_critic_lr.toml")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a key: seeds=2, critic_lr=0.01,0.1, phase2_episodes=100")
    ap.add_argument("--out", default="results/sweeps", help="parent output folder")
    ap.add_argument("--seed", type=int, default=None, help="overrides the file's seed")
    ap.add_argument("--resume", action="store_true", help="continue from the checkpoints")
    ap.add_argument("--overwrite", action="store_true",
                    help="delete the sweep's earlier checkpoints and start over")
    ap.add_argument("--executor", default="local", help=f"one of {EXECUTORS}")
    ap.add_argument("--ray-address", default=None,
                    help="Ray cluster address, e.g. ray://head:10001 (default: local cluster)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    from grounding_jax.core.jaxcache import enable_compilation_cache

    enable_compilation_cache()
    try:
        with guard.handle_interrupts():
            if args.executor not in EXECUTORS:
                raise SweepError(f"--executor: unknown value {args.executor!r}; accepted "
                                 f"values: {EXECUTORS}")
            spec = load_spec(args.file, args.set)
            summary = run(spec, args.out, resume=args.resume, overwrite=args.overwrite,
                          executor=args.executor, ray_address=args.ray_address,
                          seed=args.seed, show_progress=not args.no_progress)
    except (SweepError, CheckpointError, guard.FolderBusyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a disk or folder fault outside the paths above
        print(f"error: {e.filename or args.out}: {e.strerror or e}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, guard.Interrupted) as e:
        print(f"\ninterrupted ({'SIGINT' if isinstance(e, KeyboardInterrupt) else e}): the "
              "newest complete checkpoint of each group is kept; continue with:\n  "
              f"{resume_command(argv)}", file=sys.stderr, flush=True)
        if argv is None:  # the command line (not a caller's process): end it now
            guard.leave(guard.exit_code(e))
        return guard.exit_code(e)
    folder = pathlib.Path(args.out) / spec.name
    if spec.search != "grid":
        print(search_lines(spec, summary))
        print(f"wrote {folder}/ (sweep.json, runs.csv, {spec.figure}.png) in "
              f"{summary['wall_s']:.1f} s")
        return 0
    for p in summary["points"]:
        mean = "diverged" if p["mean"] is None else f"{p['mean']:.4g} ± {p['std']:.2g}"
        flag = f"  ({len(p['diverged'])} diverged)" if p["diverged"] else ""
        print(f"{p['point']}: {spec.metric} {mean}{flag}")
    for p in summary.get("success", []):
        print(f"{p['point']}: success of the median run at episode "
              f"{summary['evaluations'][-1]}: " + ", ".join(
                  f"{k} {p['rates'][k]['median']:.2f}" for k in adapter(spec.module).success))
    if "heldout" in summary:
        print(heldout_line(summary["heldout"], spec.metric))
    print(f"wrote {folder}/ (sweep.json, runs.csv, {spec.figure}.png) in "
          f"{summary['wall_s']:.1f} s")
    return 0


def heldout_line(h: dict, metric: str) -> str:
    """The held-out check in one line."""
    if h["mean"] is None:
        return f"held-out check on {h['seeds']} fresh seeds: every run diverged"
    return (f"held-out check on {h['seeds']} fresh seeds: {metric} {h['mean']:.4g} ± "
            f"{h['std']:.2g}" + (f" ({len(h['diverged'])} diverged)" if h["diverged"] else ""))


def search_lines(spec, summary: dict) -> str:
    """A search's result: the best configuration, the budget spent, the held-out check."""
    b, best = summary["budget"], summary["best"]
    unit = adapter(spec.module).unit
    lines = [f"{spec.search}: {b['trials_started']} trials started, {b[unit]} run-{unit} and "
             f"{b['rl_steps']} RL steps spent ({summary['diverged_trials']} trials diverged)"]
    if best is None:
        return "\n".join(lines + ["every trial diverged: no best configuration"])
    lines.append(f"best: trial {best['index']} {best['params']}: {spec.metric} "
                 f"{best['evaluations'][-1][1]:.4g} on the searched seeds")
    if spec.search == "pbt":
        lines.append("its schedule: " + "; ".join(f"from {u}: {p}" for u, p in
                                                   best["schedule"]))
    if "heldout" in summary:
        lines.append(heldout_line(summary["heldout"], spec.metric) + " (the number to report)")
    return "\n".join(lines)


def resume_command(argv: list[str] | None = None) -> str:
    """The command line that continues this one: the same arguments with ``--resume``
    instead of ``--overwrite``."""
    return guard.resume_command(["python", "-m", "grounding_jax.sweep"], argv)



if __name__ == "__main__":
    sys.exit(main())
