"""Where is it, in centimetres: the target localizer for objects placed anywhere (regression).

The paper's TL (`grounding_jax.learn.tl`) answers "left, middle or right" for the three fixed
slots. With free placement (`grounding_jax.sim.placement`) the answer is the target's table
coordinates (x, y). The network is the same family -- one sigmoid hidden layer over the edge
bitmap and the 15 symbolic units (replicated) -- with two linear outputs, the coordinates
scaled to [-1, 1] over the reachable region.

Three things change in the input, all because positions must survive the pipeline:

- the bitmap is cropped to a fixed window of the table (`vision.table_window`), not to
  the objects' group (the paper's crop keeps only where the objects stand relative to each
  other);
- it is ``BITMAP_W`` x ``BITMAP_H`` = 40 x 30 (the paper's 1200 values, shaped like the
  window) instead of 60 x 20;
- its cells keep their grey edge level (the share of the cell the outline covers) instead
  of being binarised: a binary cell cannot say where inside it an edge lies. Measured on
  6,000 scenes (hidden 200): binary 40 x 30 gave a held-out median error of 0.92 cm and a
  95th percentile of 3.9 cm, grey 0.59 / 3.1 cm; 80 x 60 binary 0.88 / 3.3 cm. What was
  left were shape words (cylinder, box): more scenes fixed that (18,000 scenes: 0.43 / 1.85
  cm).

The 9 colour units say the colour of the left, middle and right object (slots ranked by y),
as in the paper. The data set -- scenes with random placements and layouts, each serving all
six target words -- is rendered once and shipped (``assets/tl_xy_bitmaps.npz``; regenerate with
``python -m grounding_jax.learn.tl_xy --regenerate``); the labels are the target's centre read back
from the simulator's state after placing the objects.

Training is minibatch Adam (optax) on the squared error, ``vmap``-able over seeds and learning
rates: ``make_train(config) -> train(key, hyper) -> (params, metrics)``.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import pathlib
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from grounding_jax.core import trees
from grounding_jax.core.checks import (
    POSITIVE,
    UNIT_OPEN_LEFT,
    Rule,
    check_config,
    check_rules,
    integer_at_least,
)
from grounding_jax.sim import placement as free
from grounding_jax.sim import scene, tasks, tl_data

BITMAP_W, BITMAP_H = 40, 30
N_PIXELS = BITMAP_W * BITMAP_H
N_SYMBOLS = 15
DATA_NPZ = scene.ASSETS / "tl_xy_bitmaps.npz"
#: scenes in the shipped data set, and the seed they were drawn with
N_SCENES = 18000
DATA_SEED = 0
_LO = np.array([free.REACH_X[0], free.REACH_Y[0]], np.float32)
_HI = np.array([free.REACH_X[1], free.REACH_Y[1]], np.float32)


class XYData(NamedTuple):
    """Rendered scenes for the continuous TL (one row per scene; every scene serves all six
    target words: the label of word ``w`` is the centre of the object ``w`` names)."""

    bitmaps: np.ndarray  # [N, 1200] float32 grey edge levels in [0, 1]
    layout: np.ndarray  # [N] int32
    placement: np.ndarray  # [N, 3, 3] float32
    slot_xy: np.ndarray  # [N, 3, 2] the left/middle/right object's centre, from the simulator


#: ``[36 layouts, 6 words]``: the slot each target word names
WORD_SLOT = np.array([[tl_data.label_of(lay, w) for w in range(len(tasks.TARGET_WORDS))]
                      for lay in range(len(scene.LAYOUTS))], np.int32)
#: ``[36 layouts, 6 words, 15]``: the symbolic units of each (layout, word)
SYMBOLS = np.array([[tl_data.symbol_units(lay, w) for w in range(len(tasks.TARGET_WORDS))]
                    for lay in range(len(scene.LAYOUTS))], np.float32)


# ------------------------------------------------------------------------------------ data
@functools.partial(jax.jit, static_argnums=1)
def _draw(key: jax.Array, n: int) -> tuple[jax.Array, jax.Array]:
    # one program per n (run op by op, the sampler was ~20 programs per call site)
    k_p, k_l = jax.random.split(key)
    placements = jax.vmap(free.sample)(jax.random.split(k_p, n))
    return placements, jax.random.randint(k_l, (n,), 0, len(scene.LAYOUTS))


def draw_scenes(key: jax.Array, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random scenes: placements ``[n, 3, 3]`` and layouts ``[n]``."""
    placements, layouts = _draw(key, n)
    return np.asarray(placements), np.asarray(layouts, np.int32)


def bitmap(rgb: np.ndarray) -> np.ndarray:
    """Camera image -> the ``[1200]`` grey edge bitmap of the fixed table window (40 x 30)."""
    from grounding_jax.sim import vision

    return vision.bitmap_from_image(rgb, window=vision.table_window(),
                                    size=(BITMAP_W, BITMAP_H), binary=False)


