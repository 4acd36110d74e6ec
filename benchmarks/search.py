"""Search strategies compared on the action learner's tuning space: grid, random, Optuna-TPE,
ASHA and PBT -- each one's held-out success rate (the chosen configuration retrained on fresh
seeds from a key no search saw), the RL steps it spent searching, and its wall time.

The space is the tuning sweeps' own fields as ranges (``sweeps/al_tuning.toml`` for the
paper's action learner, ``sweeps/free_al_tuning.toml`` for the free family): an integer flag
becomes a choice, another integer a range, a float a log range when its values span 3x or
more, else a uniform one. The grid is the sweep file's own (one field at a time). The metric
is the success-rate mean at the end of training.

Goal: ASHA or PBT reaches the grid's held-out best within 2 points (0.02) using at most a
third of the grid's RL steps.

``--scale quick`` (the default, what ``results/benchmarks/search.json`` holds) shortens the
runs to fit a 2-core CPU in a few hours: fewer seeds and episodes than the sweep files;
``--scale full`` runs the files' own seeds and episodes (hours on a CPU).

Usage:  python benchmarks/search.py [--scale quick|full] [--families al,free]
            [--out results/benchmarks/search.json]
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import tempfile
import time
import tomllib

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from grounding_jax import sweep  # noqa: E402
from grounding_jax.core.io import atomic_write_text, code_fingerprint  # noqa: E402
from grounding_jax.core.jaxcache import enable_compilation_cache  # noqa: E402

#: the strategies, and variants of them with other settings (levers tried)
STRATEGIES = ("grid", "random", "optuna", "asha", "pbt", "pbt_small", "asha_late")
LABELS = {"grid": "grid (the sweep file's)", "optuna": "Optuna (TPE)",
          "asha": "ASHA (rungs at 1/9, 1/3, the end)",
          "asha_late": "ASHA (rungs at phase 1's end and the end)",
          "pbt": "PBT (population: a third of the grid's points, at least 4)",
          "pbt_small": "PBT (population: 30% of the grid's points, at least 3)"}
#: per family: the sweep file and, per scale, the run's settings (seeds, phase episodes,
#: chunk, held-out seeds)
FAMILIES = {
    "al": {"file": "sweeps/al_tuning.toml",
           "quick": {"seeds": 4, "phase1_episodes": 150, "phase2_episodes": 300, "chunk": 50,
                     "holdout_seeds": 8},
           "full": {"seeds": 8, "phase1_episodes": 150, "phase2_episodes": 1050, "chunk": 150,
                    "holdout_seeds": 8}},
    "free": {"file": "sweeps/free_al_tuning.toml",
             "quick": {"seeds": 3, "phase1_episodes": 300, "phase2_episodes": 300,
                       "chunk": 60, "holdout_seeds": 6},
             "full": {"seeds": 8, "phase1_episodes": 1000, "phase2_episodes": 1000,
                      "chunk": 125, "holdout_seeds": 8}},
}


def space_of(grid: dict[str, list], fields: dict) -> dict[str, dict]:
    """A grid's fields as ranges (see the module's docstring)."""
    out = {}
    for k, values in grid.items():
        if fields[k].type is int:
            out[k] = ({"choice": sorted(values)} if set(values) <= {0, 1}
                      else {"int": [min(values), max(values)]})
        elif fields[k].type is float:
            lo, hi = min(values), max(values)
            out[k] = {"log": [lo, hi]} if lo > 0 and hi / lo >= 3 else {"uniform": [lo, hi]}
        else:
            out[k] = {"choice": list(values)}
    return out


def specs(family: str, scale: str) -> dict[str, sweep.SweepSpec]:
    """The five strategies' sweeps of a family: the grid's points cost ``P * seeds *
    episodes``; random, Optuna and ASHA get as many trials as the grid has points (ASHA's rungs
    stop most of them early), PBT a population of a third of them (a third of the budget)."""
    f = FAMILIES[family]
    data = tomllib.loads((ROOT / f["file"]).read_text())
    s = f[scale]
    params = {**data.get("params", {}), "phase1_episodes": s["phase1_episodes"],
              "phase2_episodes": s["phase2_episodes"]}
    common = {k: v for k, v in data.items() if k not in ("grid", "design", "params",
                                                         "eval_at", "chunk", "seeds")}
    common |= {"seeds": s["seeds"], "chunk": s["chunk"], "metric": "success_mean",
               "params": params, "holdout_seeds": s["holdout_seeds"]}
    grid = {**common, "name": f"{family}_grid", "design": data.get("design", "product"),
            "grid": data["grid"]}
    out = {"grid": sweep.parse_spec(grid, f["file"])}
    n_points = len(out["grid"].points())
    space = space_of(data["grid"], sweep.FIELDS["al"])
    episodes = s["phase1_episodes"] + s["phase2_episodes"]
    rungs = [episodes // 9 // s["chunk"] * s["chunk"] or s["chunk"],
             episodes // 3 // s["chunk"] * s["chunk"], episodes]
    search = {**common, "space": space}
    out["random"] = {**search, "search": "random", "trials": n_points}
    out["optuna"] = {**search, "search": "optuna", "trials": n_points,
                     "optuna": {"sampler": "tpe", "batch": math.ceil(n_points / 3)}}
    out["asha"] = {**search, "search": "asha", "trials": n_points,
                   "asha": {"eta": 3, "rungs": sorted(set(rungs)),
                            "batch": max(2, n_points // 2)}}
    # ASHA ranked only once phase 1 is over (its rungs inside phase 1 rank the phase-1 rule's
    # numbers), with as many trials as a third of the grid's budget pays for
    p1 = s["phase1_episodes"]
    late_cost = p1 + (episodes - p1) / 3
    out["asha_late"] = {**search, "search": "asha",
                        "trials": max(3, int(n_points * episodes / 3 / late_cost)),
                        "asha": {"eta": 3, "rungs": [p1, episodes],
                                 "batch": max(2, n_points // 2)}}
    out["pbt"] = {**search, "search": "pbt", "trials": max(4, n_points // 3),
                  "pbt": {"interval": max(s["chunk"], episodes // 6 // s["chunk"] * s["chunk"]),
                          "fraction": 0.25}}
    out["pbt_small"] = {**out["pbt"], "trials": max(3, int(n_points * 0.3))}
    for k in STRATEGIES[1:]:
        out[k] = sweep.parse_spec({**out[k], "name": f"{family}_{k}"}, f["file"])
    return out


def grid_steps(folder: pathlib.Path) -> int:
    """RL steps a grid spent: every run's every episode's steps."""
    with np.load(folder / "metrics.npz") as m:
        return int(m["steps"].sum())


def run_family(family: str, scale: str, work: pathlib.Path, only: list[str],
               earlier: dict) -> dict:
    """Run a family's strategies (``only`` those; the others' entries are kept from
    ``earlier``, the family's entry of an earlier result file)."""
    out = dict(earlier.get("strategies", {}))
    for name, spec in specs(family, scale).items():
        if name not in only:
            continue
        t0 = time.perf_counter()
        s = sweep.run(spec, work, show_progress=False, overwrite=True)
        wall = time.perf_counter() - t0
        if name == "grid":
            best = spec.base() | s["best"]
            steps = grid_steps(work / spec.name)
            searched = len(s["points"])
        else:
            best = spec.base() | s["best"]["params"]
            steps = s["budget"]["rl_steps"]
            searched = s["budget"]["trials_started"]
        swept = list(spec.grid or spec.space)
        out[name] = {"heldout": s["heldout"]["mean"], "heldout_std": s["heldout"]["std"],
                     "heldout_runs": s["heldout"]["runs"], "rl_steps": steps,
                     "wall_s": wall, "trials": searched,
                     "best": {k: best[k] for k in swept}}
        if spec.search == "pbt":
            out[name]["schedule"] = s["best"]["schedule"]
        out[name]["code"] = code_fingerprint()
        print(f"{family} {name}: held-out {s['heldout']['mean']:.3f}, {steps} RL steps, "
              f"{wall:.0f} s", flush=True)
    out = {k: out[k] for k in STRATEGIES if k in out}
    return with_ratios({"strategies": out, "settings": FAMILIES[family][scale]})


