"""Naming an action from the camera's frames only: what the observer sees, not what it is told.

`grounding_jax.robot.observer` names another agent's act from its joint angles. Here the robot
has only the frames `grounding_jax.frames` renders (any size, the third-person ``observer``
camera by default) and reads them with its own colour vision:

1. **Seeing.** Each pixel is the table (its one flat colour), an object (saturated: red, green
   or blue by its strongest channel), the robot (unsaturated, not the table, not the black
   background) or nothing. The robot's pixels that change during the episode are its arm; its
   lowest ones in the image are the hand.
2. **Features**, per object (a scene's three objects have three colours): how much of the
   moving arm is over it (in its column and near it), how low the arm comes in its column, how
   far the object moves (its visible centroid, held while the hand hides it) and how much of
   it is hidden, and the hand's offset from it -- at the end of the episode and at their
   extremes. The features are fractions of the image width: any frame size reads alike.
3. **Naming.** A few small networks (an ensemble) score every (action, object) pair from that
   object's features (shared weights: the same act looks alike whichever object it is aimed
   at), their probabilities averaged; the best pair
   is named by the action's word and the object's colour word (a scene's colours tell its
   objects apart, so the colour names the target).

The network is fitted on the robot's own episodes, commands known (it learns what its own
acts look like), and then names other agents' episodes it never saw (the ``watch_frames``
stage). Nothing of the simulator's state enters: no joint angles, no object coordinates, no
command.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from grounding_jax.sim import render, tasks

#: the table's colour in the observer camera's frames (flat, no shadows); `label_frames` takes
#: the first frame's commonest colour as the table's, so other cameras and lights read alike
TABLE_RGB = (219, 219, 214)
COLOURS = tasks.COLOURS
#: per object: the features `features` returns, in order
FEATURES = ("arm_in_column_end", "arm_in_column_max", "arm_low_end", "arm_low_max",
            "arm_near_end", "arm_near_max", "moved_max", "moved_end", "visible_end",
            "visible_min", "hand_dx_end", "hand_dy_end", "hand_dx_min", "top_moved_max",
            "seen_end")
N_FEATURES = len(FEATURES)
#: the cameras a namer reads, those `grounding_jax.frames` renders: ``"both"``'s frames are
#: the observer's and the eye's side by side, each read alone, their features joined
CAMERAS = render.CAMERAS
#: frames wider than this are read at every n-th pixel, to about this width
READ_WIDTH = 240
#: labels of `label_frames`
NOTHING, ARM = 0, 4


def check_frames(frames: Any, field: str = "frames") -> np.ndarray:
    """``frames`` as ``uint8 [T, H, W, 3]`` or a batch ``[N, T, H, W, 3]`` (T >= 2), else a
    ValueError naming ``field`` and the accepted shapes."""
    arr = np.asarray(frames)
    if arr.dtype != np.uint8 or arr.ndim not in (4, 5) or arr.shape[-1] != 3 \
            or arr.shape[-4] < 2 or min(arr.shape[-3:-1]) < 8:
        raise ValueError(f"{field}: got {arr.dtype} of shape {arr.shape}; accepted: uint8 "
                         "[T, H, W, 3] or [N, T, H, W, 3] with T >= 2 frames of at least 8x8 "
                         "pixels, as grounding_jax.frames returns")
    return arr


def n_features(camera: str = "observer") -> int:
    """How many features per object `features` returns for frames of ``camera``."""
    if camera not in CAMERAS:
        raise ValueError(f"camera: unknown value {camera!r}; accepted values: {CAMERAS}")
    return N_FEATURES * (2 if camera == "both" else 1)


def label_frames(frames: np.ndarray) -> np.ndarray:
    """Each pixel of ``frames`` ``[T, H, W, 3]`` labelled: 0 nothing (table, background),
    1-3 an object of colour ``COLOURS[label - 1]``, 4 the robot."""
    f = frames.astype(np.int16)
    hi, lo = f.max(-1), f.min(-1)
    sat = (hi - lo) / np.maximum(hi, 1)
    table = np.abs(f - table_colour(frames[0])).max(-1) <= 4
    obj = (sat > 0.45) & (hi > 25)
    robot = (sat < 0.2) & ~table & (hi > 12)
    return (np.where(obj, f.argmax(-1) + 1, NOTHING)
            + np.where(robot, ARM, NOTHING)).astype(np.uint8)


def table_colour(frame: np.ndarray) -> np.ndarray:
    """The commonest colour of a frame ``[H, W, 3]`` that is neither black nor saturated:
    the table's (int16 ``[3]``)."""
    px = frame.reshape(-1, 3).astype(np.int16)
    hi, lo = px.max(-1), px.min(-1)
    grey = px[(hi > 40) & (hi - lo < 0.2 * hi)]
    if len(grey) == 0:
        return np.asarray(TABLE_RGB, np.int16)
    colours, counts = np.unique(grey, axis=0, return_counts=True)
    return colours[np.argmax(counts)]