def render(placements: np.ndarray, layouts: np.ndarray, progress: bool = False) -> XYData:
    """Render the scenes with the eye camera; read each slot's centre back from the
    simulator's state."""
    from grounding_jax.sim import vision

    r = vision.eye_renderer()
    idx = scene.index()
    slots = scene.layout_shape_slots()
    n = len(layouts)
    bitmaps = np.zeros((n, N_PIXELS), np.float32)
    slot_xy = np.zeros((n, 3, 2), np.float32)
    it = range(n)
    if progress:
        from tqdm import tqdm
        it = tqdm(it, desc="render", unit="scene")
    for i in it:
        lay = int(layouts[i])
        bitmaps[i] = bitmap(r.render(lay, placements[i]))
        for shape in range(3):
            slot_xy[i, slots[lay, shape]] = r.data.qpos[idx.object_qpos[shape, :2]]
    return XYData(bitmaps, np.asarray(layouts, np.int32), np.asarray(placements, np.float32),
                  slot_xy)


def save(data: XYData, path: pathlib.Path = DATA_NPZ) -> None:
    """Write a data set (edge levels as uint8 in 1/255 steps), atomically."""
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, bitmaps=np.round(data.bitmaps * 255.0).astype(np.uint8),
                        layout=data.layout, placement=data.placement, slot_xy=data.slot_xy)
    tmp.replace(path)


def load(path: pathlib.Path = DATA_NPZ) -> XYData:
    """The shipped data set (``N_SCENES`` scenes)."""
    with np.load(path) as z:
        bm = z["bitmaps"].astype(np.float32) / 255.0
        return XYData(bm, z["layout"], z["placement"], z["slot_xy"])


def normalise(xy: Any) -> Any:
    """Metres -> [-1, 1] over the reachable region."""
    return 2.0 * (xy - _LO) / (_HI - _LO) - 1.0


def denormalise(u: Any) -> Any:
    """[-1, 1] over the reachable region -> metres."""
    return _LO + (u + 1.0) * 0.5 * (_HI - _LO)


# ----------------------------------------------------------------------------------- model
CONFIG_RULES: dict[str, Rule] = {name: integer_at_least(1) for name in (
    "hidden", "replication", "steps", "batch_size", "eval_every")}


@dataclasses.dataclass(frozen=True)
class XYConfig:
    """Static configuration (changes compiled code).

    Attributes:
        hidden: hidden units.
        replication: times the 15 symbolic units are repeated (the paper's n).
        steps: minibatch updates.
        batch_size: scenes per update.
        eval_every: record the test error every this many steps.
        test_fraction: share of the scenes held out (never trained on).
    """

    hidden: int = 200
    replication: int = 20
    steps: int = 60000
    batch_size: int = 64
    eval_every: int = 1000
    test_fraction: float = 0.2

    def __post_init__(self) -> None:
        check_config(self, CONFIG_RULES)
        if not 0.0 < self.test_fraction < 1.0:
            raise ValueError(f"test_fraction: must be in (0, 1), got {self.test_fraction!r}")


@struct.dataclass
class XYHyper:
    """Traced hyperparameters.

    Attributes:
        lr: Adam's learning rate at the first step.
        symbol_scale: value of an active symbolic unit (input balance against the pixels).
        lr_final: the learning rate at the last step, as a fraction of ``lr``; it falls along
            a half cosine (1: constant).

    The defaults were chosen on two tuning keys (``benchmarks/tl_xy_tuning.py``,
    docs/beyond.md): against a constant 1e-3 the held-out median error fell by about a
    third and the 95th percentile by a tenth.
    """

    lr: Any = 3e-3
    symbol_scale: Any = 1.0
    lr_final: Any = 0.01

    def validate(self) -> XYHyper:
        """Check every field against its rule; raise ValueError naming the bad one."""
        check_rules(self, {"lr": POSITIVE, "symbol_scale": POSITIVE, "lr_final": UNIT_OPEN_LEFT})
        return self


def learning_rate(hp: XYHyper, step: Any, steps: int) -> jax.Array:
    """The learning rate at update ``step`` of ``steps``: ``lr`` falling to ``lr * lr_final``
    along a half cosine."""
    frac = jnp.clip(jnp.asarray(step, jnp.float32) / max(steps - 1, 1), 0.0, 1.0)
    return hp.lr * (hp.lr_final + (1.0 - hp.lr_final) * 0.5 * (1.0 + jnp.cos(jnp.pi * frac)))


DEFAULT_HYPER = XYHyper()


@struct.dataclass
class XYParams:
    w1: jax.Array
    b1: jax.Array
    w2: jax.Array
    b2: jax.Array