def with_ratios(family: dict) -> dict:
    """A family's entry with each strategy's RL steps and held-out number against the
    grid's, and the strategies that meet the goal (none without a grid)."""
    out = family["strategies"]
    if "grid" not in out:
        return family
    grid = out["grid"]
    for v in out.values():
        v["steps_vs_grid"] = v["rl_steps"] / grid["rl_steps"]
        v["heldout_vs_grid"] = v["heldout"] - grid["heldout"]
    return family | {"goal_met_by": [k for k in out if k.startswith(("asha", "pbt"))
                                     and out[k]["heldout_vs_grid"] >= -0.02
                                     and out[k]["steps_vs_grid"] <= 1 / 3]}


def table(result: dict) -> str:
    """The Markdown table of a run (``results/benchmarks/search.json``)."""
    rows = ["| space | strategy | trials | held-out success (mean ± std) | vs grid | RL steps | "
            "steps vs grid | wall (s) |", "|---|---|---|---|---|---|---|---|"]
    for family, r in result["families"].items():
        for name, v in r["strategies"].items():
            rows.append(f"| {family} | {LABELS.get(name, name)} | {v['trials']} | "
                        f"{v['heldout']:.3f} ± {v['heldout_std']:.3f} | "
                        f"{v.get('heldout_vs_grid', math.nan):+.3f} | {v['rl_steps']:,} | "
                        f"{v.get('steps_vs_grid', math.nan):.2f} | {v['wall_s']:.0f} |")
    return "\n".join(rows) + "\n"


