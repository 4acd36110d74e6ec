"""The index of the one-off tuning outputs in ``results/tuning/``, generated from the files.

Each JSON there was written by a tuning script (``benchmarks/free_tuning.py``,
``benchmarks/tl_xy_tuning.py``, ``benchmarks/substeps.py --episodes 1200 --key K``,
``benchmarks/al_variants.py``); this
script lists what each one measured and the numbers it holds, so the index cannot drift from
the files. It writes ``results/tuning/README.md`` and the same table into ``docs/tuning.md``.

Usage:  python benchmarks/tuning_index.py [--check]   (--check: fail if either is stale)
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
TUNING = ROOT / "results" / "tuning"
ACTIONS = ("point", "touch", "push")


def _pct(v: float | None) -> str:
    return "–" if v is None else f"{100 * v:.0f}%"


def _free_rows(files: list[pathlib.Path]) -> list[str]:
    rows = ["| file | key | episodes (phase 1 + 2) | agents | settings changed (from the "
            "defaults when it ran; the tag names the rest) | median agent, held-out "
            "placements: point / touch / push |",
            "|---|---|---|---|---|---|"]
    for p in files:
        d = json.loads(p.read_text())
        changed = ", ".join(f"{k}={v}" for k, v in sorted(d.get("changed", {}).items()))
        changed = changed or "none"
        if d.get("push_reward") not in (None, "centre"):
            changed += f"; push reward {d['push_reward']}"
        rates = " / ".join(_pct(d["by_action"].get(a)) for a in ACTIONS)
        rows.append(f"| `{p.name}` | {d['key']} | {d['phase1']} + {d['phase2']} | "
                    f"{d['agents']} | {changed} | {rates} |")
    return rows


def _tl_xy_rows(files: list[pathlib.Path]) -> list[str]:
    rows = ["| file | key | learning rate → final | held-out error median / 95th pct (cm) |",
            "|---|---|---|---|"]
    for p in files:
        d = json.loads(p.read_text())
        for pt in d["points"]:
            rows.append(f"| `{p.name}` | {d['key']} | {pt['lr']} → {pt['lr_final']} | "
                        f"{pt['median_cm']:.2f} / {pt['p95_cm']:.2f} |")
    return rows


def _substeps_rows(files: list[pathlib.Path]) -> list[str]:
    rows = ["| file | key | substeps | agents × episodes | median agent from home: point / "
            "touch / push |", "|---|---|---|---|---|"]
    for p in files:
        d = json.loads(p.read_text())
        for r in d["rows"]:
            home = r["trained"]["home"]["by_action"]
            rows.append(f"| `{p.name}` | {d['key']} | {r['substeps']} | {d['seeds']} × "
                        f"{d['episodes']} | "
                        + " / ".join(_pct(home.get(a)) for a in ACTIONS) + " |")
    return rows


def _al_variant_rows(files: list[pathlib.Path]) -> list[str]:
    rows = ["| file | key | variant | changed from the shipped settings | agents × episodes | "
            "median agent: point / touch / push, by start noise |", "|---|---|---|---|---|---|"]
    for p in files:
        d = json.loads(p.read_text())
        for name, v in d["variants"].items():
            changed = [f"{k}={x}" for k, x in v["fields"].items()]
            static = [f"task_set={v['task_set']}"] if v["task_set"] != "paper" else []
            if v.get("heads"):
                static.append("heads=" + "-".join(map(str, v["heads"])))
            changed = ", ".join(static + changed) or "none"
            rates = "; ".join(f"±{n}: " + " / ".join(_pct(lv["by_action"][a]) for a in ACTIONS)
                              for n, lv in v["levels"].items())
            rows.append(f"| `{p.name}` | {d['key']} | {name} | {changed} | {d['agents']} × "
                        f"{d['phase1'] + d['phase2']} | {rates} |")
    return rows


def _frames_rows(files: list[pathlib.Path]) -> list[str]:
    rows = ["| file | key | own episodes | namer | others named right: action and target "
            "(action / target), each draw of the fit |", "|---|---|---|---|---|"]
    for p in files:
        d = json.loads(p.read_text())
        groups: dict[tuple[str, str], list[dict]] = {}
        for r in d["rows"]:
            groups.setdefault((r["episodes"], r["namer"]), []).append(r["others"])
        for (episodes, namer), got in groups.items():
            cells = ", ".join(f"{_pct(g['both'])} ({_pct(g['action'])} / {_pct(g['target'])})"
                              for g in got)
            rows.append(f"| `{p.name}` | {d['key']} | {episodes} | {namer} | {cells} |")
    return rows


def _stage_frames_rows(files: list[pathlib.Path]) -> list[str]:
    rows = ["| file | how | camera | family | others named right from frames: action and "
            "target (action / target) | joint angles, same episodes |", "|---|---|---|---|---|---|"]
    for p in files:
        d = json.loads(p.read_text())
        for f, r in d["result"]["families"].items():
            rows.append(f"| `{p.name}` | `{d['how'].split(' (')[0]}` | {d['config']['camera']} | "
                        f"{f} | {_pct(r['frames_both'])} ({_pct(r['frames_action'])} / "
                        f"{_pct(r['frames_target'])}) | {_pct(r['joints_both'])} |")
    return rows


def _stage_touch_rows(files: list[pathlib.Path]) -> list[str]:
    rows = ["| file | episodes | variant | start | median agent: point / touch / push |",
            "|---|---|---|---|---|"]
    for p in files:
        d = json.loads(p.read_text())
        for name, row in d["result"]["variants"].items():
            if name == "paper":  # the run's own agents: trained on the run's schedule
                continue
            for noise, lv in row["levels"].items():
                trio = " / ".join(_pct(lv["by_action"][a]) for a in ACTIONS)
                episodes = row.get("episodes", d["result"]["episodes"])
                rows.append(f"| `{p.name}` | {episodes} | {row['what']} | "
                            f"{'home' if float(noise) == 0 else '±' + noise} | {trio} |")
    return rows


def index() -> str:
    """The index, as Markdown."""
    free = sorted(TUNING.glob("free_tuning_*.json"))
    tl_xy = sorted(TUNING.glob("tl_xy_tuning_k*.json"))
    substeps = sorted(TUNING.glob("substeps_*.json"))
    variants = sorted(TUNING.glob("al_variants_*.json"))
    frames = sorted(TUNING.glob("frames_levers*.json"))
    together = sorted(TUNING.glob("together_seeds*.json"))
    tl_curves = sorted(TUNING.glob("together_tl_curves.json"))
    stage_frames = sorted(TUNING.glob("watch_frames_*.json"))
    known = set(free) | set(tl_xy) | set(substeps) | set(variants) | set(frames)
    stage_touch = sorted(TUNING.glob("touch_memory_*.json"))
    known |= set(stage_frames) | set(stage_touch)
    known |= set(together) | set(tl_curves)
    other = sorted(p.name for p in TUNING.glob("*.json") if p not in known)
    lines = [
        "# Tuning outputs",
        "",
        "One-off tuning runs, kept because the tables of the documentation cite them. "
        "Generated by `python benchmarks/tuning_index.py` from the files in "
        "`results/tuning/`; the benchmark outputs users look for stay in "
        "`results/benchmarks/`. The keys are never train.py's (0): a choice made on them is "
        "checked on train.py's own runs.",
        "",
        f"## The free family's action learner ({len(free)} runs)",
        "",
        "Written by `benchmarks/free_tuning.py`; they fed the tuning tables of *Beyond the "
        "paper* (`docs/beyond.md`). Success by the success criteria, on held-out "
        "placements drawn from the file's evaluation key.",
        "",
        *_free_rows(free),
        "",
        f"## The continuous TL's learning rate ({len(tl_xy)} runs)",
        "",
        "Written by `benchmarks/tl_xy_tuning.py`; they chose the continuous TL's learning "
        "rate in *Beyond the paper* (`docs/beyond.md`).",
        "",
        *_tl_xy_rows(tl_xy),
        "",
        f"## Physics substeps, trained agents ({len(substeps)} runs)",
        "",
        "Written by `benchmarks/substeps.py --episodes 1200 --key K`; they fed the substeps "
        "table of *Benchmarks* (`docs/benchmarks.md`).",
        "",
        *_substeps_rows(substeps),
        "",
        f"## Variants of the paper family's action learner ({len(variants)} runs)",
        "",
        "Written by `benchmarks/al_variants.py`; they fed *Touch with memory* and *Every "
        "action from random starts* (`docs/beyond.md`). Every action on all 36 layouts, "
        "judged from the file's evaluation key at each start noise (0: home).",
        "",
        *_al_variant_rows(variants),
    ]
    if stage_touch:
        lines += ["", "The `touch_memory` stage run on train.py's own seed with other settings "
                  "(each file's `how`; the committed `results/paper` run is the shipped "
                  "profile's):", "", *_stage_touch_rows(stage_touch)]
    if frames:
        lines += ["", f"## Naming from frames ({len(frames)} runs)", "",
                  "Written by `benchmarks/frames_levers.py`; they fed *Naming from the camera* "
                  "(`docs/beyond.md`). The namer is fitted on the saved robot's own episodes and "
                  "judged on the run's other agents' episodes, rendered at "
                  "`grounding_jax.frames`' defaults.", "", *_frames_rows(frames)]
    if stage_frames:
        lines += ["", "The `watch_frames` stage run on train.py's own seed with another camera "
                  "(the committed `results/paper` run is the shipped one's):", "",
                  *_stage_frames_rows(stage_frames)]
    if together:
        import together_seeds

        lines += ["", f"## The modules learning together, more keys ({len(together)} runs)", "",
                  "Written by `benchmarks/together_seeds.py`; they fed *The modules learning "
                  "together* (`docs/beyond.md`): the `together` stage's paper profile again "
                  "with other keys, every key's agents pooled.", ""]
        for p in together:
            lines += [f"`{p.name}`:", "", together_seeds.table(json.loads(p.read_text())), ""]
        for p in tl_curves:  # how fast each of the stage's TL settings finds its answers
            lines += [f"`{p.name}`:", "",
                      together_seeds.curves_table(json.loads(p.read_text())), ""]
        lines.pop()
    if other:
        lines += ["", "## Other files", "", *(f"- `{n}`" for n in other)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python benchmarks/tuning_index.py")
    ap.add_argument("--check", action="store_true",
                    help="do not write; exit 1 if the committed index differs")
    args = ap.parse_args(argv)
    text = index()
    targets = (TUNING / "README.md", ROOT / "docs" / "tuning.md")
    if args.check:
        stale = [str(t) for t in targets if not t.is_file() or t.read_text() != text]
        if stale:
            print(f"stale: {stale}; run python benchmarks/tuning_index.py", file=sys.stderr)
            return 1
        return 0
    for t in targets:
        t.write_text(text)
        print(f"wrote {t}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