@functools.partial(jax.jit, static_argnames='replication')
def inputs(bitmaps: jax.Array, symbols: jax.Array, replication: int,
           symbol_scale: Any = 1.0) -> jax.Array:
    """Network inputs ``[..., 1200 + 15 n]``: bitmap, then the symbolic units n times."""
    reps = (1,) * (symbols.ndim - 1) + (replication,)
    return jnp.concatenate([bitmaps, jnp.tile(symbols * symbol_scale, reps)], axis=-1)


def init(key: jax.Array, config: XYConfig) -> XYParams:
    """Uniform weights scaled by fan-in; zero biases."""
    n_in = N_PIXELS + N_SYMBOLS * config.replication
    k1, k2 = jax.random.split(key)
    w1 = jax.random.uniform(k1, (n_in, config.hidden), jnp.float32, -1, 1) * n_in ** -0.5
    w2 = jax.random.uniform(k2, (config.hidden, 2), jnp.float32, -1, 1) * config.hidden ** -0.5
    return XYParams(w1, jnp.zeros(config.hidden), w2, jnp.zeros(2))


def _hidden_of(params: XYParams, x: jax.Array) -> jax.Array:
    return jax.nn.sigmoid(x @ params.w1 + params.b1)


@jax.jit
def apply(params: XYParams, x: jax.Array) -> jax.Array:
    """Normalised coordinates ``[..., 2]`` (see `denormalise`) of inputs ``x``."""
    return _hidden_of(params, x) @ params.w2 + params.b2


def split(key: jax.Array, n: int, test_fraction: float) -> tuple[jax.Array, jax.Array]:
    """(train, test) indices of ``n`` scenes for ``key``."""
    perm = jax.random.permutation(key, n)
    n_test = int(round(test_fraction * n))
    return perm[n_test:], perm[:n_test]


def make_train(config: XYConfig, data: XYData):
    """Build ``train(key, hyper) -> (params, metrics)``: ``config.steps`` Adam updates on
    minibatches of (training scene, target word) pairs; the held-out scenes are judged with
    all six words every ``eval_every`` steps. ``metrics``: ``test_median_cm``,
    ``test_p95_cm`` ``[steps // eval_every]``, the final ``test_err_cm`` ``[test scenes, 6]``
    and the ``test_idx`` (scenes) it refers to."""
    bm = jnp.asarray(data.bitmaps)
    sym = jnp.asarray(SYMBOLS)[data.layout]  # [N, 6, 15]
    word_xy = jnp.take_along_axis(jnp.asarray(data.slot_xy),
                                  jnp.asarray(WORD_SLOT[data.layout])[..., None], axis=1)
    n, n_words = bm.shape[0], len(tasks.TARGET_WORDS)
    n_blocks = config.steps // config.eval_every

    def train(key: jax.Array, hp: XYHyper) -> tuple[XYParams, dict[str, jax.Array]]:
        k_split, k_init, k_batches = jax.random.split(key, 3)
        train_idx, test_idx = split(k_split, n, config.test_fraction)
        opt = optax.inject_hyperparams(optax.adam)(
            learning_rate=lambda count: learning_rate(hp, count, config.steps))
        params = init(k_init, config)
        x_test = inputs(jnp.repeat(bm[test_idx][:, None], n_words, axis=1), sym[test_idx],
                        config.replication, hp.symbol_scale)

        def loss(p, rows, words):
            x = inputs(bm[rows], sym[rows, words], config.replication, hp.symbol_scale)
            return jnp.mean(jnp.sum((apply(p, x) - normalise(word_xy[rows, words])) ** 2, -1))

        def update(carry, k):
            p, s = carry
            k_r, k_w = jax.random.split(k)
            rows = train_idx[jax.random.randint(k_r, (config.batch_size,), 0, len(train_idx))]
            words = jax.random.randint(k_w, (config.batch_size,), 0, n_words)
            upd, s = opt.update(jax.grad(loss)(p, rows, words), s, p)
            return (optax.apply_updates(p, upd), s), None

        def errors(p):
            pred = denormalise(apply(p, x_test))
            return 100.0 * jnp.linalg.norm(pred - word_xy[test_idx], axis=-1)

        def block(carry, keys):
            carry, _ = jax.lax.scan(update, carry, keys)
            e = errors(carry[0])
            return carry, (jnp.median(e), jnp.quantile(e, 0.95))

        keys = jax.random.split(k_batches, (n_blocks, config.eval_every))
        (params, _), (med, p95) = jax.lax.scan(block, (params, opt.init(params)), keys)
        return params, {"test_median_cm": med, "test_p95_cm": p95,
                        "test_err_cm": errors(params), "test_idx": test_idx}

    return train


