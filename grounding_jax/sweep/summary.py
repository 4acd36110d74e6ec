"""A sweep's results: per-point summaries, ``runs.csv`` and the figure."""

from __future__ import annotations

import csv
import io
import pathlib

import numpy as np

from grounding_jax.core.io import Staged, pyplot, write_figure
from grounding_jax.sweep.spec import METRICS, SweepSpec, adapter


def summaries(spec: SweepSpec, metrics: dict[str, np.ndarray], finite: np.ndarray) -> dict:
    """Per run value of the plotted metric, per point mean/std over the finite runs, and the
    learning curves (AL)."""
    n_pts = len(spec.points())
    found = adapter(spec.module)
    if spec.metric.startswith("success_"):  # [runs, evaluations]: the last one counts
        curve, window = metrics[spec.metric], None
        value = curve[:, -1]
    elif found.curves:
        curve = metrics[spec.metric]  # [runs, episodes of the longest run]
        lengths = np.repeat([found.length(p) for p in spec.points()], spec.seeds)
        if np.all(lengths == curve.shape[1]):
            window = max(1, curve.shape[1] // 10)
            value = curve[:, -window:].mean(1)
        else:  # static groups of other lengths (NaN-padded): each run's own last tenth
            window = None
            value = np.asarray([curve[r, n - max(1, n // 10): n].mean()
                                for r, n in enumerate(lengths)], curve.dtype)
    else:  # the final value after training
        curve, value, window = None, metrics[f"final_{spec.metric}"], None
    value = value.reshape(n_pts, spec.seeds)
    ok = finite.reshape(n_pts, spec.seeds)
    pts = []
    for i, p in enumerate(spec.points()):
        v = value[i][ok[i]]
        pts.append({"point": {k: p[k] for k in spec.grid},
                    "mean": float(v.mean()) if v.size else None,
                    "std": float(v.std()) if v.size else None,
                    "runs": [float(x) for x in value[i]],
                    "diverged": [int(s) for s in np.flatnonzero(~ok[i])]})
    ok_pts = [p for p in pts if p["mean"] is not None]
    sign = 1 if spec.metric in found.lower_is_better else -1
    out = {"metric": spec.metric, "window": window, "points": pts,
           "lower_is_better": sign == 1,
           "best": min(ok_pts, key=lambda p: sign * p["mean"])["point"] if ok_pts else None}
    if curve is not None:
        c = np.asarray(curve, np.float64).reshape(n_pts, spec.seeds, -1)
        out["curves"] = [np.where(ok[i][:, None], c[i], np.nan).tolist() for i in range(n_pts)]
    if spec.evaluations():
        out["evaluations"] = list(spec.evaluations())
        final = {k: np.asarray(metrics[f"success_{k}"])[:, -1].reshape(n_pts, spec.seeds)
                 for k in found.success}
        out["success"] = [{"point": p["point"], "rates": {
            k: {"median": float(np.median(v[i])), "min": float(v[i].min()),
                "max": float(v[i].max()), "runs": v[i].tolist()} for k, v in final.items()}}
            for i, p in enumerate(pts)]
    return out


def csv_text(spec: SweepSpec, summary: dict) -> str:
    """``runs.csv``: one row per run (grid values, seed, the metric, diverged, success rates)."""
    buf = io.StringIO()
    w = csv.writer(buf)
    names = [f"success_{k}" for k in adapter(spec.module).success] if "success" in summary \
        else []
    names = [k for k in names if k != spec.metric]
    w.writerow([*spec.grid, "seed", spec.metric, "diverged", *names])
    for i, p in enumerate(summary["points"]):
        for s, v in enumerate(p["runs"]):
            extra = [summary["success"][i]["rates"][k[len("success_"):]]["runs"][s]
                     for k in names]
            w.writerow([*p["point"].values(), s, v, int(s in p["diverged"]), *extra])
    return buf.getvalue()


def point_label(spec: SweepSpec, point: dict) -> str:
    """A point's name in figures and tables: its grid values, or for an ``axes`` design the
    one field that differs from the base point (``"base"`` for the base itself)."""
    if spec.design == "axes":
        centre = {k: v[0] for k, v in spec.grid.items()}
        changed = [f"{k}={v}" for k, v in point.items() if v != centre[k]]
        return ", ".join(changed) or "base"
    return ", ".join(f"{k}={v}" for k, v in point.items())



def write_sweep_figure(spec: SweepSpec, summary: dict, out: pathlib.Path, staged: Staged) -> None:
    """Stage the sweep's figure (``<figure>.png`` and its data as ``<figure>.json``)."""
    plt = pyplot()
    curves = "curves" in summary
    height = max(3.6, 0.3 * len(summary["points"])) if spec.design == "axes" else 3.6
    fig, axes = plt.subplots(1, 2 if curves else 1, figsize=(11 if curves else 5.5, height))
    axes = np.atleast_1d(axes)
    label = METRICS[spec.module][spec.metric]
    others = [k for k in spec.grid if k != spec.x]
    xs = [p["point"][spec.x] for p in summary["points"]]
    if curves:
        ax = axes[0]
        if len(summary["points"]) > 10:  # more lines than the default colour cycle
            ax.set_prop_cycle(color=plt.get_cmap("tab20").colors)
        for p, c, full in zip(summary["points"], summary["curves"], spec.points(),
                              strict=True):
            c = np.asarray(c, float)
            name = point_label(spec, p["point"])
            if not np.isfinite(c).any():
                continue
            if spec.metric.startswith("success_"):  # measured at the evaluation episodes
                ax.plot(summary["evaluations"], np.nanmedian(c, 0), marker="o", label=name)
                continue
            mean = np.nanmean(c[:, : adapter(spec.module).length(full)], 0)  # unpadded
            k = max(1, mean.size // 25)  # bins of k episodes
            bins = mean[: mean.size // k * k].reshape(-1, k).mean(1)
            ax.plot(np.arange(bins.size) * k + k / 2, bins, label=name)
        stat = "median" if spec.metric.startswith("success_") else "mean"
        ax.set(xlabel="episode", ylabel=spec.metric,
               title=f"learning curves, {stat} over seeds\n({label})")
        ax.legend(fontsize=7)
    ax = axes[-1]
    window = (f"mean of the last {summary['window']} episodes" if summary.get("window")
              else "mean of each run's last tenth" if curves and not
              spec.metric.startswith("success_") else "after training")
    if spec.design == "axes":  # one row per point, the base on top
        ps = summary["points"]
        ys = np.arange(len(ps))[::-1]
        ax.errorbar([np.nan if p["mean"] is None else p["mean"] for p in ps], ys,
                    xerr=[0 if p["std"] is None else p["std"] for p in ps], fmt="o",
                    capsize=3)
        ax.set_yticks(ys, [point_label(spec, p["point"]) for p in ps], fontsize=7)
        ax.set(xlabel=spec.metric, title=f"{label}, {window}\n(mean ± std over "
                                         f"{spec.seeds} seeds; one field changed at a time)")
        others = []
    groups: dict[tuple, list[dict]] = {}
    for p in summary["points"] if spec.design != "axes" else []:
        groups.setdefault(tuple(p["point"][k] for k in others), []).append(p)
    for key, ps in groups.items():
        ps = [p for p in ps if p["mean"] is not None]
        ax.errorbar([p["point"][spec.x] for p in ps], [p["mean"] for p in ps],
                    yerr=[p["std"] for p in ps], marker="o", capsize=3,
                    label=", ".join(f"{k}={v}" for k, v in zip(others, key, strict=True))
                    or None)
    positive = all(isinstance(v, (int, float)) and v > 0 for v in xs)
    if spec.design != "axes":
        if positive and max(xs) / min(xs) >= 100:
            ax.set_xscale("log")
        ax.set(xlabel=spec.x, ylabel=spec.metric,
               title=f"{label}, {window}\n(mean ± std over {spec.seeds} seeds)")
    if others:
        ax.legend(fontsize=7)
    found = adapter(spec.module)
    lengths = sorted({found.length(p) for p in spec.points()})
    fig.suptitle(f"{spec.title} ({'/'.join(map(str, lengths))} {found.unit})")
    fig.tight_layout()
    write_figure(out, spec.figure, {k: v for k, v in summary.items() if k != "curves"}, fig,
                 staged)


def search_csv(spec: SweepSpec, summary: dict) -> str:
    """``runs.csv`` of a search: one row per trial (its searched fields, the units and RL
    steps it spent, its status and why, its final value, then its value at every evaluation
    as ``<metric>@<units>``)."""
    buf = io.StringIO()
    w = csv.writer(buf)
    trials = summary["trials"]
    at = sorted({e for t in trials for e, _ in t["evaluations"]})
    unit = adapter(spec.module).unit
    w.writerow(["trial", *spec.space, unit, "rl_steps", "status", "reason", spec.metric,
                "diverged", *(f"{spec.metric}@{e}" for e in at)])
    for t in trials:
        seen = dict((e, v) for e, v in t["evaluations"])
        value = t["evaluations"][-1][1] if t["evaluations"] and not t["diverged"] else None
        w.writerow([t["index"], *(t["params"][k] for k in spec.space), t["units"],
                    t["rl_steps"], t["status"], t["reason"], "" if value is None else value,
                    int(t["diverged"]), *("" if seen.get(e) is None else seen[e] for e in at)])
    return buf.getvalue()


def write_search_figure(spec: SweepSpec, summary: dict, out: pathlib.Path,
                        staged: Staged) -> None:
    """Stage a search's figure: the metric against the RL steps each trial had spent at each
    evaluation (the best trial marked; a trial stopped early is a short line, or a dot), the
    searched fields as parallel coordinates coloured by each trial's last value (where it
    stopped), and for PBT the best lineage's schedule."""
    from grounding_jax.sweep.space import normalised

    plt = pyplot()
    trials = summary["trials"]
    best = summary.get("best")
    pbt = spec.search == "pbt" and best is not None
    fig, axes = plt.subplots(1, 3 if pbt else 2, figsize=(16.5 if pbt else 11, 4))
    ax = axes[0]
    for t in trials:
        if not t["evaluations"] or not t["units"]:
            continue
        units = np.asarray([e for e, _ in t["evaluations"]], float)
        steps = units / t["units"] * t["rl_steps"]  # at a steady rate
        vals = [np.nan if v is None else v for _, v in t["evaluations"]]
        mine = best is not None and t["index"] == best["index"]
        ax.plot(steps, vals, "-o", ms=4 if mine else 2.5, lw=2.2 if mine else 0.8,
                color="crimson" if mine else "0.55", alpha=1 if mine else 0.6, zorder=3 if mine
                else 1, label=f"best: trial {t['index']}" if mine else None)
    ax.set(xlabel="RL steps spent by the trial", ylabel=spec.metric,
           title=f"{spec.search}: every trial's {spec.metric}")
    if best is not None:
        ax.legend(fontsize=8)
    ax = axes[1]
    names = list(spec.space)
    finals = [t["evaluations"][-1][1] if t["evaluations"] and not t["diverged"] else None
              for t in trials]
    ok = [v for v in finals if v is not None]
    cmap = plt.get_cmap("viridis" if spec.metric not in adapter(spec.module).lower_is_better
                        else "viridis_r")
    lo, hi = (min(ok), max(ok)) if ok else (0.0, 1.0)
    for t, v in sorted(zip(trials, finals, strict=True),
                       key=lambda tv: -np.inf if tv[1] is None else tv[1]):
        if v is None or not t["units"]:
            continue
        ys = [normalised(spec.space[n], t["params"][n]) for n in names]
        ax.plot(range(len(names)), ys, color=cmap((v - lo) / (hi - lo or 1)), alpha=0.8)
    ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
    ax.set(ylabel="place in its range (0 = low, 1 = high)",
           title=f"searched fields, coloured by {spec.metric}")
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(lo, hi))
    fig.colorbar(sm, ax=ax, label=spec.metric)
    if pbt:
        ax = axes[2]
        sched = best["schedule"]
        length = adapter(spec.module).length(spec.base())
        for n in names:
            xs = [u for u, _ in sched] + [length]
            ys = [normalised(spec.space[n], p[n]) for _, p in sched]
            ax.step(xs, ys + ys[-1:], where="post", label=n)
        ax.set(xlabel=adapter(spec.module).unit, ylabel="place in its range",
               title="the best lineage's schedule")
        ax.legend(fontsize=7)
    fig.suptitle(f"{spec.title} ({spec.search}, {len(trials)} trials)")
    fig.tight_layout()
    write_figure(out, spec.figure, {k: v for k, v in summary.items()}, fig, staged)
