"""The action namer (AN): data from a trained actor and TL, ESN training over seeds, Fig 15,
and the toroidal SOM of the actor's hidden layer (Fig 12).

Data (paper, section 2.3): for each of the 216 configurations (36 layouts x 6 target words) and
each of the 3 actions, the trained actor runs for ``steps`` steps toward the named object; its
40 hidden activations at each step, beside the 50 hidden activations of the trained TL for that
configuration, are the ESN's 90 inputs; the target is the sentence (action word + target word).
Configurations are split 2/3 : 1/3 into train and test (all 3 actions of a configuration on
the same side). Test sequences are also run from random arm starts with a random initial
reservoir state.

A sequence is named correctly when both decoded words are right at its last step.
"""

from __future__ import annotations

import functools
import json
import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.core import xla
from grounding_jax.core.io import atomic_write_text, pyplot, write_figure
from grounding_jax.learn import al, cacla, esn, som, tl
from grounding_jax.sim import scene, tl_data
from grounding_jax.sim import tasks as tasks_lib
from grounding_jax.sim.env import DEFAULT_PARAMS, Env, EnvConfig, EnvParams, Task, as_env

PAPER = {"train_acc": 0.99, "test_acc": 0.99}
DEFAULT_ENV = EnvConfig()
DEFAULT_ESN = esn.ESNConfig()
DEFAULT_SOM = som.SOMConfig()


def train_tl(key: jax.Array, epochs: int, data: tl_data.TLData | None = None
             ) -> tuple[tl.TLParams, tl.TLHyper, np.ndarray, float]:
    """Train one TL (H=50, n=20, the shipped `tl.TUNED` input balance and rate).

    Returns:
        (parameters, its hyperparameters, hidden activations for the 216 configurations
        ``[216, 50]``, test accuracy).
    """
    data = tl_data.load() if data is None else data
    cfg = tl.TLConfig(epochs=epochs, max_hidden=50, max_replication=20, eval_every=epochs,
                      pixel_budget=int(data.bitmaps.sum(1).max()))  # clean bitmaps: sparse rows
    hp = tl.TLHyper(hidden=50, replication=20, **tl.TUNED)
    params, m = jax.jit(tl.make_train(cfg, data))(key, hp)
    x = tl.build_inputs(jnp.asarray(data.bitmaps), jnp.asarray(data.symbols), hp, cfg)
    _, hid_mask = tl.masks(hp, cfg)
    return (params, hp, np.asarray(tl.apply(params, x, hid_mask)[0]),
            float(m["final_test_acc"]))


def tl_hidden(key: jax.Array, epochs: int, data: tl_data.TLData | None = None
              ) -> tuple[np.ndarray, float]:
    """Train one TL (as `train_tl`) and return its hidden activations for the 216
    configurations ``[216, 50]`` and its test accuracy."""
    return train_tl(key, epochs, data)[2:]


def actor_sequences(agent: cacla.Agent, key: jax.Array, tasks: Task, steps: int,
                    params: EnvParams = DEFAULT_PARAMS, env: Env | EnvConfig = DEFAULT_ENV
                    ) -> np.ndarray:
    """The greedy actor's hidden activations ``[N, steps, hidden]`` for a batch of tasks."""
    keys = jax.random.split(key, tasks.action.shape[0])
    run = _sequences(as_env(env).config, steps)
    return np.asarray(run(agent, keys, tasks, params))


@functools.lru_cache(maxsize=8)
def _sequences(config: EnvConfig, steps: int):
    """The jitted batch of `actor_sequences` for one env config and episode length
    (the agent and params are arguments, not constants: one compile serves every call)."""
    evaluate = al.make_eval(config, steps)
    return xla.physics_jit(jax.vmap(lambda a, k, t, p: evaluate(a, k, t, p)[2],
                                    in_axes=(None, 0, 0, None)), config)


