"""Free placement: the three objects anywhere on the reachable part of the table.

The paper puts the objects in three fixed slots (left, middle, right: ``scene.OBJECT_Y`` at
``scene.OBJECT_X``). A *placement* moves the slots: ``[3 slots, 3]`` float32 rows
``(x, y, yaw)`` in metres and radians, for the left, middle and right object, in that order
(the slots stay ranked by ``y``, so "left" still means the object with the smallest ``y``
and the layouts still say which shape and colour stands in each slot). Placement is data,
like the layout: one compiled model serves every placement.

The region is where the iCub's palm reaches a point 3 cm above an object's top within about
1 cm with its four arm joints (measured with ``ik.solve`` from several start poses; the
paper's three slots lie on its edge): ``REACH_X`` x ``REACH_Y``. Centres are at least
``MIN_SPACING`` apart.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from grounding_jax.sim import scene, tasks

#: The reachable region of object centres (robot frame, metres): x (backward), y (right).
REACH_X = (-0.27, -0.20)
REACH_Y = (0.09, 0.31)
#: Smallest distance between two object centres (metres).
MIN_SPACING = 0.09
#: Candidate triples drawn per placement: the first one that keeps the spacing is taken.
#: About 1.3% of uniform triples do, so 1024 candidates all fail with probability ~2e-6;
#: then the paper's fixed slots are used.
CANDIDATES = 1024
#: Half-size of the table top (metres): objects out of reach must still stand on it.
TABLE_HALF = 0.6
#: Where a moving target's neighbours stand, out of reach on the far right (x, y; metres).
PARKED = ((-0.24, 0.40), (-0.24, 0.49))
_TOL = 1e-6  # float32 round-off allowed at the borders


def fixed() -> np.ndarray:
    """The paper's three slots as a placement ``[3, 3]`` (yaw 0)."""
    pos = scene.object_positions()
    return np.concatenate([pos[:, :2], np.zeros((3, 1))], axis=1).astype(np.float32)


def region_text() -> str:
    """The allowed region, as the error messages say it."""
    return (f"x in [{REACH_X[0]}, {REACH_X[1]}] m, y in [{REACH_Y[0]}, {REACH_Y[1]}] m, "
            f"centres >= {MIN_SPACING} m apart, rows ordered left to right (increasing y)")


def check(placement: Any, field: str = "placement", reach: tuple[int, ...] = (0, 1, 2)
          ) -> np.ndarray:
    """Validate a placement; return it as float32 ``[3, 3]`` (a missing yaw column is 0).

    Args:
        placement: ``[3, 2]`` (x, y) or ``[3, 3]`` (x, y, yaw) for the left, middle and
            right object; or a batch ``[..., 3, 2|3]``.
        field: the name the error messages use.
        reach: the slots that must lie in the reachable region (the others only on the
            table, within ``TABLE_HALF`` of the origin: a moving target's scene parks its
            neighbours out of reach, see `moving`).

    Raises:
        ValueError: naming the bad value and the allowed region (NaN or infinite values, a
            wrong shape, a centre off the reachable region, two objects too close, rows out
            of left-to-right order).
    """
    arr = np.asarray(placement, dtype=np.float64)
    if arr.ndim < 2 or arr.shape[-2:] not in ((3, 2), (3, 3)):
        raise ValueError(f"{field}: expected shape [3, 2] (x, y) or [3, 3] (x, y, yaw) for the "
                         f"left, middle and right object, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{field}: values must be finite numbers, got {arr.tolist()}")
    xy = arr[..., :2]
    far = np.abs(xy) > TABLE_HALF
    if np.any(far):
        raise ValueError(f"{field}: {float(xy[far][0]):.4f} m lies off the table (|x|, |y| <= "
                         f"{TABLE_HALF} m); allowed: {region_text()}")
    for axis, (lo, hi), name in ((0, REACH_X, "x"), (1, REACH_Y, "y")):
        v = xy[..., list(reach), axis]
        bad = (v < lo - _TOL) | (v > hi + _TOL)
        if np.any(bad):
            raise ValueError(f"{field}: {name} = {float(v[bad][0]):.4f} m lies off the "
                             f"reachable region; allowed: {region_text()}")
    for i, j in ((0, 1), (0, 2), (1, 2)):
        d = np.linalg.norm(xy[..., i, :] - xy[..., j, :], axis=-1)
        if np.any(d < MIN_SPACING - _TOL):
            raise ValueError(f"{field}: objects {i} and {j} overlap or nearly so (centres "
                             f"{float(np.min(d)):.4f} m apart); allowed: {region_text()}")
    if np.any(np.diff(xy[..., 1], axis=-1) < 0):
        raise ValueError(f"{field}: rows must be ordered left, middle, right (increasing y), "
                         f"got y = {xy[..., 1].tolist()}")
    if arr.shape[-1] == 2:
        arr = np.concatenate([arr, np.zeros((*arr.shape[:-1], 1))], axis=-1)
    return arr.astype(np.float32)


