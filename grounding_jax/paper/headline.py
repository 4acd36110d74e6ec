"""The headline table (the paper beside us), generated from the result files.

``python -m grounding_jax.paper.headline`` rewrites the table between the ``headline``
markers of ``README.md`` and ``docs/index.md`` from ``results/paper/metrics.json`` and
``results/benchmarks/free_perform_check.json``; ``--check`` fails when they are stale, so the
text cannot drift from the results.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
import sys

from grounding_jax.paper.report import AL_GOALS, PAPER

ROOT = pathlib.Path(__file__).resolve().parents[2]
START, END = "<!-- headline: start -->", "<!-- headline: end -->"
PAGES = ("README.md", "docs/index.md")
ACTIONS = ("point", "touch", "push")


def _pct(v: float, digits: int = 0) -> str:
    return f"{100 * v:.{digits}f}%"


def _trio(rates: dict) -> str:
    return " / ".join(_pct(rates[a]) for a in ACTIONS)


def _touch_memory_row(res: dict) -> str:
    """The headline row of the ``touch_memory`` stage: each variant from home."""
    tm = res["variants"]
    first = {v: next(iter(tm[v]["levels"].values()))["by_action"] for v in tm}
    # a variant trained longer than the run's schedule says so
    longer = {v: f" ({tm[v]['episodes']} episodes)" for v in tm
              if tm[v].get("episodes", res["episodes"]) != res["episodes"]}
    cells = "; ".join(f"{tm[v]['what']}{longer.get(v, '')} {_trio(first[v])}"
                      for v in tm if v != "paper")
    return (f"| Beyond: touch with memory, and touch reaching a touching pose (not the "
            f"paper's reward), from home | proposed | {cells} |")


def table(metrics: dict, perform_check: dict | None = None) -> str:
    """The headline rows as Markdown.

    Args:
        metrics: a paper-profile run's ``metrics.json``.
        perform_check: ``benchmarks/free_perform_check.py``'s output (episodes through
            ``perform`` on a key nobody tuned on), or None.
    """
    tl, al, an, free = (metrics["tl"]["accuracy"], metrics["al"], metrics["an"],
                        metrics["beyond"]["free"])
    xy = metrics["beyond"]["tl_xy"]
    at = {int(k): v for k, v in al["success"].items()}
    paper_eps = min(at, key=lambda e: abs(e - 450))
    home, last = at[paper_eps]["home"]["by_action"], al["final"]["home"]["by_action"]
    goals = " / ".join(f"{AL_GOALS[a]:.0%}" for a in ACTIONS)
    lowest = min(tl["test_acc_per_seed"])
    rows = [
        f"| | the paper | ours (`results/paper`, {metrics['profile']} profile, seed "
        f"{metrics['seed']}) |",
        "|---|---|---|",
        f"| TL: finds the named object (test accuracy, {tl['seeds']} splits) | "
        f"{PAPER['tl_test_acc']} | {_pct(tl['test_acc_mean'], 1)} ± "
        f"{100 * tl['test_acc_std']:.1f} (lowest split {_pct(lowest, 1)}) |",
        f"| AL: point / touch / push from home, median of {al['seeds']} agents, after "
        f"{paper_eps} episodes (the paper's schedule) | {PAPER['point']} / {PAPER['touch']} / "
        f"{PAPER['push']} | {_trio(home)} |",
        f"| AL: the same after {max(at)} episodes (the shipped schedule; goals {goals}) | – | "
        f"{_trio(last)} |",
        f"| AL: point from random starts | {PAPER['random_start_point']} | "
        f"{_pct(al['final']['random_starts']['by_action']['point'])} |",
        f"| AN: names action and target (test, random starts; {an['seeds']} seeds) | "
        f"{PAPER['an_accuracy']} | {_pct(an['test_random']['acc_mean'])} |",
        f"| Beyond: continuous TL, error of the target's (x, y), median / 95th percentile | – "
        f"| {xy['median_cm_median_seed']:.2f} / {xy['p95_cm_median_seed']:.2f} cm |",
        f"| Beyond: objects anywhere, median of {free['seeds']} agents on held-out "
        f"placements, point / touch / push | – | {_trio(free['final']['by_action'])} |",
    ]
    obs = metrics.get("observer")
    if obs and obs.get("other_agent") is not None:
        n = sum(len(obs[f]["agents"]) for f in ("paper", "free") if f in obs)
        rows.append(
            f"| Beyond: names what it only watches (another agent's episodes, motor "
            f"resonance from the joints), median of {n} other agents | proposed | "
            f"{_pct(obs['other_agent'])} |")
    stages = metrics.get("stages") or {}
    if "random_starts" in stages and "0.3" in stages["random_starts"]["result"]["levels"]:
        lv = stages["random_starts"]["result"]["levels"]["0.3"]["by_action"]
        rows.append(f"| Beyond: every action from random starts within ±0.3 (goals 90% / 85% / "
                    f"90%), point / touch / push | – | {_trio(lv)} |")
    if "touch_memory" in stages:
        rows.append(_touch_memory_row(stages["touch_memory"]["result"]))
    if "watch_frames" in stages:
        wf = {f: r for f, r in stages["watch_frames"]["result"]["families"].items()
              if r.get("episodes")}
        cells = "; ".join(f"{f} family {_pct(r['frames_both'])} (joint angles "
                          f"{_pct(r['joints_both'])})" for f, r in wf.items())
        rows.append(f"| Beyond: names other agents' acts from rendered frames only (goal 90%), "
                    f"action and target right | proposed | {cells} |")
    if "together" in stages:
        arms = stages["together"]["result"]["arms"]
        cells = "; ".join(f"{arm} {_trio({a: arms[arm]['summary'][a]['median'] for a in ACTIONS})}"
                          f", named {_pct(arms[arm]['summary']['named']['median'])}"
                          for arm in ("sequence", "together"))
        rows.append(f"| Beyond: the modules trained together vs one after another, same seeds "
                    f"and budget, point / touch / push | future work | {cells} |")
    if perform_check is not None:
        p = perform_check
        rows.append(
            f"| Beyond, through `perform` on a key nobody tuned on ({p['episodes']} episodes, "
            f"key {p['key']}), point / touch / push | – | median agent "
            f"{_trio(p['median_agent_success'])}; the saved agent "
            + " / ".join(_pct(p[f'success_{a}']) for a in ACTIONS)
            + f", named right {_pct(p['named_right'])} |")
    return "\n".join(rows) + "\n"


def _read(root: pathlib.Path) -> str:
    metrics = json.loads((root / "results" / "paper" / "metrics.json").read_text())
    check = root / "results" / "benchmarks" / "free_perform_check.json"
    return table(metrics, json.loads(check.read_text()) if check.is_file() else None)


def replace(text: str, rows: str, source: str = "<text>") -> str:
    """``text`` with the table between the markers replaced by ``rows``."""
    pattern = re.compile(re.escape(START) + r"\n.*?" + re.escape(END), re.S)
    if not pattern.search(text):
        raise ValueError(f"{source}: no {START} ... {END} block")
    return pattern.sub(lambda _: f"{START}\n{rows}{END}", text)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m grounding_jax.paper.headline")
    ap.add_argument("--check", action="store_true", help="exit 1 if a page is stale")
    ap.add_argument("--root", default=str(ROOT), help="the checkout")
    args = ap.parse_args(argv)
    root = pathlib.Path(args.root)
    rows = _read(root)
    stale = []
    for page in PAGES:
        path = root / page
        text = path.read_text()
        new = replace(text, rows, page)
        if new != text:
            stale.append(page)
            if not args.check:
                path.write_text(new)
    if args.check and stale:
        print(f"stale headline table in {stale}: run python -m grounding_jax.paper.headline",
              file=sys.stderr)
        return 1
    print("up to date" if not stale else f"rewrote {', '.join(stale)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
