"""Sequential reference of the action learner: one agent at a time, NumPy networks, C MuJoCo
``mj_step`` in a Python loop -- the way the paper's era would run it.

It is the same algorithm as ``grounding_jax.learn.al`` (same env semantics, networks, CACLA rules,
schedule), written independently of JAX, and serves two purposes:

- a correctness cross-check: its learning curves over a few seeds must fall within the spread of
  the JAX trainer's (``python benchmarks/reference_cacla.py`` draws the plot);
- the speed baseline of ``benchmarks/al_throughput.py``.

Random numbers come from NumPy, so curves agree in distribution, not step by step.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import time

import mujoco
import numpy as np

import grounding_jax as gj
from grounding_jax.sim import scene

ROOT = pathlib.Path(__file__).resolve().parent.parent


# ------------------------------------------------------------------------------- networks
@dataclasses.dataclass
class Net:
    """Two-layer tanh network; ``out_tanh`` selects a tanh (actor) or linear (critic) output."""

    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: np.ndarray
    out_tanh: bool

    @classmethod
    def init(cls, rng: np.random.Generator, n_in: int, n_hidden: int, n_out: int,
             out_tanh: bool) -> Net:
        return cls(rng.uniform(-1, 1, (n_in, n_hidden)) / np.sqrt(n_in), np.zeros(n_hidden),
                   rng.uniform(-1, 1, (n_hidden, n_out)) / np.sqrt(n_hidden), np.zeros(n_out),
                   out_tanh)

    def forward(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = np.tanh(x @ self.w1 + self.b1)
        y = h @ self.w2 + self.b2
        return h, (np.tanh(y) if self.out_tanh else y)

    def step_along(self, x: np.ndarray, out_weight: np.ndarray, lr: float) -> None:
        """``theta += lr * d(out . out_weight)/d theta`` (hand-written backprop)."""
        h, y = self.forward(x)
        dz2 = out_weight * (1.0 - y * y) if self.out_tanh else out_weight
        dz1 = (self.w2 @ dz2) * (1.0 - h * h)
        self.w2 += lr * np.outer(h, dz2)
        self.b2 += lr * dz2
        self.w1 += lr * np.outer(x, dz1)
        self.b1 += lr * dz1


# ------------------------------------------------------------------------------------- env
class SequentialEnv:
    """The point/touch/push env of ``grounding_jax.sim.env`` on one ``MjData``, stepped with
    ``mj_step`` in a Python loop (float64 throughout)."""

    def __init__(self, substeps: int = 10, episode_length: int = 75) -> None:
        self.m = scene.model()
        self.d = mujoco.MjData(self.m)
        self.idx = scene.index()
        self.substeps, self.length = substeps, episode_length
        self.lim = np.radians(scene.PAPER_LIMITS_DEG)
        self.home = scene.home_qpos()
        self.pointing = self.scale(scene.pointing_configs())
        self.slots = scene.layout_shape_slots()
        self.object_pos = scene.object_positions()
        self.range = self.idx.joint_range
        self.physics_s = 0.0

    def scale(self, q: np.ndarray) -> np.ndarray:
        lo, hi = self.lim[..., 0], self.lim[..., 1]
        return 2.0 * (q - lo) / (hi - lo) - 1.0

    def unscale(self, j: np.ndarray) -> np.ndarray:
        lo, hi = self.lim[..., 0], self.lim[..., 1]
        return lo + (j + 1.0) * 0.5 * (hi - lo)

    def _objects(self) -> np.ndarray:
        return self.d.qpos[self.idx.object_qpos[:, :3]].copy()

    def _evaluate(self) -> tuple[np.ndarray, float, dict]:
        d, idx = self.d, self.idx
        joints = self.scale(d.qpos[idx.arm_qpos])
        contacts = np.any(d.sensordata[idx.sensor_contact] > 0, axis=1)
        obs = np.concatenate([joints, [float(contacts.any())], np.eye(3)[self.action],
                              np.eye(3)[self.position]])
        target_shape = int(np.argsort(self.slots[self.layout])[self.position])
        point = -np.abs(joints - self.pointing[self.position]).sum()
        dist = np.linalg.norm(d.sensordata[idx.sensor_palm_pos] - self.start[target_shape])
        is_target = np.arange(3) == target_shape
        touch = (-dist + (-0.5 if (contacts & ~is_target).any() else 0.0)
                 + (-0.3 if (contacts & is_target).any() else 0.0))
        reward = (point, touch, -dist)[self.action]
        moved = np.linalg.norm(self._objects() - self.start, axis=1)
        info = {"point_l1": -point, "touched_target": bool((contacts & is_target).any()),
                "target_moved": moved[target_shape],
                "wrong_moved": bool(((moved > 0.01) & ~is_target).any())}
        return obs, reward, info

    def reset(self, action: int, position: int, layout: int) -> tuple[np.ndarray, float]:
        self.action, self.position, self.layout = action, position, layout
        d = self.d
        mujoco.mj_resetData(self.m, d)
        d.qpos[:] = scene.place_objects(self.home.copy(), layout)
        d.ctrl[:] = d.qpos[self.idx.arm_qpos]
        mujoco.mj_forward(self.m, d)
        self.start = self._objects()
        self.t, self.wrong_since = 0, -1
        obs, reward, self.info = self._evaluate()
        return obs, reward

    def step(self, a: np.ndarray) -> tuple[np.ndarray, float, bool]:
        d = self.d
        q = self.scale(d.qpos[self.idx.arm_qpos])
        d.ctrl[:] = np.clip(self.unscale(q + a / 3.0), self.range[:, 0], self.range[:, 1])
        # the move the servo was really given (clipped at the joint limits), in action units
        self.executed = np.clip((self.scale(d.ctrl) - q) * 3.0, -1.0, 1.0)
        d.qacc_warmstart[:] = 0.0  # as the JAX backends: each RL step starts cold
        t0 = time.perf_counter()
        for _ in range(self.substeps):
            mujoco.mj_step(self.m, d)
        self.physics_s += time.perf_counter() - t0
        obs, reward, self.info = self._evaluate()
        self.t += 1
        if self.wrong_since < 0 and self.info["wrong_moved"]:
            self.wrong_since = self.t
        done = self.t >= self.length or (self.wrong_since >= 0 and self.t - self.wrong_since >= 3)
        return obs, reward, done


# ------------------------------------------------------------------------------- training
def train(seed: int, phase1_episodes: int = 150, phase2_episodes: int = 300,
          actor_lr: float = 0.001, critic_lr: float = 0.01, sigma: float = 0.1,
          gamma: float = 0.0, substeps: int = 10, actor_lr_decay: float = 1.0,
          critic_lr_decay: float = 1.0, sigma_decay: float = 1.0,
          executed_target: float = 0.0) -> tuple[dict[str, np.ndarray], dict]:
    """Train one agent. Returns (per-episode metrics, timing: total/physics seconds, steps).

    The decays and ``executed_target`` mean what they mean in
    ``grounding_jax.learn.cacla.CaclaHyper``: a rate is ``v * decay ** (episode / (episodes -
    1))``; with ``executed_target`` the actor is pulled toward the executed (limit-clipped)
    action instead of the explored one."""
    rng = np.random.default_rng(seed)
    env = SequentialEnv(substeps)
    actor = Net.init(rng, 11, 40, 4, out_tanh=True)
    critic = Net.init(rng, 11, 20, 1, out_tanh=False)
    episodes = phase1_episodes + phase2_episodes
    rec = {k: np.zeros(episodes) for k in ("return", "final_reward", "final_point_l1",
                                           "action", "position", "steps")}
    n_steps, t0 = 0, time.perf_counter()
    for ep in range(episodes):
        phase1 = ep < phase1_episodes
        x = ep / max(episodes - 1, 1)
        a_lr, c_lr = actor_lr * actor_lr_decay ** x, critic_lr * critic_lr_decay ** x
        sig = sigma * sigma_decay ** x
        action, position = int(rng.integers(3)), int(rng.integers(3))
        obs, r_prev = env.reset(action, position, int(rng.integers(len(scene.LAYOUTS))))
        ret, done = 0.0, False
        while not done:
            _, mean = actor.forward(obs)
            a = mean + sig * rng.standard_normal(4)
            nxt, r, done = env.step(a)
            v = critic.forward(obs)[1][0]
            v_next = 0.0 if done else critic.forward(nxt)[1][0]
            delta = r + gamma * v_next - v
            critic.step_along(obs, np.ones(1), c_lr * delta)
            if (r > r_prev) if phase1 else (delta > 0):
                target = env.executed if executed_target else a
                actor.step_along(obs, target - mean, a_lr)
            obs, r_prev, ret = nxt, r, ret + r
            n_steps += 1
        for k, val in (("return", ret), ("final_reward", r),
                       ("final_point_l1", env.info["point_l1"]), ("action", action),
                       ("position", position), ("steps", env.t)):
            rec[k][ep] = val
    timing = {"total_s": time.perf_counter() - t0, "physics_s": env.physics_s, "steps": n_steps}
    return rec, timing


def _curves(final_reward: np.ndarray, action: np.ndarray, block: int) -> np.ndarray:
    """Mean final reward per action per block of episodes: ``[agents, blocks, 3]``."""
    a, e = final_reward.shape
    nb = e // block
    fr = final_reward[:, : nb * block].reshape(a, nb, block)
    ac = action[:, : nb * block].reshape(a, nb, block)
    out = np.full((a, nb, 3), np.nan)
    for i in range(3):
        w = ac == i
        out[..., i] = np.where(w.any(-1), (fr * w).sum(-1) / np.maximum(w.sum(-1), 1), np.nan)
    return out


def main(argv: list[str] | None = None) -> None:
    """Cross-check: reference vs JAX trainer learning curves, same hyperparameters."""
    ap = argparse.ArgumentParser(description=main.__doc__)
    ap.add_argument("--seeds", type=int, default=3, help="reference agents (sequential)")
    ap.add_argument("--jax-seeds", type=int, default=8, help="JAX agents (vmapped)")
    ap.add_argument("--phase1", type=int, default=150)
    ap.add_argument("--phase2", type=int, default=300)
    ap.add_argument("--block", type=int, default=25, help="episodes per point of the curve")
    ap.add_argument("--out", default=str(ROOT / "results" / "benchmarks"))
    args = ap.parse_args(argv)
    gj.enable_compilation_cache()

    import jax
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from grounding_jax.core.io import atomic_write_text
    from grounding_jax.learn import al
    from grounding_jax.paper import al_experiments

    hp_ref = {**al_experiments.TUNED, **al_experiments.TUNED_AL}  # the shipped settings
    refs = [train(s, args.phase1, args.phase2, **hp_ref) for s in range(args.seeds)]
    ref_fr = np.stack([r["final_reward"] for r, _ in refs])
    ref_ac = np.stack([r["action"] for r, _ in refs])

    cfg = al.ALConfig(phase1_episodes=args.phase1, phase2_episodes=args.phase2)
    hp = al.hyper(**al_experiments.TUNED, **al_experiments.TUNED_AL)
    keys = jax.random.split(jax.random.key(0), args.jax_seeds)
    _, m = jax.jit(jax.vmap(al.make_train(cfg), in_axes=(0, None)))(keys, hp)
    jax_fr, jax_ac = np.asarray(m["final_reward"]), np.asarray(m["action"])

    cr, cj = _curves(ref_fr, ref_ac, args.block), _curves(jax_fr, jax_ac, args.block)
    x = (np.arange(cr.shape[1]) + 0.5) * args.block
    lo, hi = np.nanmin(cj, axis=0), np.nanmax(cj, axis=0)
    # share of (reference agent, block, action) points inside the JAX agents' min-max band
    inside = float(np.nanmean((cr >= lo - 1e-9) & (cr <= hi + 1e-9)))
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4), sharey=False)
    for i, ax in enumerate(axes):
        ax.fill_between(x, lo[:, i], hi[:, i], color="C0", alpha=0.25,
                        label=f"JAX trainer, {args.jax_seeds} agents (min-max)")
        ax.plot(x, np.nanmean(cj[..., i], 0), color="C0")
        for j in range(cr.shape[0]):
            ax.plot(x, cr[j, :, i], color="C3", lw=0.8, label="sequential reference" if j == 0
                    else None)
        ax.axvline(args.phase1, color="grey", ls=":", lw=0.8)
        ax.set_title(scene.ACTIONS[i])
        ax.set_xlabel("episode")
    axes[0].set_ylabel(f"final reward (mean per {args.block} episodes)")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"AL cross-check: {inside:.0%} of reference points inside the JAX band")
    fig.tight_layout()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "reference_crosscheck.png", dpi=110)
    result = {"hyperparameters": hp_ref, "phase1": args.phase1, "phase2": args.phase2,
              "block": args.block, "episodes_x": x.tolist(), "inside_band": inside,
              "reference": cr.tolist(), "jax_mean": np.nanmean(cj, 0).tolist(),
              "jax_min": lo.tolist(), "jax_max": hi.tolist(),
              "reference_timing": [t for _, t in refs]}
    atomic_write_text(out / "reference_crosscheck.json", json.dumps(result, indent=1))
    print(f"{inside:.0%} of the reference's points inside the JAX agents' band; "
          f"wrote {out / 'reference_crosscheck.png'}")


if __name__ == "__main__":
    main()
