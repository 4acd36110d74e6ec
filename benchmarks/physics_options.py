"""MuJoCo solver and contact options of the scene: faster physics, and still the same pushes?

Each variant is the shipped scene model with one option changed. In one process, on both
cores (``mujoco.rollout``), for each variant:

- speed: RL steps (10 substeps) per second on a full batch of 256 transitions sampled from
  the scripted pushes, the variants timed ``--repeats`` times in a shuffled order each round
  (median; the ratio is against the shipped model in the same rounds);
- one step: the largest change of any qpos entry after one RL step, over every transition of
  the scripted pushes (the shipped model's result as the reference);
- whole pushes: the scripted push of each position on ``--layouts``, replayed open loop (the
  same joint targets at every step) under the variant; how far each object's end position
  lies from the shipped model's (cm: the largest, and the median over episodes).

Usage:  python benchmarks/physics_options.py [--repeats 9] [--layouts 0 3 7]
Writes results/benchmarks/physics_options.json and prints its Markdown table (`table`).
"""

from __future__ import annotations

import argparse
import copy
import json
import pathlib
import sys
import time

import jax
import mujoco
import numpy as np
from mujoco import rollout

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
import grounding_jax as gj  # noqa: E402
from grounding_jax.sim import rollout as episodes  # noqa: E402
from grounding_jax.sim import scene, scripted  # noqa: E402

SUBSTEPS = 10


def _set(**fields):
    def edit(m: mujoco.MjModel) -> None:
        for k, v in fields.items():
            setattr(m.opt, k, v)
    return edit


def _condim3(m: mujoco.MjModel) -> None:
    m.geom_condim[m.geom_condim > 3] = 3


def _no_islands(m: mujoco.MjModel) -> None:
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ISLAND)


#: variant name -> what it changes in the shipped model
VARIANTS = {
    "shipped": lambda m: None,
    "condim 3 (no torsional / rolling friction)": _condim3,
    "elliptic friction cones": _set(cone=mujoco.mjtCone.mjCONE_ELLIPTIC),
    "solver tolerance 1e-6 (shipped 1e-8)": _set(tolerance=1e-6),
    "solver tolerance 1e-5": _set(tolerance=1e-5),
    "solver iterations 5 (shipped 10)": _set(iterations=5, ls_iterations=5),
    "line-search iterations 3 (shipped 10)": _set(ls_iterations=3),
    "line-search iterations 5": _set(ls_iterations=5),
    "constraint islands off": _no_islands,
}


def _model(name: str) -> mujoco.MjModel:
    m = copy.deepcopy(scene.model())  # the cached model is shared: never edit it
    VARIANTS[name](m)
    return m


def scripted_pushes(layouts: tuple[int, ...]):
    """The scripted pushes' transitions (state0 rows, ctrl rows) and episodes (state0, ctrls)."""
    env = gj.make_env("mujoco")
    states, ctrls, eps = [], [], []
    for layout in layouts:
        for p in range(3):
            w = np.asarray(scripted.push_waypoints(p))
            first, traj = jax.device_get(episodes.run_episode(
                env, jax.random.key(0), gj.make_task("push", p, layout),
                lambda s, w=w: scripted.tracking_action(w, s.step, s.obs), gj.EnvParams()))
            qp = np.concatenate([first.qpos[None], traj.qpos])
            qv = np.concatenate([first.qvel[None], traj.qvel])
            rows = np.concatenate([np.zeros((len(qp), 1)), qp, qv], axis=1).astype(np.float64)
            u = np.asarray(traj.info["ctrl"], np.float64)
            states.append(rows[:-1])
            ctrls.append(u)
            eps.append((rows[0], u))
    return np.concatenate(states), np.concatenate(ctrls), eps


