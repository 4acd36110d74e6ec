"""The modules learning together: the TL, the AL and the AN trained at the same time, against
the paper's order (one after another), on the same seeds and the same budget.

Each module's budget is cut into ``rounds`` equal pieces: the TL's epochs, the AL's episodes
(the paper's two phases, its learning rate and exploration decays following the whole run),
the AN's training sequences. A step spends one piece of one module. In sequence the steps are
every TL piece, then every AL piece, then every AN piece (the paper); together they take
turns, TL, AL, AN, round after round. Whatever the order, the AL is told the TL's current
estimate of where the named object lies (`grounding_jax.learn.together.told_table`; the
reward follows the true object), and the AN's readout is fitted on every sequence it has
collected so far, each recorded from the AL and the TL as they were when it was collected.
Each agent has its own TL, AL and AN, drawn from the same keys in both arms: the arms differ
in the order of the steps only.

After each step the module it trained is measured (the TL's test configurations, the AL's
success told its TL's estimate, the AN naming test configurations): the learning curves.
At the end both arms are judged alike: success per action, told the agent's own TL's estimate
for each of the target's two words, and the share of test sequences named right.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import pathlib
import time

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core import xla
from grounding_jax.core.io import atomic_write_text, pyplot, write_figure
from grounding_jax.learn import al, esn, tl
from grounding_jax.learn import together as tg
from grounding_jax.paper import al_eval, al_experiments
from grounding_jax.paper.stage import Inputs, Stage
from grounding_jax.paper.stages.random_starts import LAYOUTS, pct
from grounding_jax.sim import scene, tl_data
from grounding_jax.sim.env import DEFAULT_PARAMS, EnvConfig, Task, as_env

ARMS = ("sequence", "together")
ACTIONS = scene.ACTIONS
#: the AN's training and test configurations (the paper's 2/3 : 1/3 of 216)
AN_TRAIN, AN_TEST = 144, 72


@dataclasses.dataclass(frozen=True)
class TogetherConfig:
    """The agents (each its own TL, AL and AN), the rounds each budget is cut into, the
    budgets (TL epochs, AL episodes of each phase, AN training configurations, each run with
    every action), the AN's test configurations, what the AL is told of the TL's estimate
    (`grounding_jax.learn.together.TOLD`), the layouts of the final judge and the steps of
    the AN's sequences, and which TL (`grounding_jax.learn.together.TL_HYPERS`)."""

    agents: int = 2
    rounds: int = 2
    tl_epochs: int = 40
    phase1_episodes: int = 30
    phase2_episodes: int = 30
    an_configs: int = 12
    an_test_configs: int = 12
    told: str = "winner"
    layouts: str = "shapes"
    steps: int = 100
    tl: str = "shipped"

    def __post_init__(self) -> None:
        for name, low in (("agents", 1), ("rounds", 1), ("tl_epochs", 1), ("an_configs", 1),
                          ("an_test_configs", 1), ("steps", 1), ("phase1_episodes", 0),
                          ("phase2_episodes", 0)):
            if getattr(self, name) < low:
                raise ValueError(f"{name}: must be >= {low}, got {getattr(self, name)}")
        for name, value in (("tl_epochs", self.tl_epochs), ("an_configs", self.an_configs),
                            ("phase1_episodes + phase2_episodes", self.episodes)):
            if value % self.rounds:
                raise ValueError(f"{name}: {value} does not split into rounds={self.rounds} "
                                 "equal pieces; accepted: a multiple of rounds")
        if self.an_configs > AN_TRAIN or self.an_test_configs > AN_TEST:
            raise ValueError(f"an_configs <= {AN_TRAIN} and an_test_configs <= {AN_TEST}, got "
                             f"{self.an_configs} and {self.an_test_configs}")
        if self.told not in tg.TOLD:
            raise ValueError(f"told: {self.told!r}; accepted values: {tg.TOLD}")
        if self.layouts not in LAYOUTS:
            raise ValueError(f"layouts: {self.layouts!r}; accepted values: {list(LAYOUTS)}")
        if self.tl not in tg.TL_HYPERS:
            raise ValueError(f"tl: {self.tl!r}; accepted values: {list(tg.TL_HYPERS)}")

    @property
    def episodes(self) -> int:
        return self.phase1_episodes + self.phase2_episodes


