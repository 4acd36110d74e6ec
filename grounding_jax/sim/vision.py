"""What the robot sees: the eye camera image and the paper's OpenCV pipeline to a 60x20 bitmap.

Rendering is headless through EGL (or OSMesa), chosen here at call time, so it works whatever
``MUJOCO_GL`` was when ``mujoco`` was imported. ``GROUNDING_JAX_GL`` (or ``MUJOCO_GL``) picks
the backend; by default EGL is tried first, then OSMesa.

The pipeline (paper, section 2.1 and Fig 4), each step a small pure function:
1. `to_black_and_white` -- grey, then Otsu threshold: objects black on a white table;
2. `crop_group` -- the bounding box of all three objects together (plus a margin);
3. `invert` -- objects white on black;
4. `edges` -- the outline of each white region (morphological gradient);
5. `to_bitmap` -- resize to 60 x 20 and binarise: 1200 values in {0, 1}.
"""

from __future__ import annotations

import copy
import functools
import os

import cv2
import mujoco
import numpy as np

from grounding_jax.sim import placement as free
from grounding_jax.sim import scene

WIDTH, HEIGHT = 320, 240
BITMAP_W, BITMAP_H = 60, 20
BITMAP_SIZE = BITMAP_W * BITMAP_H
GL_BACKENDS = ("egl", "osmesa")


# ------------------------------------------------------------------------------- rendering
def _gl_candidates() -> tuple[str, ...]:
    wanted = (os.environ.get("GROUNDING_JAX_GL") or os.environ.get("MUJOCO_GL") or "").lower()
    if wanted in GL_BACKENDS:
        return (wanted,)
    return GL_BACKENDS


def _make_context(width: int, height: int):
    errors = []
    for name in _gl_candidates():
        try:
            if name == "egl":
                from mujoco.egl import GLContext
            else:
                from mujoco.osmesa import GLContext
            ctx = GLContext(width, height)
            ctx.make_current()
            return ctx
        except Exception as e:  # noqa: BLE001 - any failure means: try the next backend
            errors.append(f"{name}: {type(e).__name__}: {e}")
    raise RuntimeError(
        "No headless OpenGL backend works here; tried "
        + "; ".join(errors)
        + ". Install EGL (Debian/Ubuntu: apt-get install libegl1) or OSMesa "
        "(apt-get install libosmesa6) and choose it with GROUNDING_JAX_GL=egl|osmesa."
    )


class EyeRenderer:
    """Offscreen renderer of a scene camera: by default the robot's ``eye`` (robot meshes and
    helpers hidden), or ``"observer"``, the third-person camera facing the robot (for people;
    see `grounding_jax.sim.render`)."""

    def __init__(self, width: int = WIDTH, height: int = HEIGHT, camera: str = "eye") -> None:
        cameras = tuple(scene.model().camera(i).name for i in range(scene.model().ncam))
        if camera not in cameras:
            raise ValueError(f"camera: unknown value {camera!r}; accepted values: {cameras}")
        self.width, self.height = width, height
        self.model = copy.copy(scene.model())  # private copy: colours are set per layout
        self.model.vis.global_.offwidth = max(width, self.model.vis.global_.offwidth)
        self.model.vis.global_.offheight = max(height, self.model.vis.global_.offheight)
        self.data = mujoco.MjData(self.model)
        self._ctx = _make_context(width, height)
        self._mjr = mujoco.MjrContext(self.model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._mjr)
        self._scn = mujoco.MjvScene(self.model, maxgeom=200)
        self._opt = mujoco.MjvOption()
        self._opt.geomgroup[:] = 0
        self._opt.geomgroup[0] = 1  # table and objects only: the arm is not in the bitmap
        self._opt.sitegroup[:] = 0
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._cam.fixedcamid = self.model.camera(camera).id
        self._rect = mujoco.MjrRect(0, 0, width, height)

    def render(self, layout: int, placement: np.ndarray | None = None,
               qpos: np.ndarray | None = None, arm: bool = False) -> np.ndarray:
        """RGB image ``[height, width, 3]`` uint8 of ``layout`` with the arm at home.

        Args:
            layout: which shape and colour stands in each slot (0..35).
            placement: ``None`` (the paper's slots) or a placement ``[3, 3]`` (see
                `grounding_jax.sim.placement`).
            qpos: a full physics ``qpos`` (e.g. a frame of an episode) to draw instead of
                the resting objects; ``layout`` still gives the colours.
            arm: draw the robot's meshes too (for people; the bitmaps never show the arm).
        """
        m, d = self.model, self.data
        scene.paint_layout(m, layout)
        if qpos is not None:
            d.qpos[:] = qpos
        else:
            if placement is not None:
                placement = free.check(placement)
            d.qpos[:] = scene.place_objects(scene.home_qpos(), layout, placement)
        mujoco.mj_forward(m, d)
        self._opt.geomgroup[2] = int(arm)  # the robot's visual meshes
        self._ctx.make_current()
        mujoco.mjv_updateScene(m, d, self._opt, None, self._cam, mujoco.mjtCatBit.mjCAT_ALL,
                               self._scn)
        mujoco.mjr_render(self._rect, self._scn, self._mjr)
        rgb = np.empty((self.height, self.width, 3), np.uint8)
        mujoco.mjr_readPixels(rgb, None, self._rect, self._mjr)
        return np.flipud(rgb).copy()

    def close(self) -> None:
        """Free the GL context and its buffers (the renderer cannot draw after this)."""
        self._mjr.free()
        self._ctx.free()


