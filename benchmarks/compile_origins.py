"""Where a `train.py` run's XLA programs come from: each program built (compiled, or loaded
from the persistent cache) with the package line that asked for it.

    python benchmarks/compile_origins.py [--json PATH] [--top N] -- [train.py arguments]

It runs `train.py` in this process with a `jax.monitoring` listener that, for every program
JAX builds, records its name, its build seconds and the innermost frame of this package (or of
`train.py`) on the stack. The summary groups the programs by that line: eager one-operation
programs show up as many cheap builds at one host-side line, the large ones as a few slow
builds. It prints the top lines and writes the whole table as JSON (default
`results/benchmarks/compile_origins.json`).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import pathlib
import sys
import time
import traceback

ROOT = pathlib.Path(__file__).resolve().parent.parent
_BUILD = "/jax/core/compile/backend_compile_duration"


def _origin() -> str:
    """The innermost stack frame in this package or train.py, as ``path:line:function``."""
    for frame in reversed(traceback.extract_stack()):
        f = frame.filename
        if ("grounding_jax" in f and "compiles.py" not in f) or f.endswith("train.py"):
            return f"{os.path.relpath(f, ROOT)}:{frame.lineno}:{frame.name}"
    return "?"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", default=str(ROOT / "results/benchmarks/compile_origins.json"))
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("train_args", nargs="*", help="arguments for train.py (after --)")
    args = parser.parse_args(argv)

    import jax

    sys.path.insert(0, str(ROOT))
    rows: list[tuple[str, str, float]] = []

    def on_duration(event: str, duration: float, **kw) -> None:
        if event == _BUILD:
            rows.append((_origin(), str(kw.get("fun_name", "?")), duration))

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    import train

    t = time.perf_counter()
    rc = train.main(args.train_args)
    wall = time.perf_counter() - t
    by: dict[str, dict] = collections.defaultdict(
        lambda: {"programs": 0, "build_s": 0.0, "names": collections.Counter()})
    for origin, name, seconds in rows:
        by[origin]["programs"] += 1
        by[origin]["build_s"] += seconds
        by[origin]["names"][name] += 1
    table = sorted(({"origin": k, "programs": v["programs"], "build_s": round(v["build_s"], 2),
                     "names": dict(v["names"])} for k, v in by.items()),
                   key=lambda r: (-r["programs"], -r["build_s"]))
    out = {"train_args": args.train_args, "rc": rc, "wall_s": round(wall, 1),
           "programs": len(rows), "build_s": round(sum(r[2] for r in rows), 1),
           "by_origin": table}
    path = pathlib.Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(out, indent=1) + "\n")
    tmp.replace(path)
    print(f"{len(rows)} programs, {out['build_s']} s building them; by origin:")
    for r in table[:args.top]:
        print(f"{r['programs']:5d} {r['build_s']:7.1f} s  {r['origin']}")
    print(f"wrote {path}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