def localize(params: XYParams, bitmaps: jax.Array, symbols: jax.Array, config: XYConfig,
             hp: XYHyper = DEFAULT_HYPER) -> jax.Array:
    """The target's table coordinates (metres) ``[..., 2]`` from bitmaps and symbols."""
    return denormalise(apply(params, inputs(bitmaps, symbols, config.replication,
                                            hp.symbol_scale)))


def hidden(params: XYParams, bitmaps: jax.Array, symbols: jax.Array, config: XYConfig,
           hp: XYHyper = DEFAULT_HYPER) -> jax.Array:
    """The hidden layer ``[..., hidden]`` for bitmaps and symbols (the free family's namer
    reads it as the TL's "what" input, as the paper's AN reads the TL's)."""
    return _hidden_of(params, inputs(bitmaps, symbols, config.replication, hp.symbol_scale))


#: the goals for the held-out error (cm)
GOAL_MEDIAN_CM, GOAL_P95_CM = 1.0, 2.5


def run(key: jax.Array, out: pathlib.Path, seeds: int = 3, config: XYConfig = XYConfig(),
        scenes: int = N_SCENES, hyper: XYHyper = DEFAULT_HYPER) -> tuple[dict, XYParams]:
    """The continuous TL's result: ``seeds`` localizers (each its own train/test split of the
    first ``scenes`` shipped scenes) trained in one ``vmap``; held-out error in cm, overall
    and by target word. Writes ``out/tl_xy.json`` and ``out/tl_xy.png`` (error CDFs).

    Returns:
        (the results dict, the trained parameters of seed 0).
    """
    import time

    from grounding_jax.core.io import pyplot, write_figure

    data = load()
    if not 0 < scenes <= len(data.layout):
        raise ValueError(f"scenes: must be in 1..{len(data.layout)}, got {scenes!r}")
    data = XYData(*(x[:scenes] for x in data))
    hyper.validate()
    t = time.perf_counter()
    params, m = jax.jit(jax.vmap(make_train(config, data), in_axes=(0, None)))(
        jax.random.split(key, seeds), hyper)
    err = np.asarray(m["test_err_cm"])  # [seeds, test scenes, 6 words]
    wall = time.perf_counter() - t
    med, p95 = np.median(err, axis=(1, 2)), np.quantile(err, 0.95, axis=(1, 2))
    words = tasks.TARGET_WORDS
    res = {"scenes": scenes, "test_scenes": int(err.shape[1]), "seeds": seeds,
           "config": dataclasses.asdict(config),
           "hyper": {k: float(v) for k, v in dataclasses.asdict(hyper).items()},
           "median_cm": med.tolist(), "p95_cm": p95.tolist(),
           "median_cm_median_seed": float(np.median(med)),
           "p95_cm_median_seed": float(np.median(p95)),
           "by_word_median_cm": {w: float(np.median(err[..., i])) for i, w in enumerate(words)},
           "by_word_p95_cm": {w: float(np.quantile(err[..., i], 0.95))
                              for i, w in enumerate(words)},
           "curve_median_cm": np.asarray(m["test_median_cm"]).tolist(),
           "curve_p95_cm": np.asarray(m["test_p95_cm"]).tolist(),
           "goals_cm": {"median": GOAL_MEDIAN_CM, "p95": GOAL_P95_CM}, "wall_s": wall}
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for label, cols in (("shape words", slice(0, 3)), ("colour words", slice(3, 6))):
        e = np.sort(err[..., cols].ravel())
        ax.plot(e, np.arange(1, e.size + 1) / e.size, label=label)
    ax.axvline(GOAL_MEDIAN_CM, color="grey", ls=":", lw=0.8)
    ax.axvline(GOAL_P95_CM, color="grey", ls="--", lw=0.8)
    ax.set(xlabel="held-out error (cm)", ylabel="share of (scene, word)", xlim=(0, 6),
           title=f"TL with free placement: {seeds} seeds, {err.shape[1]} held-out scenes each")
    ax.legend(fontsize=8)
    write_figure(out, "tl_xy", res, fig)
    return res, trees.take(params, 0)


def main(argv: list[str] | None = None) -> None:
    """Command line: train the continuous TL and print its held-out errors."""
    ap = argparse.ArgumentParser(description="Render and ship the continuous TL's scenes.")
    ap.add_argument("--regenerate", action="store_true", help="render and overwrite the data")
    args = ap.parse_args(argv)
    if args.regenerate:
        data = render(*draw_scenes(jax.random.key(DATA_SEED), N_SCENES), progress=True)
        save(data)
        print(f"wrote {DATA_NPZ}: {data.bitmaps.shape}")
    else:
        print(f"{DATA_NPZ}: {load().bitmaps.shape}; use --regenerate to re-render")


if __name__ == "__main__":
    main()
