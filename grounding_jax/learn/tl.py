"""Target localizer (TL): MLP (1200 + 15 n) -> H sigmoid -> 3 sigmoid, winner-take-all.

Trained as the paper did: plain online back-propagation (one pattern at a time, order shuffled
every epoch) of the squared error of the sigmoid outputs, learning rate 0.1, 500-600 epochs.

Everything is a pure function and ``vmap``-able over seeds and hyperparameters. The hidden
size and the replication factor ``n`` can both be *traced*: the network is built at padded
sizes (``TLConfig.max_hidden``, ``TLConfig.max_replication``) and masked -- masked hidden units
output 0 and masked input replicas are 0, so neither takes part in the forward pass or gets a
gradient, and the result equals that of the unpadded network (tested). For sweeps over the
hidden size, one compile per size turned out faster than padding everything to the largest
(``benchmarks/tl_throughput.py``), so the sweep runner (and `tl_experiments.run_grid`,
which runs through it) groups by hidden size;
``n`` stays traced (its cost is negligible, see `make_train`).
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from grounding_jax.core.checks import (
    POSITIVE,
    UNIT_CLOSED,
    Rule,
    check_config,
    check_rules,
    integer_at_least,
)
from grounding_jax.sim import tl_data

N_OUT = 3
N_SYMBOLS = 15
N_PIXELS = 1200
NOISE_MODES = ("fixed", "fresh")


#: What each count of `TLConfig` accepts (its ``__post_init__`` and the sweep runner
#: read it).
CONFIG_RULES: dict[str, Rule] = {name: integer_at_least(1) for name in (
    "epochs", "max_hidden", "max_replication", "eval_every")}


@dataclasses.dataclass(frozen=True)
class TLConfig:
    """Static configuration (changes compiled code).

    Attributes:
        epochs: sweeps through the training set.
        max_hidden: padded hidden size (>= every hidden size in the batch).
        max_replication: padded replication factor (>= every n in the batch).
        eval_every: record train/test accuracy every this many epochs.
        noise_mode: ``"fixed"`` -- each pattern's pixels are flipped once, before training
            (a fixed noisy data set); ``"fresh"`` -- a new flip at every presentation of a
            training pattern (test patterns keep one fixed draw).
        pixel_budget: 0 for dense pixel updates; else the number of pixel rows each online
            step touches (>= the active pixels of every bitmap; clean bitmaps only, so
            ``noise`` must be 0). Same result, less memory traffic.
    """

    epochs: int = 600
    max_hidden: int = 50
    max_replication: int = 20
    eval_every: int = 10
    noise_mode: str = "fixed"
    pixel_budget: int = 0

    def __post_init__(self) -> None:
        if self.noise_mode not in NOISE_MODES:
            raise ValueError(f"noise_mode: unknown value {self.noise_mode!r}; accepted values: "
                             f"{NOISE_MODES}")
        check_config(self, CONFIG_RULES)
        if self.eval_every > self.epochs:
            raise ValueError(f"eval_every: must be <= epochs ({self.epochs}: at least one "
                             f"evaluation), got {self.eval_every}")
        b = self.pixel_budget
        if not isinstance(b, (int, np.integer)) or isinstance(b, bool) or not 0 <= b <= N_PIXELS:
            raise ValueError(f"pixel_budget: must be an integer in 0..{N_PIXELS}, got {b!r}")

    @property
    def n_inputs(self) -> int:
        return N_PIXELS + N_SYMBOLS * self.max_replication


@struct.dataclass
class TLHyper:
    """Traced hyperparameters (scalars, or arrays with a leading batch axis under vmap).

    Attributes:
        lr: learning rate (paper: 0.1).
        hidden: hidden units in use (paper: 50).
        replication: times the 15 colour + target units are repeated (paper: 20).
        noise: probability that each bitmap pixel is flipped (fixed per pattern; paper: 0.1).
        image_scale: value of an "on" pixel (paper: 1). Input balance, like ``replication``.
        target_scale: value of the active target-word unit (paper: 1); the colour units stay
            1. Scaling an input by s acts like replicating it s**2 times more (same initial
            spread of the pre-activations, same change per update).
    """

    lr: Any = 0.1
    hidden: Any = 50
    replication: Any = 20
    noise: Any = 0.0
    image_scale: Any = 1.0
    target_scale: Any = 1.0


#: The shipped input balance and learning rate, chosen on tuning keys disjoint from the
#: reported ones (docs/tl.md); the defaults of `TLHyper` are the paper's.
TUNED = {"lr": 0.15, "image_scale": 0.6, "target_scale": 8.0}


def stack_hyper(rows: list[dict]) -> TLHyper:
    """A batch of hyperparameters from dicts of `HYPER_FIELDS` (a missing field takes
    the `TLHyper` default): arrays with a leading batch axis (float32 rates and
    scales, int32 sizes)."""
    default = TLHyper()
    return TLHyper(**{f: jnp.asarray([r.get(f, getattr(default, f)) for r in rows],
                                     jnp.float32 if is_float else jnp.int32)
                      for f, is_float in HYPER_FIELDS.items()})


def symbol_scale(hp: TLHyper) -> jax.Array:
    """Per-unit values ``[15]`` of the symbolic units: 1 for the 9 colour units,
    ``target_scale`` for the 6 target units."""
    n_target = len(tl_data.TARGET_WORDS)
    return jnp.concatenate([jnp.ones(N_SYMBOLS - n_target, jnp.float32),
                            jnp.full((n_target,), hp.target_scale, jnp.float32)])


#: What each field of `TLHyper` accepts (``validate`` and the sweep runner read it).
HYPER_RULES: dict[str, Rule] = {
    "lr": POSITIVE, "hidden": integer_at_least(1), "replication": integer_at_least(1),
    "noise": UNIT_CLOSED, "image_scale": POSITIVE, "target_scale": POSITIVE,
}
#: The fields of `TLHyper` and whether each is a float (else an int).
HYPER_FIELDS = {name: rule.type is float for name, rule in HYPER_RULES.items()}


def validate(hp: TLHyper, config: TLConfig) -> None:
    """Raise ValueError naming the field for bad concrete values (before any compile)."""
    check_rules(hp, HYPER_RULES)
    hid, rep, noise = (np.asarray(getattr(hp, f)) for f in ("hidden", "replication", "noise"))
    if np.any(hid > config.max_hidden):
        raise ValueError(f"hidden: {hid.max()} exceeds max_hidden={config.max_hidden}")
    if np.any(rep > config.max_replication):
        raise ValueError(f"replication (n): {rep.max()} exceeds max_replication="
                         f"{config.max_replication}")
    if config.pixel_budget and np.any(noise > 0):
        raise ValueError("noise: must be 0 with pixel_budget > 0 (sparse rows assume clean "
                         "bitmaps); use pixel_budget=0 for the noise test")


@struct.dataclass
class TLParams:
    w1: jax.Array  # [n_inputs, max_hidden]
    b1: jax.Array
    w2: jax.Array  # [max_hidden, 3]
    b2: jax.Array


@functools.partial(jax.jit, static_argnames='config')
def masks(hp: TLHyper, config: TLConfig) -> tuple[jax.Array, jax.Array]:
    """(input mask [n_inputs], hidden mask [max_hidden]) for the traced sizes."""
    rep = jnp.repeat(jnp.arange(config.max_replication) < hp.replication, N_SYMBOLS)
    in_mask = jnp.concatenate([jnp.ones(N_PIXELS, bool), rep]).astype(jnp.float32)
    hid_mask = (jnp.arange(config.max_hidden) < hp.hidden).astype(jnp.float32)
    return in_mask, hid_mask


def init(key: jax.Array, hp: TLHyper, config: TLConfig) -> TLParams:
    """Uniform weights in +-1/sqrt(fan-in) of the *used* sizes; zero biases.

    Each hidden unit's weights, and each replica's block of them, come from their own
    ``fold_in`` of the key, so the used part of the network does not depend on the padded
    sizes: a padded, masked network starts exactly as the unpadded one would.

    Args:
        key: PRNG key.
        hp: hyperparameters (hidden, replication set the fan-ins).
        config: static sizes.

    Returns:
        Parameters at the padded sizes.
    """
    k1, k2 = jax.random.split(key)
    fan1 = (N_PIXELS + N_SYMBOLS * jnp.asarray(hp.replication)).astype(jnp.float32)
    a1 = 1.0 / jnp.sqrt(fan1)
    a2 = 1.0 / jnp.sqrt(jnp.asarray(hp.hidden, jnp.float32))

    def unit_in(j):  # incoming weights of hidden unit j: pixels, then one block per replica
        kj = jax.random.fold_in(k1, j)
        pix = jax.random.uniform(jax.random.fold_in(kj, 0), (N_PIXELS,), jnp.float32, -1, 1)
        reps = jax.vmap(lambda r: jax.random.uniform(jax.random.fold_in(kj, r + 1),
                                                     (N_SYMBOLS,), jnp.float32, -1, 1))(
            jnp.arange(config.max_replication))
        return jnp.concatenate([pix, reps.reshape(-1)])

    def unit_out(j):
        return jax.random.uniform(jax.random.fold_in(k2, j), (N_OUT,), jnp.float32, -1, 1)

    units = jnp.arange(config.max_hidden)
    w1 = jax.vmap(unit_in, out_axes=1)(units) * a1
    w2 = jax.vmap(unit_out)(units) * a2
    return TLParams(w1=w1, b1=jnp.zeros(config.max_hidden), w2=w2, b2=jnp.zeros(N_OUT))


@jax.jit
def apply(params: TLParams, x: jax.Array, hid_mask: jax.Array | None = None
          ) -> tuple[jax.Array, jax.Array]:
    """Forward pass.

    Args:
        params: network parameters.
        x: input ``[..., n_inputs]`` (masked replicas already zero).
        hid_mask: ``[max_hidden]`` 0/1 mask of the hidden units in use (None: all).

    Returns:
        (hidden activations, outputs in (0, 1)); the position is ``argmax`` of the outputs.
    """
    h = jax.nn.sigmoid(x @ params.w1 + params.b1)
    if hid_mask is not None:
        h = h * hid_mask
    return h, jax.nn.sigmoid(h @ params.w2 + params.b2)


@functools.partial(jax.jit, static_argnames='config')
def build_inputs(bitmaps: jax.Array, symbols: jax.Array, hp: TLHyper, config: TLConfig
                 ) -> jax.Array:
    """Padded inputs ``[N, n_inputs]``: bitmap x ``image_scale``, then the 15 symbols (target
    units x ``target_scale``) x max_replication, masked."""
    in_mask, _ = masks(hp, config)
    sym = jnp.tile(symbols * symbol_scale(hp), (1, config.max_replication))
    return jnp.concatenate([bitmaps * hp.image_scale, sym], axis=1) * in_mask


@functools.partial(jax.jit, static_argnames='n_all')
def split_indices(key: jax.Array, n_all: int = tl_data.N_CONFIGS
                  ) -> tuple[jax.Array, jax.Array]:
    """(train, test) indices of the configurations that `make_train` uses for ``key``:
    a random 2/3 : 1/3 split (the same for every hyperparameter)."""
    perm = jax.random.permutation(jax.random.split(key, 4)[0], n_all)
    n_train = int(round(2 / 3 * n_all))
    return perm[:n_train], perm[n_train:]


class _Run(typing.NamedTuple):
    """One TL's training program for a key and hyperparameters (see `_program`)."""

    state: tuple  # the compact state at the start: pixel weights, U, biases, output layer
    keys: jax.Array  # one key per epoch
    epoch: typing.Callable  # (state, key) -> state
    evaluate: typing.Callable  # state -> ((train acc, test acc, train RMSE, test RMSE), right)
    params: typing.Callable  # state -> TLParams
    test: jax.Array  # the test configurations' indices