@jax.jit
def sample(key: jax.Array) -> jax.Array:
    """A random placement ``[3, 3]``: centres uniform over the region given the spacing
    (rejection among `CANDIDATES` uniform triples), ranked left to right, yaw uniform
    in [0, 2 pi). Pure and ``vmap``-able.
    """
    k_xy, k_yaw = jax.random.split(key)
    lo = jnp.array([REACH_X[0], REACH_Y[0]], jnp.float32)
    hi = jnp.array([REACH_X[1], REACH_Y[1]], jnp.float32)
    xy = jax.random.uniform(k_xy, (CANDIDATES, 3, 2), jnp.float32, lo, hi)
    d = jnp.linalg.norm(xy[:, :, None] - xy[:, None, :], axis=-1)
    ok = jnp.all((d >= MIN_SPACING) | jnp.eye(3, dtype=bool), axis=(1, 2))
    pick = jnp.argmax(ok)
    chosen = jnp.where(ok[pick], xy[pick], jnp.asarray(fixed()[:, :2]))
    chosen = chosen[jnp.argsort(chosen[:, 1])]
    yaw = jax.random.uniform(k_yaw, (3, 1), jnp.float32, 0.0, 2.0 * jnp.pi)
    return jnp.concatenate([chosen, yaw], axis=1)


def free_joint_qpos(placement: jax.Array) -> jax.Array:
    """Resting free-joint qpos ``[3 slots, 7]`` (position, quaternion) of a placement."""
    z = jnp.full((3, 1), scene.TABLE_Z + scene.OBJECT_HALF, jnp.float32)
    half = 0.5 * placement[:, 2:3]
    zeros = jnp.zeros_like(half)
    quat = jnp.concatenate([jnp.cos(half), zeros, zeros, jnp.sin(half)], axis=1)
    return jnp.concatenate([placement[:, :2], z, quat], axis=1)


def normalise(xy: jax.Array) -> jax.Array:
    """Table coordinates (metres, ``[..., 2]``) -> [-1, 1] over the reachable region (the
    actor's target units in the ``"free"`` task set)."""
    lo = jnp.array([REACH_X[0], REACH_Y[0]], jnp.float32)
    hi = jnp.array([REACH_X[1], REACH_Y[1]], jnp.float32)
    return 2.0 * (xy - lo) / (hi - lo) - 1.0


def population(xy: jax.Array, grid: tuple[int, int]) -> jax.Array:
    """Table coordinates (metres, ``[2]``) as a population code: a Gaussian bump (width one
    grid spacing, in units scaled to [-1, 1] over the reachable region) at each of the
    ``grid[0] x grid[1]`` centres spread evenly over the region, flattened x-major."""
    u = normalise(xy)
    cx, cy = jnp.linspace(-1.0, 1.0, grid[0]), jnp.linspace(-1.0, 1.0, grid[1])
    wx, wy = 2.0 / (grid[0] - 1), 2.0 / (grid[1] - 1)
    bx = jnp.exp(-0.5 * ((u[0] - cx) / wx) ** 2)
    by = jnp.exp(-0.5 * ((u[1] - cy) / wy) ** 2)
    return (bx[:, None] * by[None, :]).ravel()


def target_units(xy: jax.Array, target_obs: str) -> jax.Array:
    """The actor's target units for table coordinates ``xy`` (metres, ``[2]``):
    `normalise` for ``target_obs="xy"``, `population` on
    ``tasks.POPULATION_GRID`` for ``"population"`` (see `tasks.TaskSet`)."""
    if target_obs == "population":
        return population(xy, tasks.POPULATION_GRID)
    if target_obs == "xy":
        return normalise(xy)
    raise ValueError(f"target_obs: {target_obs!r} has no coordinates; accepted values: "
                     f"'xy', 'population'")


# ------------------------------------------------------------- the pose maps (point, touch, push)
POINTING_MAP = scene.ASSETS / "pointing_map.npz"
TOUCH_MAP = scene.ASSETS / "touch_map.npz"
PUSH_MAP = scene.ASSETS / "push_map.npz"


@functools.cache
def _load_map(path: str) -> dict[str, np.ndarray]:
    with np.load(path) as f:
        return {k: f[k] for k in f.files}


