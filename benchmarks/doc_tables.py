"""The documentation's measured tables, generated from the benchmark result files.

A page marks a generated table with ``<!-- table: NAME -->`` ... ``<!-- end table -->``; this
script rewrites each from its result file with the benchmark script's own ``table()``, so
text and results cannot drift. ``--check`` fails (exit 1) when a page is stale.

Usage:  python benchmarks/doc_tables.py [--check]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
import sys

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

#: table name -> (result file, benchmark module whose table() renders it[, the function's
#: name when it is not ``table``)
TABLES = {
    "faults": ("results/benchmarks/faults.json", "faults"),
    "env_throughput": ("results/benchmarks/env_throughput.json", "env_throughput"),
    "al_throughput": ("results/benchmarks/al_throughput.json", "al_throughput"),
    "tl_throughput": ("results/benchmarks/tl_throughput.json", "tl_throughput"),
    "search": ("results/benchmarks/search.json", "search"),
    "compile_options": ("results/benchmarks/compile_options.json", "compile_options"),
    "physics_options": ("results/benchmarks/physics_options.json", "physics_options"),
    "frames_levers": ("results/tuning/frames_levers.json", "frames_levers"),
    "together_seeds": ("results/tuning/together_seeds.json", "together_seeds"),
    "together_seeds_paper_tl": ("results/tuning/together_seeds_paper_tl.json",
                                "together_seeds"),
    "together_seeds_slow_tl": ("results/tuning/together_seeds_slow_tl.json",
                               "together_seeds"),
    "together_tl_curves": ("results/tuning/together_tl_curves.json", "together_seeds",
                           "curves_table"),
    "together_report": ("results/paper/together/together.json", "together_seeds",
                        "stage_table"),
}
BLOCK = re.compile(r"(<!-- table: (\w+) -->\n).*?(<!-- end table -->)", re.S)


def render(name: str) -> str:
    """The table ``name`` from its result file."""
    import importlib

    path, module, *function = TABLES[name]
    render_it = getattr(importlib.import_module(module), (function or ["table"])[0])
    return render_it(json.loads((ROOT / path).read_text()))


def rewrite(text: str, source: str) -> str:
    """``text`` with every marked table regenerated."""
    def one(m: re.Match) -> str:
        if m.group(2) not in TABLES:
            raise ValueError(f"{source}: unknown table {m.group(2)!r}; accepted: "
                             f"{sorted(TABLES)}")
        return m.group(1) + render(m.group(2)) + m.group(3)

    return BLOCK.sub(one, text)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python benchmarks/doc_tables.py")
    ap.add_argument("--check", action="store_true", help="exit 1 if a page is stale")
    args = ap.parse_args(argv)
    stale = []
    for page in sorted((ROOT / "docs").glob("*.md")):
        text = page.read_text()
        new = rewrite(text, str(page))
        if new != text:
            stale.append(page.name)
            if not args.check:
                page.write_text(new)
    if args.check and stale:
        print(f"stale tables in {stale}: run python benchmarks/doc_tables.py", file=sys.stderr)
        return 1
    print(f"rewrote {stale}" if stale else "up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
