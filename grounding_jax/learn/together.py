"""The three modules learning together: the pieces a run needs to train the TL, the AL and
the AN in rounds, each module reading the others' current state.

The paper trains them one after another (the TL, then the AL told the true position, then
the AN on the trained AL's sequences) and leaves training them at the same time as future
work. Here the AL is told what a TL estimates (`told_table`: the TL's winner-take-all
position, or its raw outputs, for each layout, position and word), and the AN's inputs are
a TL's hidden layer beside the AL's hidden layer on greedy episodes (`namer_inputs`). Which
TL and which AL is the caller's choice: the current ones (together) or the trained ones
(in sequence). `grounding_jax.paper.stages.together` compares the two on the same seeds and
budget.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.learn import an, cacla, esn, tl
from grounding_jax.sim import tl_data
from grounding_jax.sim.env import EnvConfig, Task

#: What the AL is told of the TL's estimate: the one-hot of its winning position (what
#: `Robot.perform` passes on) or its three sigmoid outputs as they are.
TOLD = ("winner", "output")
#: the TL the together stage trains: the shipped hidden size, replication and input balance
TL_HYPER = tl.TLHyper(hidden=50, replication=20, **tl.TUNED)
#: the TLs a together run can train: the shipped one, the paper's (lr 0.1, every input at 1),
#: or the shipped one at a tenth of its learning rate (wrong for longer while the AL learns)
TL_HYPERS = {"shipped": TL_HYPER, "paper": tl.TLHyper(hidden=50, replication=20),
             "slow": TL_HYPER.replace(lr=TL_HYPER.lr / 10)}


def told_index(data: tl_data.TLData | None = None) -> np.ndarray:
    """``[36, 3, 2]``: the configuration (0..215) that names the object at each layout and
    position by its shape word (0) or its colour word (1)."""
    data = tl_data.load() if data is None else data
    index = np.full((int(data.layout.max()) + 1, 3, 2), -1, np.int64)
    n_shapes = len(tl_data.TARGET_WORDS) // 2
    kind = (np.asarray(data.word) >= n_shapes).astype(np.int64)
    index[data.layout, data.labels, kind] = np.arange(len(data.labels))
    if np.any(index < 0):
        raise ValueError("data: some object is named by no configuration")
    return index


def told_table(outputs: jax.Array, told: str = "winner",
               data: tl_data.TLData | None = None) -> jax.Array:
    """The units the AL is told (`grounding_jax.learn.al.ALHyper.told`) from a TL's outputs
    ``[..., 216, 3]``: ``[..., 36, 3, 2, 3]``."""
    if told not in TOLD:
        raise ValueError(f"told: unknown value {told!r}; accepted values: {TOLD}")
    outputs = jnp.asarray(outputs, jnp.float32)
    if told == "winner":
        outputs = jax.nn.one_hot(jnp.argmax(outputs, -1), outputs.shape[-1])
    return outputs[..., jnp.asarray(told_index(data)), :]


@functools.lru_cache(maxsize=4)
def _inputs(config: tl.TLConfig):
    data = tl_data.load()
    bitmaps, symbols = jnp.asarray(data.bitmaps), jnp.asarray(data.symbols)

    @jax.jit
    def run(params: tl.TLParams, hp: tl.TLHyper) -> tuple[jax.Array, jax.Array]:
        _, hid_mask = tl.masks(hp, config)
        return tl.apply(params, tl.build_inputs(bitmaps, symbols, hp, config), hid_mask)

    return run


def tl_layers(params: tl.TLParams, config: tl.TLConfig, hp: tl.TLHyper = TL_HYPER
              ) -> tuple[jax.Array, jax.Array]:
    """A TL's (hidden activations ``[216, H]``, outputs ``[216, 3]``) for every
    configuration; batched parameters give a leading agent axis."""
    run = _inputs(config)
    if params.b2.ndim == 1:  # one TL
        return run(params, hp)
    return jax.vmap(run, in_axes=(0, None))(params, hp)


def sequence_tasks(configs: np.ndarray, n_actions: int, data: tl_data.TLData | None = None
                   ) -> dict[str, np.ndarray]:
    """Every action on each of ``configs``: ``config``, ``action``, ``position``, ``layout``
    and ``word`` arrays ``[len(configs) * n_actions]`` (a configuration's actions side by
    side)."""
    data = tl_data.load() if data is None else data
    config = np.repeat(np.asarray(configs, np.int64), n_actions)
    return {"config": config, "action": np.tile(np.arange(n_actions), len(configs)),
            "position": np.asarray(data.labels)[config],
            "layout": np.asarray(data.layout)[config], "word": np.asarray(data.word)[config]}


def namer_inputs(agent: cacla.Agent, tl_hidden: jax.Array, told: jax.Array, key: jax.Array,
                 seq: dict[str, np.ndarray], steps: int, env: EnvConfig) -> np.ndarray:
    """The ESN's inputs ``[N, steps, 40 + H]`` for the sequences ``seq`` (`sequence_tasks`):
    the greedy actor's hidden layer, told ``told`` (``[36, 3, 2, 3]``) for the command's
    word, from home, beside the TL's hidden layer ``tl_hidden`` ``[216, H]`` for the
    command's configuration."""
    kind = (seq["word"] >= len(tl_data.TARGET_WORDS) // 2).astype(np.int64)
    told = np.asarray(told)
    tasks = Task(action=jnp.asarray(seq["action"], jnp.int32),
                 position=jnp.asarray(seq["position"], jnp.int32),
                 layout=jnp.asarray(seq["layout"], jnp.int32),
                 target_units=jnp.asarray(told[seq["layout"], seq["position"], kind]))
    h = an.actor_sequences(agent, key, tasks, steps, env=env)
    what = np.asarray(tl_hidden)[seq["config"]]
    return np.concatenate([h, np.broadcast_to(what[:, None], h.shape[:2] + what.shape[1:])],
                          axis=2).astype(np.float32)


def fit_namer(net: esn.ESN, inputs: np.ndarray, action: np.ndarray, word: np.ndarray,
              n_actions: int) -> esn.ESN:
    """``net`` with its readout fitted (as `grounding_jax.learn.an.train_namer` fits it) on
    the sequences ``inputs`` ``[N, T, n_in]`` from a zero reservoir state."""
    states = esn_states(net, inputs)
    d = esn.targets(jnp.asarray(action), jnp.asarray(word), n_actions)
    d = jnp.broadcast_to(d[:, None], states.shape[:2] + (d.shape[-1],))
    return net.replace(w_out=esn.fit_readout(states.reshape(-1, states.shape[-1]),
                                             d.reshape(-1, d.shape[-1])))


def esn_states(net: esn.ESN, inputs: np.ndarray) -> jax.Array:
    """Reservoir states ``[N, T, n_res]`` from a zero state."""
    return jax.vmap(lambda u: esn.run(net, u))(jnp.asarray(inputs))


def named_right(net: esn.ESN, inputs: np.ndarray, action: np.ndarray, word: np.ndarray,
                n_actions: int) -> float:
    """The share of sequences whose action and target word are both right at the last
    step."""
    states = esn_states(net, inputs)[:, -1]
    a, w = esn.decode(esn.apply(net, states), n_actions)
    return float(np.mean((np.asarray(a) == action) & (np.asarray(w) == word)))