def _hand(moving: np.ndarray) -> np.ndarray:
    """The hand's image position ``[T, 2]`` (x, y as fractions of the width; the lowest
    moving pixels; zero in a frame where no arm moves)."""
    t_n, h, w = moving.shape
    hand = np.zeros((t_n, 2))
    for t in range(t_n):
        ys, xs = np.nonzero(moving[t])
        if len(ys) > 3:
            low = ys >= ys.max() - max(2, h // 50)
            hand[t] = xs[low].mean() / w, ys[low].mean() / w
    return hand


def _track(mask: np.ndarray, xs: np.ndarray, ys: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An object's visible area ``[T]``, its centroid ``[T, 2]`` (held at its last place
    while mostly hidden) and whether it was mostly visible ``[T]``."""
    area = mask.sum((1, 2)).astype(np.float64)
    safe = np.maximum(area, 1.0)
    c = np.stack([(mask * xs).sum((1, 2)) / safe, (mask * ys).sum((1, 2)) / safe], 1)
    seen = area > 0.4 * max(area[0], 1.0)
    for t in range(1, len(c)):
        if not seen[t]:
            c[t] = c[t - 1]
    return area, c, seen


def features(frames: Any, camera: str = "observer") -> np.ndarray:
    """Per object (by colour), the `FEATURES` of an episode's frames: ``float32 [3,
    n_features(camera)]``. ``frames``: ``uint8 [T, H, W, 3]`` of ``camera`` (for ``"both"``
    the two views side by side, as `grounding_jax.frames` renders them: each view's
    features, the observer's first)."""
    frames = check_frames(frames)
    if n_features(camera) == N_FEATURES:
        return _view_features(frames)
    if frames.shape[2] % 2:
        raise ValueError(f"frames: {frames.shape[2]} pixels wide; accepted for camera 'both': "
                         "an even width (two views side by side)")
    return np.concatenate([_view_features(v) for v in np.split(frames, 2, axis=2)], -1)


# one line per feature group reads better than helpers split to fit 80 lines
def _view_features(frames: np.ndarray) -> np.ndarray:
    """`features` of one camera's frames ``[T, H, W, 3]``: ``float32 [3, N_FEATURES]``."""
    stride = max(1, frames.shape[2] // READ_WIDTH)  # what a wider frame adds is not needed
    lab = label_frames(frames[:, ::stride, ::stride])
    t_n, h, w = lab.shape
    arm = lab == ARM
    moving = arm & ~arm.all(0)  # the body (head, torso) stays where it is
    ys, xs = np.mgrid[0:h, 0:w] / w
    tail = slice(int(t_n * 0.8), t_n)
    count = moving.sum((1, 2)) + 1e-6
    hand = _hand(moving)
    rows = []
    for c in range(len(COLOURS)):
        m = lab == c + 1
        area, centre, seen = _track(m, xs, ys)
        if area[0] == 0:
            rows.append(np.zeros(N_FEATURES))  # not in view
            continue
        top = np.array([ys[mm].min() if mm.any() else np.nan for mm in m])
        ox, oy = centre[0]
        column = moving & (np.abs(xs - ox) < 0.035)[None]
        in_col = column.sum((1, 2)) / count
        low = np.array([ys[b].max() - top[0] if b.any() else -0.2 for b in column])
        near = (moving & (np.hypot(xs - ox, ys - oy) < 0.06)[None]).sum((1, 2)) / count
        moved = np.hypot(*(centre - centre[0]).T)
        d = hand - centre[0]
        visible = area / area[0]
        top_moved = np.abs(top - top[0])
        rows.append([in_col[tail].mean(), in_col.max(), low[tail].mean(), low.max(),
                     near[tail].mean(), near.max(), moved.max(), moved[tail].mean(),
                     visible[tail].mean(), visible.min(), d[tail, 0].mean(), d[tail, 1].mean(),
                     np.abs(d[:, 0]).min(),
                     np.nanmax(top_moved) if np.isfinite(top_moved).any() else 0.0,
                     seen[tail].mean()])
    return np.asarray(rows, np.float32)


class FramesNamer(struct.PyTreeNode):
    """The fitted scorer: feature standardization (``mean``, ``scale`` ``[F]``, F =
    `n_features` of its camera) and
    an ensemble of ``members`` one-hidden-layer networks (``w1 [members, F,
    hidden]``, ``w2 [members, hidden, n_actions]``), each shared by the three objects; their
    probabilities are averaged (members fitted from other draws disagree where the frames say
    little, and the average is steadier than any one)."""

    mean: jax.Array
    scale: jax.Array
    w1: jax.Array
    b1: jax.Array
    w2: jax.Array
    b2: jax.Array
    #: the camera of the frames it was fitted on (frames of another camera read otherwise)
    camera: str = struct.field(pytree_node=False, default="observer")

    def member_logits(self, feats: jax.Array) -> jax.Array:
        """Each member's logits ``[..., members, n_actions * 3]`` (action-major) of features
        ``[..., 3, F]``."""
        z = (feats - self.mean) / self.scale
        h = jnp.tanh(jnp.einsum("...of,mfh->...moh", z, self.w1) + self.b1[:, None, :])
        s = jnp.einsum("...moh,mha->...mao", h, self.w2) + self.b2[:, :, None]
        return s.reshape(s.shape[:-2] + (-1,))

    def scores(self, feats: jax.Array) -> jax.Array:
        """``[..., n_actions, 3 objects]`` log of the members' mean probability of each
        (action, object) pair for features ``[..., 3, F]``."""
        p = jax.nn.softmax(self.member_logits(feats), axis=-1).mean(-2)
        return jnp.log(p).reshape(p.shape[:-1] + (self.w2.shape[-1], -1))


def like(hidden: int, n_actions: int, camera: str = "observer", members: int = 1
         ) -> FramesNamer:
    """A zero `FramesNamer` of these sizes (the shape a checkpoint is restored into)."""
    z, f = jnp.zeros, n_features(camera)
    return FramesNamer(mean=z(f), scale=jnp.ones(f),
                       w1=z((members, f, hidden)), b1=z((members, hidden)),
                       w2=z((members, hidden, n_actions)), b2=z((members, n_actions)),
                       camera=camera)


def fit(key: jax.Array, feats: np.ndarray, action: np.ndarray, target: np.ndarray,
        n_actions: int, hidden: int = 8, l2: float = 1e-3, steps: int = 1500,
        lr: float = 1e-2, camera: str = "observer", members: int = 7) -> FramesNamer:
    """Fit a `FramesNamer` by full-batch Adam (optax): each member on softmax cross-entropy
    over every (action, object) pair plus ``l2`` times its squared weights, from its own
    initial draw.

    Args:
        key: initialises the weights.
        feats: ``[N, 3, F]`` (`features` of N episodes, F = `n_features` of ``camera``).
        action: ``[N]`` the action done (index).
        target: ``[N]`` the target's colour index (into `COLOURS`).
        n_actions: how many actions there are.
        hidden: hidden units.
        l2: weight decay.
        steps: Adam steps.
        lr: its learning rate.
        camera: the camera the frames came from (kept with the namer).
        members: networks in the ensemble.
    """
    x, f = np.asarray(feats, np.float32), n_features(camera)
    if x.ndim != 3 or x.shape[1:] != (len(COLOURS), f):
        raise ValueError(f"feats: shape {x.shape}; accepted for camera {camera!r}: "
                         f"[N, {len(COLOURS)}, {f}]")
    flat = x.reshape(-1, f)
    k1, k2 = jax.random.split(key)
    net = FramesNamer(
        mean=jnp.asarray(flat.mean(0)), scale=jnp.asarray(flat.std(0) + 1e-6),
        w1=jax.random.normal(k1, (members, f, hidden)) / np.sqrt(f),
        b1=jnp.zeros((members, hidden)),
        w2=jax.random.normal(k2, (members, hidden, n_actions)) / np.sqrt(hidden),
        b2=jnp.zeros((members, n_actions)), camera=camera)
    label = jnp.asarray(np.asarray(action) * len(COLOURS) + np.asarray(target))
    return _adam(net, jnp.asarray(x), label, jnp.float32(l2), steps, lr)


def _adam(net: FramesNamer, x: jax.Array, label: jax.Array, l2: jax.Array, steps: int,
          lr: float) -> FramesNamer:
    opt = optax.adam(lr)

    def loss(n: FramesNamer) -> jax.Array:  # the members' losses summed: each its own
        logits = jnp.swapaxes(n.member_logits(x), 0, 1)  # [members, N, pairs]
        ce = optax.softmax_cross_entropy_with_integer_labels(logits, label[None]).mean(-1)
        return jnp.sum(ce + l2 * (jnp.sum(n.w1 ** 2, (1, 2)) + jnp.sum(n.w2 ** 2, (1, 2))))

    def step(carry, _):
        n, s = carry
        g = jax.grad(loss)(n)
        g = g.replace(mean=jnp.zeros_like(n.mean), scale=jnp.zeros_like(n.scale))
        u, s = opt.update(g, s, n)
        return (optax.apply_updates(n, u), s), None

    (net, _), _ = jax.jit(lambda n: jax.lax.scan(step, (n, opt.init(n)), None, steps))(net)
    return net


def best(net: FramesNamer, feats: np.ndarray) -> tuple[int, int, np.ndarray]:
    """(action index, colour index, scores ``[n_actions, 3]``) of one episode's features."""
    s = np.asarray(net.scores(jnp.asarray(feats, jnp.float32)))
    a, c = np.unravel_index(int(np.argmax(s)), s.shape)
    return int(a), int(c), s


#: the families a robot may hold a frames namer for
FAMILIES = ("paper", "free")


def namers_config(namers: dict[str, FramesNamer]) -> dict[str, dict[str, int]]:
    """The JSON a checkpoint keeps of namers by family: their sizes."""
    bad = [f for f in namers if f not in FAMILIES]
    if bad:
        raise ValueError(f"frames_namers: families {bad} not accepted; accepted: {FAMILIES}")
    return {f: {"hidden": int(n.w1.shape[-1]), "n_actions": int(n.w2.shape[-1]),
                "members": int(n.w1.shape[0]), "camera": n.camera} for f, n in namers.items()}


def namers_like(config: dict[str, dict[str, int]]) -> dict[str, FramesNamer]:
    """Zero namers of the sizes `namers_config` wrote (ValueError/KeyError if it is not)."""
    if not set(config) <= set(FAMILIES):
        raise ValueError(f"frames: families {sorted(config)}; accepted: {FAMILIES}")
    return {f: like(int(c["hidden"]), int(c["n_actions"]), str(c["camera"]),
                    int(c["members"])) for f, c in config.items()}


def watch(namers: dict[str, FramesNamer] | None, frames: Any, family: str,
          action_names: tuple[str, ...], camera: str = "observer"
          ) -> tuple[str, str] | list[tuple[str, str]]:
    """(action word, target colour word) of ``frames`` (one episode or a batch) by the namer of
    ``family``; see `grounding_jax.robot.trained.Robot.watch_frames`."""
    if family not in FAMILIES:
        raise ValueError(f"family: {family!r} not accepted; accepted: {FAMILIES}")
    if not namers or family not in namers:
        raise ValueError(f"family: these modules hold no frames namer for {family!r} (held: "
                         f"{sorted(namers or {})}); the watch_frames stage fits one and saves "
                         "the robot with it (results/<profile>/watch_frames/modules)")
    arr = check_frames(frames)
    net = namers[family]
    if camera != net.camera:
        raise ValueError(f"camera: {camera!r}, but the {family!r} namer was fitted on frames of "
                         f"the {net.camera!r} camera; accepted: {net.camera!r} (render them with "
                         f"grounding_jax.frames(episode, camera={net.camera!r}))")
    if int(net.w2.shape[-1]) != len(action_names):
        raise ValueError(f"family: its namer scores {net.w2.shape[-1]} actions, the robot has "
                         f"{len(action_names)}")
    out = []
    for episode in (arr if arr.ndim == 5 else arr[None]):
        a, c, _ = best(net, features(episode, net.camera))
        out.append((action_names[a], COLOURS[c]))
    return out if arr.ndim == 5 else out[0]