@functools.lru_cache(maxsize=4)
def _judge(env_config: EnvConfig):
    """``judge(agents, keys, tasks) -> success [agents, tasks]``: each agent its own tasks
    (the units it is told differ by agent), greedy, from home."""
    env = as_env(env_config, al_eval.EVAL_STEPS)
    evaluate = al.make_eval(env)

    def one(agent, key, task):
        _, traj, _ = evaluate(agent, key, task, DEFAULT_PARAMS)
        return al_eval.episode_success(traj, task, task_set=env.tasks)["success"]

    return xla.physics_jit(jax.vmap(jax.vmap(one, in_axes=(None, 0, 0))), env)


def judge_tasks(told: jax.Array, layouts: tuple[int, ...]) -> Task:
    """Every task of ``layouts`` once per word of its target, each agent told its own TL's
    units ``told`` ``[agents, 36, 3, 2, 3]``: a `Task` batch ``[agents, tasks]``."""
    base = al_eval.all_tasks(layouts)
    n = int(base.action.shape[0])
    lay, pos = np.tile(np.asarray(base.layout), 2), np.tile(np.asarray(base.position), 2)
    kind = np.repeat([0, 1], n)
    agents = told.shape[0]
    rep = lambda x: jnp.broadcast_to(jnp.tile(x, 2), (agents, 2 * n))  # noqa: E731
    return Task(action=rep(base.action), position=rep(base.position), layout=rep(base.layout),
                target_units=told[:, lay, pos, kind])