@functools.cache
def eye_renderer() -> EyeRenderer:
    """A process-wide renderer (made on first use)."""
    return EyeRenderer()


# -------------------------------------------------------------------------------- pipeline
def to_black_and_white(rgb: np.ndarray) -> np.ndarray:
    """Grey, then Otsu's threshold: 0 where darker than the threshold (objects), 255 else."""
    grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    _, bw = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    return bw


def crop_group(bw: np.ndarray, margin: int = 2) -> np.ndarray:
    """Crop to the bounding box of all black (object) pixels, plus ``margin`` pixels."""
    ys, xs = np.nonzero(bw == 0)
    if len(xs) == 0:
        raise ValueError("image: no object pixels found to crop")
    y0, y1 = max(ys.min() - margin, 0), min(ys.max() + margin + 1, bw.shape[0])
    x0, x1 = max(xs.min() - margin, 0), min(xs.max() + margin + 1, bw.shape[1])
    return bw[y0:y1, x0:x1]


def invert(bw: np.ndarray) -> np.ndarray:
    """Swap black and white."""
    return cv2.bitwise_not(bw)


def edges(img: np.ndarray) -> np.ndarray:
    """Outline of the white regions: morphological gradient with a 3x3 cross."""
    kernel = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    return cv2.morphologyEx(img, cv2.MORPH_GRADIENT, kernel)


def to_bitmap(edge_img: np.ndarray, size: tuple[int, int] = (BITMAP_W, BITMAP_H),
              binary: bool = True) -> np.ndarray:
    """Resize to ``size`` (width, height; the paper's 60 x 20) by area average and
    binarise: ``[width * height]`` float32 in {0, 1}; with ``binary=False`` the averaged
    edge level in [0, 1] is kept instead (where an edge falls inside a cell)."""
    small = cv2.resize(edge_img.astype(np.float32), size, interpolation=cv2.INTER_AREA)
    out = (small > 0.0).astype(np.float32) if binary else small / 255.0
    return out.reshape(size[0] * size[1])


def bitmap_from_image(rgb: np.ndarray, window: tuple[int, int, int, int] | None = None,
                      size: tuple[int, int] = (BITMAP_W, BITMAP_H), binary: bool = True
                      ) -> np.ndarray:
    """The whole pipeline: RGB camera image -> ``[1200]`` edge bitmap.

    Args:
        rgb: the camera image ``[H, W, 3]``.
        window: ``None`` crops to the objects' group (the paper: where the objects stand
            relative to each other); a fixed pixel window ``(x0, y0, x1, y1)`` (e.g.
            `table_window`) keeps where they stand on the table.
        size: the bitmap's (width, height).
        binary: binarise the bitmap (the paper) or keep grey edge levels (see
            `to_bitmap`).
    """
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"image: expected an RGB image [H, W, 3], got shape {rgb.shape}")
    bw = to_black_and_white(rgb)
    if window is None:
        bw = crop_group(bw)
    else:
        x0, y0, x1, y1 = window
        bw = bw[y0:y1, x0:x1]
    return to_bitmap(edges(invert(bw)), size, binary)


def project(points: np.ndarray, width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    """Pixel coordinates ``[..., 2]`` (column, row; row 0 at the top) of world points
    ``[..., 3]`` in the eye camera's image (a pinhole with MuJoCo's vertical field of view)."""
    m = scene.model()
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)  # the camera is fixed in the world: any pose will do
    cam = m.camera("eye").id
    rel = (np.asarray(points, float) - d.cam_xpos[cam]) @ d.cam_xmat[cam].reshape(3, 3)
    f = 0.5 * height / np.tan(np.radians(m.cam_fovy[cam]) / 2.0)
    depth = -rel[..., 2]  # the camera looks down its -z axis
    return np.stack([0.5 * width + f * rel[..., 0] / depth,
                     0.5 * height - f * rel[..., 1] / depth], axis=-1)


@functools.cache
def table_window(margin: int = 3) -> tuple[int, int, int, int]:
    """The fixed pixel window ``(x0, y0, x1, y1)`` that holds every object wherever the free
    placement puts it: the image of the reachable region's corners, widened by the objects'
    extent (a box's half-diagonal around, its height up) and ``margin`` pixels."""
    r = float(np.hypot(scene.OBJECT_HALF, scene.OBJECT_HALF))
    corners = [(x + dx, y + dy, scene.TABLE_Z + dz)
               for x in free.REACH_X for y in free.REACH_Y
               for dx in (-r, r) for dy in (-r, r) for dz in (0.0, 2 * scene.OBJECT_HALF)]
    uv = project(np.array(corners))
    x0, y0 = np.floor(uv.min(axis=0)).astype(int) - margin
    x1, y1 = np.ceil(uv.max(axis=0)).astype(int) + margin + 1
    return max(int(x0), 0), max(int(y0), 0), min(int(x1), WIDTH), min(int(y1), HEIGHT)