def merge(path: pathlib.Path, other: pathlib.Path) -> None:
    """Fold ``other``'s strategies into the result file ``path`` (ratios recomputed)."""
    result, extra = json.loads(path.read_text()), json.loads(other.read_text())
    if result["scale"] != extra["scale"]:
        raise SystemExit(f"--merge: {other} holds the {extra['scale']!r} scale, {path} the "
                         f"{result['scale']!r} one")
    for f, fam in extra["families"].items():
        mine = result["families"].setdefault(f, {"strategies": {}, "settings":
                                                 fam["settings"]})
        mine["strategies"] = {k: ({**mine["strategies"], **fam["strategies"]})[k]
                              for k in STRATEGIES
                              if k in mine["strategies"] or k in fam["strategies"]}
        result["families"][f] = with_ratios(mine)
    result["strategies"] = result["families"]["al"]["strategies"]
    atomic_write_text(path, json.dumps(result, indent=1) + "\n")
    print(table(result))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scale", choices=("quick", "full"), default="quick")
    ap.add_argument("--families", default="al,free")
    ap.add_argument("--out", default="results/benchmarks/search.json")
    ap.add_argument("--merge", default=None, metavar="FILE",
                    help="fold the strategies of another result file (same scale) into --out "
                         "and exit")
    ap.add_argument("--only", default=",".join(STRATEGIES),
                    help="run only these strategies; the others' numbers are kept from --out "
                         "(each entry records the code fingerprint it ran with)")
    args = ap.parse_args()
    only = args.only.split(",")
    if bad := [s for s in only if s not in STRATEGIES]:
        ap.error(f"--only: unknown {bad[0]!r}; accepted values: {STRATEGIES}")
    if args.merge:
        merge(ROOT / args.out, pathlib.Path(args.merge))
        return
    families = args.families.split(",")
    bad = [f for f in families if f not in FAMILIES]
    if bad:
        ap.error(f"--families: unknown {bad[0]!r}; accepted values: {sorted(FAMILIES)}")
    enable_compilation_cache()
    for f in families:
        specs(f, args.scale)  # every sweep validated before anything runs
    path = ROOT / args.out
    earlier = json.loads(path.read_text()) if path.is_file() and set(only) != set(STRATEGIES) \
        else {}
    if earlier and earlier.get("scale") != args.scale:
        ap.error(f"--only: {args.out} holds the {earlier.get('scale')!r} scale, not "
                 f"{args.scale!r}")
    result = {"scale": args.scale, "metric": "success_mean",
              "families": dict(earlier.get("families", {}))}
    with tempfile.TemporaryDirectory() as tmp:
        for f in families:
            result["families"][f] = run_family(f, args.scale, pathlib.Path(tmp), only,
                                               result["families"].get(f, {}))
            atomic_write_text(path, json.dumps(result | {"strategies": result["families"][
                next(iter(result["families"]))]["strategies"]}, indent=1) + "\n")
    result["strategies"] = result["families"]["al" if "al" in result["families"] else
                                              families[0]]["strategies"]
    atomic_write_text(path, json.dumps(result, indent=1) + "\n")
    print(table(result))


if __name__ == "__main__":
    main()