def dataset(agent: cacla.Agent, tl_h: np.ndarray, key: jax.Array, steps: int = 100,
            start_noise: float = 0.0, env: Env | EnvConfig = DEFAULT_ENV) -> dict:
    """All sequences: 216 configurations x the actions of ``env``'s task set (648 for
    the paper's 3).

    Returns:
        ``inputs`` [648, steps, 90], ``actor_hidden`` [648, steps, 40], ``action``, ``word``,
        ``position``, ``config`` [648] (configuration index 0..215).
    """
    data = tl_data.load()
    env = as_env(env)
    n_actions = env.tasks.n_actions
    config = np.repeat(np.arange(tl_data.N_CONFIGS), n_actions)
    action = np.tile(np.arange(n_actions), tl_data.N_CONFIGS)
    tasks = Task(action=jnp.asarray(action, jnp.int32),
                 position=jnp.asarray(data.labels[config], jnp.int32),
                 layout=jnp.asarray(data.layout[config], jnp.int32))
    h = actor_sequences(agent, key, tasks, steps, EnvParams(start_noise=start_noise), env)
    tl_part = np.broadcast_to(tl_h[config][:, None], (len(config), steps, tl_h.shape[1]))
    return {"inputs": np.concatenate([h, tl_part], axis=2).astype(np.float32),
            "actor_hidden": h, "action": action, "word": data.word[config],
            "position": data.labels[config], "config": config}


@jax.jit
def _states(esn_net: esn.ESN, inputs: np.ndarray, x0: jax.Array) -> jax.Array:
    """Reservoir states ``[N, T, n_res]`` of a batch of sequences from initial states x0."""
    return jax.vmap(lambda u, x: esn.run(esn_net, u, x))(jnp.asarray(inputs), x0)


def _correct(esn_net: esn.ESN, states: jax.Array, action, word, n_actions: int) -> np.ndarray:
    """``[N, T]``: both decoded words right at each step."""
    a, w = esn.decode(esn.apply(esn_net, states), n_actions)
    return (np.asarray(a) == np.asarray(action)[:, None]) & (np.asarray(w) ==
                                                             np.asarray(word)[:, None])


def _settle(ok: np.ndarray) -> np.ndarray:
    """Per sequence: the first step from which the naming stays correct (T if never)."""
    t = ok.shape[1]
    wrong_after = np.flip(np.cumsum(np.flip(~ok, 1), 1), 1) > 0  # a wrong step at or after t
    return np.where(wrong_after.all(1), t, np.argmin(wrong_after, axis=1))


def train_namer(key: jax.Array, home: dict, rand: dict, train_fraction: float = 2 / 3,
                config: esn.ESNConfig = DEFAULT_ESN, ridge: float = 0.0) -> dict:
    """One seed: split, init the ESN, fit the readout on the training sequences (home starts,
    zero initial state), and name train / test / random-start test sequences.

    The split is over ``home["config"]`` (all sequences of a configuration on one side):
    the paper's 216 (layout, word) configurations, or ``home["n_configs"]`` of them when the
    data set says so (the free family's scenes)."""
    k_split, k_init, k_x0 = jax.random.split(key, 3)
    n_actions = tasks_lib.get(config.task_set).n_actions
    n_configs = int(home.get("n_configs", tl_data.N_CONFIGS))
    perm = np.asarray(jax.random.permutation(k_split, n_configs))
    n_train = int(round(train_fraction * n_configs))
    train_cfg = np.zeros(n_configs, bool)
    train_cfg[perm[:n_train]] = True
    tr, te = train_cfg[home["config"]], ~train_cfg[home["config"]]
    net = esn.init(k_init, config)
    states = _states(net, home["inputs"][tr], jnp.zeros((int(tr.sum()), config.n_res)))
    d = esn.targets(jnp.asarray(home["action"][tr]), jnp.asarray(home["word"][tr]), n_actions)
    d = jnp.broadcast_to(d[:, None], states.shape[:2] + (d.shape[-1],))
    net = net.replace(w_out=esn.fit_readout(states.reshape(-1, config.n_res),
                                            d.reshape(-1, d.shape[-1]), ridge))
    out = {"net": net}
    x0_rand = jax.random.uniform(k_x0, (int(te.sum()), config.n_res), minval=-1, maxval=1)
    zeros_te = jnp.zeros((int(te.sum()), config.n_res))
    # the reservoir states do not depend on the readout: the training ones are reused
    for name, src, sel, st in (("train", home, tr, states),
                               ("test", home, te, _states(net, home["inputs"][te], zeros_te)),
                               ("test_random", rand, te,
                                _states(net, rand["inputs"][te], x0_rand))):
        ok = _correct(net, st, src["action"][sel], src["word"][sel], n_actions)
        settle = _settle(ok)
        out[name] = {"acc": float(ok[:, -1].mean()), "acc_per_step": ok.mean(0).tolist(),
                     "settle_mean": float(settle.mean()), "settle_median": float(np.median(settle))}
    out["train_mask"], out["x0_rand"] = tr, x0_rand
    return out