class _Runner:
    def __init__(self) -> None:
        self.pool = rollout.Rollout(nthread=2)

    def run(self, m: mujoco.MjModel, state0: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
        """The states after ``ctrl.shape[1]`` steps (ctrl ``[batch, steps, nu]``)."""
        datas = [mujoco.MjData(m) for _ in range(2)]
        states, _ = self.pool.rollout(m, datas, state0, ctrl, nstep=ctrl.shape[1],
                                      initial_warmstart=np.zeros((len(state0), m.nv)))
        return states[:, -1]


def faithfulness(runner: _Runner, models: dict, states, ctrls, eps) -> dict:
    """One-step and whole-push differences from the shipped model (see the module doc)."""
    nq = scene.model().nq
    idx = scene.index()
    pos = 1 + np.concatenate([q[:3] for q in idx.object_qpos])
    one_ctrl = np.repeat(ctrls[:, None], SUBSTEPS, axis=1)

    def ends(m):
        return np.stack([runner.run(m, s0[None], np.repeat(u, SUBSTEPS, 0)[None])[0]
                         for s0, u in eps])

    ref_one, ref_end = runner.run(models["shipped"], states, one_ctrl), ends(models["shipped"])
    out = {}
    for name, m in models.items():
        one = runner.run(m, states, one_ctrl)
        end = ends(m)
        per_episode = np.abs(end[:, pos] - ref_end[:, pos]).max(axis=1) * 100
        out[name] = {"one_step_max_dq": float(np.abs(one[:, 1:1 + nq]
                                                      - ref_one[:, 1:1 + nq]).max()),
                     "push_end_max_cm": float(per_episode.max()),
                     "push_end_median_cm": float(np.median(per_episode))}
    return out


def speed(runner: _Runner, models: dict, states, ctrls, repeats: int, batch: int = 256
          ) -> dict:
    """RL steps/s per variant (median over shuffled rounds) and its ratio to the shipped."""
    take = np.random.default_rng(0).integers(0, len(states), batch)
    s0, u = states[take], np.repeat(ctrls[take][:, None], SUBSTEPS, axis=1)
    times = {n: [] for n in models}
    order = np.random.default_rng(1)
    for name in models:  # warm-up
        runner.run(models[name], s0, u)
    for _ in range(repeats):
        for name in order.permutation(list(models)):
            t = time.perf_counter()
            for _ in range(4):
                runner.run(models[name], s0, u)
            times[name].append((time.perf_counter() - t) / 4)
    base = float(np.median(times["shipped"]))
    return {n: {"rl_steps_per_s": batch / float(np.median(t)),
                "speedup": base / float(np.median(t))} for n, t in times.items()}


def table(result: dict) -> str:
    """The Markdown table of a run (``results/benchmarks/physics_options.json``)."""
    lines = ["| variant | RL steps/s (256 scenes) | × shipped | one RL step: largest qpos "
             "change | scripted pushes, open loop: objects' end positions, largest / median "
             "change (cm) |", "|---|---|---|---|---|"]
    for name, r in result["variants"].items():
        lines.append(f"| {name} | {r['rl_steps_per_s']:,.0f} | {r['speedup']:.2f} | "
                     f"{r['one_step_max_dq']:.1e} | {r['push_end_max_cm']:.3g} / "
                     f"{r['push_end_median_cm']:.3g} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--layouts", type=int, nargs="+", default=[0, 3, 7])
    ap.add_argument("--out", default=str(HERE.parent / "results/benchmarks/"
                                                        "physics_options.json"))
    args = ap.parse_args(argv)
    states, ctrls, eps = scripted_pushes(tuple(args.layouts))
    models = {name: _model(name) for name in VARIANTS}
    runner = _Runner()
    faith = faithfulness(runner, models, states, ctrls, eps)
    fast = speed(runner, models, states, ctrls, args.repeats)
    result = {"substeps": SUBSTEPS, "transitions": len(states), "layouts": args.layouts,
              "repeats": args.repeats, "mujoco": mujoco.__version__,
              "variants": {n: {**fast[n], **faith[n]} for n in VARIANTS}}
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(table(result), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