class _Modules:
    """One arm's modules for every agent, and a step of each (see the module doc)."""

    def __init__(self, keys: jax.Array, config: TogetherConfig, env_config: EnvConfig):
        self.config, self.env_config = config, env_config
        self.k_tl, k_al, k_an, self.k_judge = (keys[:, i] for i in range(4))
        self.tl_config = tl.TLConfig(epochs=config.tl_epochs, max_hidden=50,
                                     max_replication=20, eval_every=config.tl_epochs)
        start, advance, self._tl_params = tl.make_rounds(self.tl_config)
        self._tl_advance = jax.jit(jax.vmap(advance, in_axes=(0, None, 0, None, None)),
                                   static_argnums=4)
        self.tl_hp = tg.TL_HYPERS[config.tl]
        self.tl_state = jax.vmap(start, in_axes=(0, None))(self.k_tl, self.tl_hp)
        self.tl_done = 0
        self.al_config = al.ALConfig(env=env_config, phase1_episodes=config.phase1_episodes,
                                     phase2_episodes=config.phase2_episodes)
        start_al, self._al_advance = al.make_pieces(self.al_config)
        self.hp = al.validate(al.hyper(**al_experiments.TUNED, **al_experiments.TUNED_AL))
        self.al_state = start_al(k_al, self._hp())
        n_actions = env_config.tasks.n_actions
        self.n_actions = n_actions
        self.nets, self.seq_train, self.seq_test, self.collected = [], [], [], []
        for k in k_an:
            k_split, k_net = jax.random.split(k)
            perm = np.asarray(jax.random.permutation(k_split, tl_data.N_CONFIGS))
            self.nets.append(esn.init(k_net, esn.ESNConfig(task_set=env_config.task_set)))
            self.seq_train.append(tg.sequence_tasks(perm[:config.an_configs], n_actions))
            self.seq_test.append(tg.sequence_tasks(
                perm[AN_TRAIN:AN_TRAIN + config.an_test_configs], n_actions))
            self.collected.append([])
        self.an_done = 0

    def _hp(self, told: jax.Array | None = None) -> al.ALHyper:
        told = self.told() if told is None else told
        return self.hp.replace(told=told)

    def tl_layers(self) -> tuple[jax.Array, jax.Array]:
        params = jax.vmap(self._tl_params, in_axes=(0, None, 0))(self.k_tl, self.tl_hp,
                                                                 self.tl_state)
        return tg.tl_layers(params, self.tl_config, self.tl_hp)

    def told(self) -> jax.Array:
        return tg.told_table(self.tl_layers()[1], self.config.told)

    def step_tl(self) -> None:
        """One piece of the TL's epochs."""
        piece = self.config.tl_epochs // self.config.rounds
        self.tl_state, _ = self._tl_advance(self.k_tl, self.tl_hp, self.tl_state,
                                            self.tl_done, piece)
        self.tl_done += piece
        jax.block_until_ready(self.tl_state)

    def step_al(self) -> None:
        """One piece of the AL's episodes, told the TL's current estimate."""
        self.al_state, _ = self._al_advance(self.al_state, self._hp(),
                                            self.config.episodes // self.config.rounds)
        jax.block_until_ready(self.al_state["agent"])

    def _inputs(self, i: int, seq: dict, hidden: jax.Array, told: jax.Array) -> np.ndarray:
        agent = jax.tree.map(lambda x: x[i], self.al_state["agent"])
        key = jax.random.fold_in(self.k_judge[i], self.an_done)
        return tg.namer_inputs(agent, hidden[i], told[i], key, seq, self.config.steps,
                               self.env_config)

    def step_an(self) -> None:
        """One piece of the AN's training sequences, from the AL and the TL as they are; the
        readout refitted on all collected so far."""
        per = self.config.an_configs // self.config.rounds * self.n_actions
        hidden, outputs = self.tl_layers()
        told = tg.told_table(outputs, self.config.told)
        for i, seq in enumerate(self.seq_train):
            part = {k: v[self.an_done * per:(self.an_done + 1) * per] for k, v in seq.items()}
            self.collected[i].append(self._inputs(i, part, hidden, told))
            upto = {k: v[:(self.an_done + 1) * per] for k, v in seq.items()}
            self.nets[i] = tg.fit_namer(self.nets[i], np.concatenate(self.collected[i]),
                                        upto["action"], upto["word"], self.n_actions)
        self.an_done += 1

    def measure_tl(self) -> list[float]:
        """Each agent's TL test accuracy (its own split)."""
        _, outputs = self.tl_layers()
        labels = jnp.asarray(tl_data.load().labels)
        te = jax.vmap(lambda k: tl.split_indices(k)[1])(self.k_tl)
        right = jnp.argmax(outputs, -1) == labels
        return np.asarray(jnp.take_along_axis(right, te, 1).mean(1)).tolist()

    def measure_al(self, layouts: tuple[int, ...]) -> dict[str, list[float]]:
        """Each agent's success per action on ``layouts``, told its TL's estimate."""
        tasks = judge_tasks(self.told(), layouts)
        keys = jax.vmap(lambda k: jax.random.split(k, tasks.action.shape[1]))(self.k_judge)
        ok = np.asarray(_judge(self.env_config)(self.al_state["agent"], keys, tasks))
        act = np.asarray(tasks.action[0])
        return {a: ok[:, act == i].mean(1).tolist() for i, a in enumerate(ACTIONS)}

    def save(self, directory: pathlib.Path, i: int, extra: dict) -> None:
        """Agent ``i``'s TL, AL and AN as a robot (`grounding_jax.load` loads it)."""
        from grounding_jax.robot import trained

        pick = lambda tree: jax.tree.map(lambda x: x[i], tree)  # noqa: E731
        params = self._tl_params(self.k_tl[i], self.tl_hp, pick(self.tl_state))
        trained.save(directory, params, self.tl_hp, pick(self.al_state["agent"]),
                     self.al_config.learner, self.nets[i],
                     esn.ESNConfig(task_set=self.env_config.task_set), self.env_config,
                     extra=extra)

    def measure_an(self) -> list[float]:
        """Each agent's share of test sequences named right."""
        hidden, outputs = self.tl_layers()
        told = tg.told_table(outputs, self.config.told)
        return [tg.named_right(self.nets[i], self._inputs(i, seq, hidden, told),
                               seq["action"], seq["word"], self.n_actions)
                for i, seq in enumerate(self.seq_test)]


def order(arm: str, rounds: int) -> list[str]:
    """The modules each step trains: in sequence, or taking turns."""
    if arm == "sequence":
        return ["tl"] * rounds + ["al"] * rounds + ["an"] * rounds
    return ["tl", "al", "an"] * rounds


def train_arm(arm: str, keys: jax.Array, config: TogetherConfig, env_config: EnvConfig,
              ) -> tuple[dict, _Modules]:
    """One arm trained step by step: its learning curves, what the end is judged at, the
    seconds spent training (the measurements after each step aside), and its modules."""
    mods = _Modules(keys, config, env_config)
    curve_layouts = LAYOUTS["shapes"]
    curves: dict[str, list] = {"tl": [], "al": [], "an": []}
    train_s = 0.0
    steps = order(arm, config.rounds)
    for s, module in enumerate(steps, 1):
        t0 = time.perf_counter()
        getattr(mods, f"step_{module}")()
        train_s += time.perf_counter() - t0
        got = (mods.measure_al(curve_layouts) if module == "al" else
               getattr(mods, f"measure_{module}")())
        curves[module].append({"budget": s / len(steps), "per_agent": got})
        print(f"together stage, {arm}: step {s}/{len(steps)} ({module})", flush=True)
    final = mods.measure_al(LAYOUTS[config.layouts])
    return {"curves": curves, "train_s": train_s, "tl_test_acc": mods.measure_tl(),
            "success": final, "named": curves["an"][-1]["per_agent"]}, mods


def spread(values: list[float]) -> dict:
    """The median agent and the min-max over agents."""
    v = np.asarray(values, float)
    return {"median": float(np.median(v)), "min": float(v.min()), "max": float(v.max())}


def run(key: jax.Array, inputs: Inputs, out: pathlib.Path, config: TogetherConfig) -> dict:
    """Train both arms from the same keys and judge them alike (see the module doc)."""
    env_config = EnvConfig(backend=inputs.backend)
    keys = jax.vmap(lambda k: jax.random.split(k, 4))(jax.random.split(key, config.agents))
    t0 = time.perf_counter()
    _warm_up(keys, config, env_config)
    res = {"config": dataclasses.asdict(config), "warm_up_s": time.perf_counter() - t0,
           "arms": {}}
    out = pathlib.Path(out)
    for arm in ARMS:
        got, mods = train_arm(arm, keys, config, env_config)
        got["summary"] = {"tl_test_acc": spread(got["tl_test_acc"]),
                          "named": spread(got["named"]),
                          **{a: spread(v) for a, v in got["success"].items()}}
        res["arms"][arm] = got
    # the median agent (by its mean success over the actions) of the modules trained together
    mean = np.mean([got["success"][a] for a in ACTIONS], axis=0)
    res["saved_agent"] = int(np.argsort(mean)[(len(mean) - 1) // 2])
    mods.save(out / "modules", res["saved_agent"],
              {"stage": "together", "profile": inputs.profile, "told": config.told})
    figure(res, out)
    atomic_write_text(out / "together.json", json.dumps(res, indent=1))
    return res


def _warm_up(keys: jax.Array, config: TogetherConfig, env_config: EnvConfig) -> None:
    """One step of each module and each measurement on throwaway modules: the compiles both
    arms share land here, not in the first arm's seconds."""
    mods = _Modules(keys, config, env_config)
    for module in ("tl", "al", "an"):
        getattr(mods, f"step_{module}")()
    mods.measure_tl(), mods.measure_an(), mods.measure_al(LAYOUTS["shapes"])
    if config.layouts != "shapes":
        mods.measure_al(LAYOUTS[config.layouts])


def _curve(points: list[dict], reduce) -> tuple[list[float], list[float], list[float]]:
    xs = [p["budget"] for p in points]
    vals = [reduce(p["per_agent"]) for p in points]
    return xs, [float(np.median(v)) for v in vals], [float(np.min(v)) for v in vals]


def figure(res: dict, out: pathlib.Path) -> None:
    """``together.png``: the three modules' learning curves, both arms, against the share
    of the whole budget spent (median agent; the band reaches the weakest agent)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    panels = (("tl", "TL: test configurations located", lambda v: np.asarray(v)),
              ("al", "AL: success, mean of point / touch / push",
               lambda v: np.mean([v[a] for a in ACTIONS], axis=0)),
              ("an", "AN: test sequences named right", lambda v: np.asarray(v)))
    data = {}
    for ax, (module, title, reduce) in zip(axes, panels, strict=True):
        for arm, style in zip(ARMS, ("o-", "s--"), strict=True):
            xs, med, low = _curve(res["arms"][arm]["curves"][module], reduce)
            ax.plot(xs, med, style, label=arm)
            ax.fill_between(xs, low, med, alpha=0.15)
            data[f"{module}_{arm}"] = {"budget": xs, "median": med, "min": low}
        ax.set(title=title, xlabel="share of the whole budget spent", ylim=(0, 1.02),
               xlim=(0, 1.02))
        ax.legend(fontsize=8, loc="lower right")
    fig.suptitle("Modules trained in sequence (the paper) or together, same seeds and budget")
    fig.tight_layout()
    write_figure(out, "together", data, fig)


def report(res: dict, config: TogetherConfig) -> str:
    """The stage's REPORT section: both arms side by side, the figure and the answer."""
    c = res["config"]
    lines = [f"{len(res['arms']['sequence']['tl_test_acc'])} agents, each its own TL "
             f"({c.get('tl', 'shipped')} settings, {c['tl_epochs']} epochs), AL "
             f"({c['phase1_episodes']} + {c['phase2_episodes']} episodes) and AN "
             f"({c['an_configs']} training configurations x 3 actions), "
             f"every budget in {c['rounds']} pieces; the AL told its TL's "
             f"{'winning position' if c['told'] == 'winner' else 'outputs'}. Median agent "
             "(min-max); success told the TL's estimate for both words of each target "
             f"({c['layouts']} layouts); named: {c['an_test_configs']} test configurations x "
             "3 actions.", "",
             *arms_table(res)]
    lines += ["", "![learning curves](together/together.png)", "", answer(res), "",
              f"The median agent trained together (agent {res['saved_agent']}) is saved as a "
              "robot at `together/modules` (`grounding_jax.load`, then `perform`)."]
    return "\n".join(lines)


def arms_table(res: dict) -> list[str]:
    """The two arms side by side, a Markdown table's lines."""
    lines = ["| modules trained | TL test | point | touch | push | named right | training |",
             "|---|---|---|---|---|---|---|"]
    for arm in ARMS:
        s = res["arms"][arm]["summary"]
        cells = [f"{pct(s[k]['median'])} ({pct(s[k]['min'])}-{pct(s[k]['max'])})"
                 for k in ("tl_test_acc", *ACTIONS, "named")]
        lines.append(f"| {'one after another (the paper)' if arm == 'sequence' else 'together'}"
                     f" | {' | '.join(cells)} | {res['arms'][arm]['train_s']:.0f} s |")
    return lines


def answer(res: dict) -> str:
    """The comparison in words, from the measured medians."""
    seq, tog = (res["arms"][a]["summary"] for a in ARMS)
    parts = []
    for key, name in (("tl_test_acc", "the TL's test accuracy"), *((a, a) for a in ACTIONS),
                      ("named", "naming")):
        d = tog[key]["median"] - seq[key]["median"]
        word = "equal" if abs(d) < 0.005 else (f"{100 * d:+.0f} points")
        parts.append(f"{name} {word}")
    return ("Trained together instead of one after another, the median agent's results move "
            "by: " + ", ".join(parts) + ". The TL learns the same either way (it reads no "
            "other module); what differs is what the AL is told while the TL is still "
            "learning, and which AL the AN's sequences come from.")


STAGE = Stage(name="together", title="Beyond the paper: the modules learning together",
              config=TogetherConfig, run=run, report=report,
              profiles={"paper": {"agents": 5, "rounds": 6, "tl_epochs": 600,
                                  "phase1_episodes": 150, "phase2_episodes": 1050,
                                  "an_configs": 144, "an_test_configs": 72,
                                  "layouts": "all"}})