OUTPUT_NAMES = (*scene.ACTIONS, *tl_data.TARGET_WORDS)


def fig15(res: dict, home: dict, rand: dict, out: pathlib.Path) -> dict:
    """Fig 15: the 9 outputs over time for "point/touch/push sphere" -- a training
    configuration (home start, zero state) and a test one (random start and state)."""
    plt = pyplot()
    net, tr = res["net"], res["train_mask"]
    sphere = tl_data.word_index("sphere")
    fig, axes = plt.subplots(2, 3, figsize=(13, 6), sharey=True)
    data = {"outputs": OUTPUT_NAMES, "runs": []}
    te_index = np.flatnonzero(~tr)
    for row, (src, sel, label) in enumerate(((home, tr, "training set, home start"),
                                             (rand, ~tr, "test set, random start and state"))):
        for a in range(3):
            cand = np.flatnonzero(sel & (src["word"] == sphere) & (src["action"] == a))
            i = int(cand[0])
            x0 = (jnp.zeros(net.w_res.shape[0]) if row == 0 else
                  res["x0_rand"][int(np.searchsorted(te_index, i))])
            y = np.asarray(esn.apply(net, esn.run(net, jnp.asarray(src["inputs"][i]), x0)))
            ax = axes[row, a]
            for k in range(y.shape[1]):
                ax.plot(y[:, k], lw=1.6 if k in (a, 3 + sphere) else 0.8,
                        ls="-" if k < 3 else "--", label=OUTPUT_NAMES[k])
            ax.set_title(f"{scene.ACTIONS[a]} sphere ({label})", fontsize=9)
            ax.set_xlabel("step")
            data["runs"].append({"action": scene.ACTIONS[a], "set": label,
                                 "config": int(src["config"][i]), "outputs": y.tolist()})
    axes[0, 0].set_ylabel("output")
    axes[1, 0].set_ylabel("output")
    axes[0, 2].legend(fontsize=7, ncol=3)
    fig.suptitle("Fig 15: ESN outputs (solid: action words, dashed: target words)")
    fig.tight_layout()
    write_figure(out, "fig15", data, fig)
    return {"configs": [r["config"] for r in data["runs"]]}


