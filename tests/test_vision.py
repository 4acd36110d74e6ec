"""The OpenCV pipeline on synthetic images, the renderer, and the cached TL bitmaps."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from grounding_jax.sim import scene, tl_data, vision


def _white(h=240, w=320):
    return np.full((h, w, 3), 255, np.uint8)


def test_black_and_white_separates_dark_objects_from_a_light_table():
    img = _white()
    img[100:140, 200:260] = (30, 140, 30)
    bw = vision.to_black_and_white(img)
    assert bw[120, 230] == 0 and bw[10, 10] == 255
    assert (bw == 0).sum() == 40 * 60


def test_crop_group_is_the_bounding_box_of_all_objects_plus_margin():
    bw = np.full((240, 320), 255, np.uint8)
    bw[50:60, 40:50] = 0
    bw[120:150, 250:290] = 0
    crop = vision.crop_group(bw, margin=2)
    assert crop.shape == (150 - 50 + 4, 290 - 40 + 4)
    with pytest.raises(ValueError, match="image"):
        vision.crop_group(np.full((10, 10), 255, np.uint8))


def test_edges_of_a_filled_rectangle_are_its_outline():
    img = np.zeros((40, 60), np.uint8)
    img[10:30, 20:50] = 255
    e = vision.edges(img)
    assert e[10, 30] == 255 and e[29, 30] == 255 and e[20, 20] == 255 and e[20, 49] == 255
    assert e[20, 35] == 0  # interior
    assert e[2, 2] == 0  # far outside
    assert e[9, 30] == 255  # the gradient marks the ring just outside too


def test_pipeline_puts_the_right_objects_outline_in_the_right_third():
    img = _white()
    img[110:120, 20:30] = 0  # small left marker
    img[110:120, 150:160] = 0  # small middle marker
    img[100:140, 250:310] = (200, 20, 20)  # big filled rectangle on the right
    bm = vision.bitmap_from_image(img).reshape(20, 60)
    assert bm.shape == (20, 60) and set(np.unique(bm)) <= {0.0, 1.0}
    right = bm[:, 40:]
    # the rectangle spans the full crop height: its top and bottom edges are lit
    assert right[0].sum() > 10 and right[-1].sum() > 10
    assert right[5:15, 8:14].sum() == 0  # its inside is empty
    assert bm[:, 40:].sum() > bm[:, :20].sum()  # more outline on the right than the left


def test_pipeline_rejects_a_non_rgb_image():
    with pytest.raises(ValueError, match=r"image: expected an RGB image"):
        vision.bitmap_from_image(np.zeros((240, 320)))


def test_render_is_320x240_and_the_cache_matches_a_fresh_render(renderer):
    cached = tl_data.cached_bitmaps()
    for layout in (0, 13, 35):
        img = renderer.render(layout)
        assert img.shape == (240, 320, 3) and img.dtype == np.uint8
        np.testing.assert_array_equal(vision.bitmap_from_image(img), cached[layout])


def test_cached_bitmaps_separate_the_shape_orders():
    bm = tl_data.cached_bitmaps().astype(int)
    assert bm.shape == (36, 1200) and set(np.unique(bm)) <= {0, 1}
    order = np.arange(36) // 6  # layouts 6k..6k+5 share a shape order
    diff = np.abs(bm[:, None] - bm[None]).sum(-1)
    across = diff[order[:, None] != order[None]]
    within = diff[(order[:, None] == order[None]) & ~np.eye(36, dtype=bool)]
    # B&W conversion drops colour by design (colour reaches the TL through its own units):
    # colour orders of one shape order differ by at most a dozen shading pixels (measured 10;
    # a shade can shift the crop by a pixel), while different shape orders differ by over a
    # hundred (measured 121).
    assert across.min() >= 100
    assert within.max() <= 12


def test_each_positions_shape_is_recoverable_from_the_bitmap():
    bm = tl_data.cached_bitmaps().reshape(36, 20, 60).astype(np.uint8)
    seen: dict[tuple, str] = {}
    for i in range(36):
        n, _, stats, cent = cv2.connectedComponentsWithStats(bm[i], connectivity=8)
        comps = sorted(range(1, n), key=lambda k: cent[k][0])
        assert len(comps) == 3, f"layout {i}: {len(comps)} outlines"
        for pos, k in enumerate(comps):
            feature = (pos, *stats[k][[cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT, cv2.CC_STAT_AREA]])
            shape = scene.LAYOUTS[i][0][pos]
            assert seen.setdefault(tuple(int(v) for v in feature), shape) == shape


def test_no_gl_backend_gives_a_clear_error(monkeypatch):
    import sys

    monkeypatch.delenv("GROUNDING_JAX_GL", raising=False)
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.setitem(sys.modules, "mujoco.egl", None)  # importing it now fails
    monkeypatch.setitem(sys.modules, "mujoco.osmesa", None)
    with pytest.raises(RuntimeError, match=r"tried egl: .*; osmesa: .*libegl1.*libosmesa6"):
        vision._make_context(32, 32)