def make_train(config: TLConfig, data: tl_data.TLData | None = None):
    """Build ``train(key, hp) -> (params, metrics)`` over the 216 configurations.

    The key is split once into: the train/test split (2/3 : 1/3), the pixel noise, the
    initial weights and the per-epoch shuffles.

    Training is online back-propagation on the full network, computed compactly: the ``n``
    replicas of the 15 symbolic units always see the same input, so each gets the same
    update; the training loop carries that one shared ``[15, H]`` update instead of ``n``
    copies and rebuilds the full ``(1200 + 15 n)``-input weights at the end (exactly the
    weights plain backprop on the replicated input gives; tested against it). With
    ``config.pixel_budget > 0`` the pixel part of each step touches only the ``pixel_budget``
    rows of the active (1) pixels (exact for clean bitmaps, which have fewer 1s than that).

    Returns:
        A pure function; ``metrics`` holds ``train_acc``/``test_acc``/``train_rmse``/
        ``test_rmse`` every ``eval_every`` epochs (``[epochs // eval_every]``) and the final
        values (``final_train_acc``, ``final_test_acc``, ...).
    """
    data = tl_data.load() if data is None else data
    setup = _program(config, data)
    shape_word = jnp.asarray(data.word < len(tl_data.TARGET_WORDS) // 2)

    def train(key: jax.Array, hp: TLHyper) -> tuple[TLParams, dict[str, jax.Array]]:
        run = setup(key, hp)
        n_blocks = config.epochs // config.eval_every
        blocks = run.keys[: n_blocks * config.eval_every].reshape(n_blocks, config.eval_every)

        def block(st, keys):  # eval_every epochs, then one evaluation
            st = jax.lax.fori_loop(0, keys.shape[0], lambda j, q: run.epoch(q, keys[j]), st)
            return st, run.evaluate(st)[0]

        state, curves = jax.lax.scan(block, run.state, blocks)
        state = jax.lax.fori_loop(n_blocks * config.eval_every, config.epochs,
                                  lambda j, q: run.epoch(q, run.keys[j]), state)
        final, correct = run.evaluate(state)
        test_shape = shape_word[run.test]
        metrics = {
            "train_acc": curves[0], "test_acc": curves[1], "train_rmse": curves[2],
            "test_rmse": curves[3], "final_train_acc": final[0], "final_test_acc": final[1],
            "final_train_rmse": final[2], "final_test_rmse": final[3],
            # test accuracy on patterns naming a shape / a colour (the latter never needs
            # the image)
            "final_test_acc_shape_words": jnp.sum(correct[run.test] & test_shape)
            / jnp.maximum(jnp.sum(test_shape), 1),
            "final_test_acc_colour_words": jnp.sum(correct[run.test] & ~test_shape)
            / jnp.maximum(jnp.sum(~test_shape), 1),
        }
        return run.params(state), metrics

    return train


def make_rounds(config: TLConfig, data: tl_data.TLData | None = None):
    """Build ``(start, advance, params)``: one TL trained a few epochs at a time, as
    `make_train` trains it (the same epochs, keys and updates; no evaluations between).

    ``start(key, hp) -> state``; ``advance(key, hp, state, first, epochs) -> (state, (train
    acc, test acc))`` runs epochs ``first .. first + epochs - 1`` of ``config.epochs``
    (``epochs`` static, ``first`` traced); ``params(key, hp, state) -> TLParams``. The key
    and hyperparameters are the run's own at every call.
    """
    setup = _program(config, data)

    def start(key: jax.Array, hp: TLHyper) -> tuple:
        return setup(key, hp).state

    def advance(key: jax.Array, hp: TLHyper, state: tuple, first: jax.Array, epochs: int):
        run = setup(key, hp)
        keys = jax.lax.dynamic_slice_in_dim(run.keys, first, epochs)
        state = jax.lax.fori_loop(0, epochs, lambda j, q: run.epoch(q, keys[j]), state)
        return state, run.evaluate(state)[0][:2]

    def params(key: jax.Array, hp: TLHyper, state: tuple) -> TLParams:
        return setup(key, hp).params(state)

    return start, advance, params


# the online step, its compact state and the final weights share one closure
def _program(config: TLConfig, data: tl_data.TLData | None):  # noqa: C901
    """``setup(key, hp) -> _Run``: the training program of `make_train` for one key."""
    data = tl_data.load() if data is None else data
    bitmaps = jnp.asarray(data.bitmaps)
    symbols_raw = jnp.asarray(data.symbols)
    labels = jnp.asarray(data.labels)
    targets = jax.nn.one_hot(labels, N_OUT)
    n_all = labels.shape[0]
    n_train = int(round(2 / 3 * n_all))
    budget = config.pixel_budget
    if budget:
        active = data.bitmaps.sum(1)
        if active.max() > budget:
            raise ValueError(f"pixel_budget: {budget} is below the {int(active.max())} active "
                             "pixels of the densest bitmap")
        order = np.argsort(-data.bitmaps, axis=1, kind="stable")[:, :budget]
        pix_idx = jnp.asarray(order, jnp.int32)  # rows of the 1s first, then 0-rows (val 0)
        pix_val = jnp.asarray(np.take_along_axis(data.bitmaps, order, axis=1))

    def setup(key: jax.Array, hp: TLHyper) -> _Run:
        _, k_noise, k_init, k_epochs = jax.random.split(key, 4)  # the first: split_indices
        tr, te = split_indices(key, n_all)
        on = jnp.asarray(hp.image_scale, jnp.float32)  # the value of an "on" pixel
        symbols = symbols_raw * symbol_scale(hp)
        if budget:  # sparse rows are only valid for the clean bitmaps (validate checks)
            pixels = bitmaps * on
            row_vals = pix_val * on
        else:
            flip = jax.random.bernoulli(k_noise, hp.noise, bitmaps.shape)
            pixels = jnp.where(flip, 1.0 - bitmaps, bitmaps) * on
        _, hid_mask = masks(hp, config)
        p0 = init(k_init, hp, config)
        rep_mask = (jnp.arange(config.max_replication) < hp.replication).astype(jnp.float32)
        w_sym0 = p0.w1[N_PIXELS:].reshape(config.max_replication, N_SYMBOLS, -1)
        s0 = jnp.einsum("r,rsh->sh", rep_mask, w_sym0)  # sum of the used replicas' weights
        n_rep = jnp.asarray(hp.replication, jnp.float32)
        # compact state: pixel weights, shared symbol update U, biases, output layer
        state = (p0.w1[:N_PIXELS], jnp.zeros_like(s0), p0.b1, p0.w2, p0.b2)

        def forward(st, pix, sym):
            wp, u, b1, w2, b2 = st
            h = jax.nn.sigmoid(pix @ wp + sym @ (s0 + n_rep * u) + b1) * hid_mask
            return h, jax.nn.sigmoid(h @ w2 + b2)

        def evaluate(st):
            """(train acc, test acc, train RMSE, test RMSE), and which patterns are right."""
            _, y = forward(st, pixels, symbols)
            correct = jnp.argmax(y, -1) == labels
            err = jnp.mean((y - targets) ** 2, axis=-1)
            acc = correct.astype(jnp.float32)
            return (acc[tr].mean(), acc[te].mean(), jnp.sqrt(err[tr].mean()),
                    jnp.sqrt(err[te].mean())), correct

        def sgd(st, i_k):
            i, k = i_k
            wp, u, b1, w2, b2 = st
            sym = symbols[i]
            if budget:
                rows, vals = pix_idx[i], row_vals[i]
                h = jax.nn.sigmoid(vals @ wp[rows] + sym @ (s0 + n_rep * u) + b1) * hid_mask
            else:
                pix = pixels[i]
                if config.noise_mode == "fresh":
                    pix = jnp.where(jax.random.bernoulli(k, hp.noise, pix.shape),
                                    1.0 - bitmaps[i], bitmaps[i]) * on
                h = jax.nn.sigmoid(pix @ wp + sym @ (s0 + n_rep * u) + b1) * hid_mask
            y = jax.nn.sigmoid(h @ w2 + b2)
            d_out = (y - targets[i]) * y * (1.0 - y)  # d(0.5 |y - t|^2) / d(pre-activation)
            d_hid = (w2 @ d_out) * h * (1.0 - h) * hid_mask
            if budget:
                wp = wp.at[rows].add(-hp.lr * vals[:, None] * d_hid[None])
            else:
                wp = wp - hp.lr * jnp.outer(pix, d_hid)
            return (wp, u - hp.lr * jnp.outer(sym, d_hid), b1 - hp.lr * d_hid,
                    w2 - hp.lr * jnp.outer(h, d_out), b2 - hp.lr * d_out), None

        def epoch(st, k):
            k_order, k_flip = jax.random.split(k)
            order = tr[jax.random.permutation(k_order, n_train)]
            return jax.lax.scan(sgd, st, (order, jax.random.split(k_flip, n_train)))[0]

        def to_params(st) -> TLParams:
            wp, u, b1, w2, b2 = st
            w_sym = w_sym0 + rep_mask[:, None, None] * u[None]  # every used replica got U
            return TLParams(w1=jnp.concatenate([wp, w_sym.reshape(-1, w_sym.shape[-1])]),
                            b1=b1, w2=w2, b2=b2)

        return _Run(state=state, keys=jax.random.split(k_epochs, config.epochs), epoch=epoch,
                    evaluate=evaluate, params=to_params, test=te)

    return setup


def localize(params: TLParams, bitmap: jax.Array, symbols: jax.Array, hp: TLHyper
             ) -> jax.Array:
    """Position (0 left, 1 middle, 2 right) of the named object, by winner-take-all.

    Args:
        params: trained parameters (padded sizes are read from their shapes).
        bitmap: ``[1200]`` edge bitmap.
        symbols: ``[15]`` colour + target units.
        hp: the hyperparameters the network was trained with (hidden size, replication and
            input scales; the others are unused).
    """
    cfg = TLConfig(max_hidden=params.w1.shape[1],
                   max_replication=(params.w1.shape[0] - N_PIXELS) // N_SYMBOLS)
    x = build_inputs(bitmap[None], symbols[None], hp, cfg)[0]
    _, hid_mask = masks(hp, cfg)
    return jnp.argmax(apply(params, x, hid_mask)[1])