def fig12(key: jax.Array, home: dict, out: pathlib.Path, skip: int = 0, every: int = 3,
          config: som.SOMConfig = DEFAULT_SOM) -> dict:
    """Fig 12: a toroidal SOM of the actor's hidden activations (steps ``skip``.. of the
    home-start sequences, every ``every``-th), drawn twice: cells coloured by majority action
    and by majority position, marker size by hit count. Returns the purities."""
    plt = pyplot()
    h = home["actor_hidden"][:, skip::every]  # [N, t, 40]
    n_t = h.shape[1]
    x = jnp.asarray(h.reshape(-1, h.shape[-1]))
    labels = {"action": np.repeat(home["action"], n_t),
              "position": np.repeat(home["position"], n_t)}
    w = som.train(key, x, config)
    units = np.asarray(som.bmu(w, x))
    cells = np.asarray(som.grid(config))
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    res = {"rows": config.rows, "cols": config.cols, "samples": int(x.shape[0])}
    for ax, (field, lab) in zip(axes, labels.items(), strict=True):
        names = scene.ACTIONS if field == "action" else scene.POSITIONS
        hits = np.bincount(units, minlength=len(cells))
        major = np.array([np.bincount(lab[units == u], minlength=3).argmax() if hits[u] else -1
                          for u in range(len(cells))])
        for k, name in enumerate(names):
            sel = major == k
            ax.scatter(cells[sel, 1], cells[sel, 0], s=8 + 300 * hits[sel] / hits.max(),
                       label=name, alpha=0.8)
        ax.scatter(cells[major < 0, 1], cells[major < 0, 0], s=4, c="lightgrey")
        p = som.purity(units, lab)
        res[f"purity_{field}"] = p
        ax.set_title(f"by {field} (purity {p:.2f})")
        ax.set_aspect("equal")
        ax.invert_yaxis()
        ax.legend(fontsize=8, loc="upper right")
    fig.suptitle(f"Fig 12: toroidal SOM ({config.rows}x{config.cols}) of actor hidden "
                 "activations; marker size = hits")
    fig.tight_layout()
    write_figure(out, "fig12", res, fig)
    return res


def run(key: jax.Array, out, agent: cacla.Agent, seeds: int, tl_epochs: int, steps: int = 100,
        env_config: EnvConfig = DEFAULT_ENV, start_noise: float = 0.5,
        esn_config: esn.ESNConfig = DEFAULT_ESN) -> tuple[dict, dict]:
    """The AN results: accuracy over ``seeds`` ESNs (train, test, test from random starts),
    the settling time, Fig 15 and the SOM (Fig 12). Writes JSON + PNG under ``out``.

    Args:
        key: one PRNG key, split once here.
        out: output folder.
        agent: a trained actor (one agent).
        seeds: ESNs (and train/test splits) to train.
        tl_epochs: epochs of the TL whose hidden layer is the ESN's "what" input.
        steps: steps per sequence (paper: 100).
        env_config: static env config.
        start_noise: half-width of the random arm starts of the random-start test.
        esn_config: the ESN's static config.

    Returns:
        (results, the trained modules of seed 0: ``tl_params``, ``tl_hyper``, ``net``, the
        ESN with its readout, and ``esn_config`` -- what `grounding_jax.robot.trained.save`
        stores).
    """
    out = pathlib.Path(out)
    k_tl, k_home, k_rand, k_esn, k_som = jax.random.split(key, 5)
    tl_params, tl_hyper, tl_h, tl_acc = train_tl(k_tl, tl_epochs)
    env = Env(env_config)  # both data sets share it
    home = dataset(agent, tl_h, k_home, steps, 0.0, env)
    rand = dataset(agent, tl_h, k_rand, steps, start_noise, env)
    runs = [train_namer(k, home, rand, config=esn_config)
            for k in jax.random.split(k_esn, seeds)]
    res = {"seeds": seeds, "steps": steps, "tl_test_acc": tl_acc, "paper": PAPER}
    for name in ("train", "test", "test_random"):
        accs = [r[name]["acc"] for r in runs]
        res[name] = {"acc_mean": float(np.mean(accs)), "acc_std": float(np.std(accs)),
                     "acc_per_seed": accs,
                     "settle_median": float(np.mean([r[name]["settle_median"] for r in runs])),
                     "acc_per_step_mean": np.mean([r[name]["acc_per_step"] for r in runs],
                                                  0).tolist()}
    res["fig15"] = fig15(runs[0], home, rand, out)
    res["fig12"] = fig12(k_som, home, out)
    atomic_write_text(out / "an.json", json.dumps(res, indent=1) + "\n")
    return res, {"tl_params": tl_params, "tl_hyper": tl_hyper, "net": runs[0]["net"],
                 "esn_config": esn_config}
