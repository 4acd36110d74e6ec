"""What the robot sees: the eye camera image and the paper's OpenCV pipeline to a 60x20 bitmap.

Rendering is headless through EGL (or OSMesa), chosen here at call time, so it works whatever
``MUJOCO_GL`` was when ``mujoco`` was imported. ``GROUNDING_JAX_GL`` (or ``MUJOCO_GL``) picks
the backend; by default EGL is tried first, then OSMesa.

The pipeline (paper, section 2.1 and Fig 4), each step a small pure function:
1. :func:`to_black_and_white` -- grey, then Otsu threshold: objects black on a white table;
2. :func:`crop_group` -- the bounding box of all three objects together (plus a margin);
3. :func:`invert` -- objects white on black;
4. :func:`edges` -- the outline of each white region (morphological gradient);
5. :func:`to_bitmap` -- resize to 60 x 20 and binarise: 1200 values in {0, 1}.
"""

from __future__ import annotations

import copy
import functools
import os

import cv2
import mujoco
import numpy as np

from grounding_jax import scene

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
    """Offscreen renderer of the ``eye`` camera (robot meshes and helpers hidden)."""

    def __init__(self, width: int = WIDTH, height: int = HEIGHT) -> None:
        self.width, self.height = width, height
        self.model = copy.copy(scene.model())  # private copy: colours are set per layout
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
        self._cam.fixedcamid = self.model.camera("eye").id
        self._rect = mujoco.MjrRect(0, 0, width, height)

    def render(self, layout: int) -> np.ndarray:
        """RGB image ``[height, width, 3]`` uint8 of ``layout`` with the arm at home."""
        m, d = self.model, self.data
        shapes, colours = scene.LAYOUTS[layout]
        for shape, colour in zip(shapes, colours, strict=True):
            m.geom_rgba[m.geom(f"{shape}_geom").id] = scene.COLOUR_RGBA[colour]
        d.qpos[:] = scene.place_objects(scene.home_qpos(), layout)
        mujoco.mj_forward(m, d)
        self._ctx.make_current()
        mujoco.mjv_updateScene(m, d, self._opt, None, self._cam, mujoco.mjtCatBit.mjCAT_ALL,
                               self._scn)
        mujoco.mjr_render(self._rect, self._scn, self._mjr)
        rgb = np.empty((self.height, self.width, 3), np.uint8)
        mujoco.mjr_readPixels(rgb, None, self._rect, self._mjr)
        return np.flipud(rgb).copy()

    def close(self) -> None:
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


def to_bitmap(edge_img: np.ndarray) -> np.ndarray:
    """Resize to 60 x 20 (area average) and binarise: ``[1200]`` float32 in {0, 1}."""
    small = cv2.resize(edge_img.astype(np.float32), (BITMAP_W, BITMAP_H),
                       interpolation=cv2.INTER_AREA)
    return (small > 0.0).astype(np.float32).reshape(BITMAP_SIZE)


def bitmap_from_image(rgb: np.ndarray) -> np.ndarray:
    """The whole pipeline: RGB camera image -> ``[1200]`` edge bitmap."""
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"image: expected an RGB image [H, W, 3], got shape {rgb.shape}")
    return to_bitmap(edges(invert(crop_group(to_black_and_white(rgb)))))