def pointing_map() -> dict[str, np.ndarray]:
    """The pointing poses solved on a 1 cm grid over the region and a 1 cm margin
    (``assets/make_pointing_map.py``): ``x`` [nx], ``y`` [ny], ``joints`` [nx, ny, 4]
    (radians; a cubic fit to the searched poses, which zigzag: ``raw_joints``), ``aim_deg``
    [nx, ny] (how far the palm's normal misses the object's centre)."""
    return _load_map(str(POINTING_MAP))


def touch_map() -> dict[str, np.ndarray]:
    """The touching poses on the pointing map's grid (``assets/make_touch_map.py``): ``x``
    [nx], ``y`` [ny], ``joints`` [nx, ny, 4] (radians: the palm pressed ``TOUCH_DEPTH`` into
    the top face of an object standing at the node, palm as far down as four joints allow),
    ``reach_error`` [nx, ny] (metres the palm site stays from that point: > 0 where the
    arm cannot get that low)."""
    return _load_map(str(TOUCH_MAP))


def push_map() -> dict[str, np.ndarray]:
    """The pushing poses on the pointing map's grid (``assets/make_touch_map.py --action
    push``): ``x``, ``y``, ``joints`` [nx, ny, 4] (radians: the palm site ``offset`` from the
    centre of an object standing at the node -- 1 cm toward the robot, 0.5 cm up: at its near
    face, pushed 1.5-2.5 cm), ``reach_error`` [nx, ny] (metres)."""
    return _load_map(str(PUSH_MAP))


def _interpolate(m: dict[str, np.ndarray], xy: jax.Array) -> jax.Array:
    """Bilinear interpolation of a pose map's four nodes around ``xy`` (clamped at the map's
    border)."""
    gx, gy = jnp.asarray(m["x"]), jnp.asarray(m["y"])
    joints = jnp.asarray(m["joints"])
    fx = jnp.clip((xy[0] - gx[0]) / (gx[1] - gx[0]), 0.0, gx.shape[0] - 1.0)
    fy = jnp.clip((xy[1] - gy[0]) / (gy[1] - gy[0]), 0.0, gy.shape[0] - 1.0)
    i = jnp.minimum(jnp.floor(fx).astype(jnp.int32), gx.shape[0] - 2)
    j = jnp.minimum(jnp.floor(fy).astype(jnp.int32), gy.shape[0] - 2)
    tx, ty = fx - i, fy - j
    return ((1 - tx) * (1 - ty) * joints[i, j] + tx * (1 - ty) * joints[i + 1, j]
            + (1 - tx) * ty * joints[i, j + 1] + tx * ty * joints[i + 1, j + 1])


def pointing_pose(xy: jax.Array) -> jax.Array:
    """The pointing pose (radians, ``[4]``) for an object at ``xy`` (metres): bilinear
    interpolation of the map's four surrounding nodes (clamped at the map's border). Pure,
    ``jit``- and ``vmap``-able."""
    return _interpolate(pointing_map(), xy)


def touch_pose(xy: jax.Array) -> jax.Array:
    """The touching pose (radians, ``[4]``) for an object at ``xy`` (metres), interpolated in
    `touch_map` as `pointing_pose` is. Pure, ``jit``- and ``vmap``-able."""
    return _interpolate(touch_map(), xy)


def push_pose(xy: jax.Array) -> jax.Array:
    """The pushing pose (radians, ``[4]``) for an object at ``xy`` (metres), interpolated in
    `push_map` as `pointing_pose` is. Pure, ``jit``- and ``vmap``-able."""
    return _interpolate(push_map(), xy)


# ------------------------------------------------------------------------ a moving target
def moving(key: jax.Array, speed: Any) -> tuple[jax.Array, jax.Array]:
    """A scene for a target that slides: ``(placement [3, 3], velocity [2])``.

    The target (the left slot) starts at a random x in the region and y within 2 cm of the
    region's left edge and slides right (+y) at ``speed`` m/s until the region's right edge
    (``Env.step`` stops it there): 20-22 cm of path. Its neighbours are parked out of reach
    (`PARKED`), so the arm that follows it meets nothing on the way. Pure and
    ``vmap``-able over keys and speeds.
    """
    k_x, k_y, k_yaw = jax.random.split(key, 3)
    x = jax.random.uniform(k_x, (), jnp.float32, REACH_X[0], REACH_X[1])
    y = jax.random.uniform(k_y, (), jnp.float32, REACH_Y[0], REACH_Y[0] + 0.02)
    parked = jnp.asarray(PARKED, jnp.float32)
    rows = jnp.concatenate([jnp.stack([x, y])[None], parked])
    yaw = jax.random.uniform(k_yaw, (3, 1), jnp.float32, 0.0, 2.0 * jnp.pi)
    placement = jnp.concatenate([rows, yaw], axis=1)
    return placement, jnp.stack([jnp.zeros((), jnp.float32), jnp.asarray(speed, jnp.float32)])
