"""The target localizer's data: 216 configurations = 36 layouts x 6 target words.

Each input is the 60x20 edge bitmap of the layout (1200 values) followed by the 9 colour units
(left/middle/right x red/green/blue) and the 6 target units (box, cylinder, sphere, red, green,
blue), those 15 repeated ``n`` times (paper: n = 20, 1500 inputs). The label is the position
(0 left, 1 middle, 2 right) of the named object.

The 36 bitmaps are rendered once and cached in ``assets/tl_bitmaps.npz``; regenerate with
``python -m grounding_jax.sim.tl_data --regenerate``.
"""

from __future__ import annotations

import argparse
import pathlib
from typing import NamedTuple

import numpy as np

from grounding_jax.core.checks import require_int
from grounding_jax.sim import scene, tasks

BITMAPS_NPZ = scene.ASSETS / "tl_bitmaps.npz"
TARGET_WORDS = tasks.TARGET_WORDS  # box, cylinder, sphere, red, green, blue
N_CONFIGS = len(scene.LAYOUTS) * len(TARGET_WORDS)  # 216


class TLData(NamedTuple):
    """The 216 configurations, in (layout, target word) order."""

    bitmaps: np.ndarray  # [216, 1200] float32 in {0, 1}
    symbols: np.ndarray  # [216, 15] float32: 9 colour + 6 target units (not replicated)
    labels: np.ndarray  # [216] int32: position of the named object
    layout: np.ndarray  # [216] int32
    word: np.ndarray  # [216] int32 index into TARGET_WORDS


def render_bitmaps() -> np.ndarray:
    """Render the 36 layouts with the eye camera and run the OpenCV pipeline: ``[36, 1200]``."""
    from grounding_jax.sim import vision

    renderer = vision.eye_renderer()
    return np.stack([vision.bitmap_from_image(renderer.render(i))
                     for i in range(len(scene.LAYOUTS))]).astype(np.uint8)


def cached_bitmaps() -> np.ndarray:
    """The cached ``[36, 1200]`` bitmaps (uint8 0/1) from ``assets/tl_bitmaps.npz``."""
    if not BITMAPS_NPZ.exists():
        raise FileNotFoundError(f"{BITMAPS_NPZ} is missing: run "
                                "`python -m grounding_jax.sim.tl_data --regenerate`")
    with np.load(BITMAPS_NPZ) as f:
        return f["bitmaps"]


def save_bitmaps(bitmaps: np.ndarray, path: pathlib.Path = BITMAPS_NPZ) -> None:
    """Write the cache atomically (a half-written file never replaces a good one)."""
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, bitmaps=bitmaps.astype(np.uint8))
    tmp.replace(path)


def word_index(word: str | int) -> int:
    """Index of a target word; ValueError naming the accepted words otherwise."""
    if isinstance(word, str) and word in TARGET_WORDS:
        return TARGET_WORDS.index(word)
    if isinstance(word, (int, np.integer)) and not isinstance(word, bool) and 0 <= word < 6:
        return int(word)
    raise ValueError(f"target word: unknown value {word!r}; accepted values: {TARGET_WORDS}")


def label_of(layout: int, word: int) -> int:
    """Position (0 L, 1 M, 2 R) of the object that ``TARGET_WORDS[word]`` names in a layout."""
    shapes, colours = scene.LAYOUTS[layout]
    name = TARGET_WORDS[word]
    return shapes.index(name) if name in scene.SHAPES else colours.index(name)


def symbol_units(layout: int, word: str | int) -> np.ndarray:
    """The 15 symbolic units of a configuration: colour (L/M/R x R/G/B) then target word."""
    word = word_index(word)
    if not 0 <= int(layout) < len(scene.LAYOUTS):
        raise ValueError(f"layout: index {layout} out of range; accepted: 0..35")
    _, colours = scene.LAYOUTS[layout]
    colour = np.zeros((3, 3), np.float32)
    for pos, c in enumerate(colours):
        colour[pos, scene.COLOURS.index(c)] = 1.0
    target = np.zeros(len(TARGET_WORDS), np.float32)
    target[word] = 1.0
    return np.concatenate([colour.reshape(9), target])


def load(bitmaps: np.ndarray | None = None) -> TLData:
    """All 216 configurations (bitmaps from the cache unless given)."""
    bm = cached_bitmaps() if bitmaps is None else bitmaps
    if bm.shape != (len(scene.LAYOUTS), 1200):
        raise ValueError(f"bitmaps: expected shape (36, 1200), got {bm.shape}")
    layouts, words = np.divmod(np.arange(N_CONFIGS), len(TARGET_WORDS))
    return TLData(
        bitmaps=bm[layouts].astype(np.float32),
        symbols=np.stack([symbol_units(lay, w) for lay, w in zip(layouts, words, strict=True)]),
        labels=np.array([label_of(lay, w) for lay, w in zip(layouts, words, strict=True)],
                        np.int32),
        layout=layouts.astype(np.int32),
        word=words.astype(np.int32),
    )


def inputs(data: TLData, n: int) -> np.ndarray:
    """Network inputs ``[216, 1200 + 15 n]``: bitmap, then the 15 symbolic units n times."""
    require_int("n (replication)", n, 1)
    return np.concatenate([data.bitmaps, np.tile(data.symbols, (1, n))], axis=1)


def split(key_seed: int, n_items: int = N_CONFIGS, train_fraction: float = 2 / 3
          ) -> tuple[np.ndarray, np.ndarray]:
    """Random 2/3 : 1/3 train/test split of the configurations (indices), from a seed."""
    perm = np.random.default_rng(key_seed).permutation(n_items)
    n_train = int(round(train_fraction * n_items))
    return np.sort(perm[:n_train]), np.sort(perm[n_train:])


def main() -> None:
    ap = argparse.ArgumentParser(description="Render and cache the 36 TL bitmaps.")
    ap.add_argument("--regenerate", action="store_true", help="render and overwrite the cache")
    args = ap.parse_args()
    if args.regenerate:
        bm = render_bitmaps()
        save_bitmaps(bm)
        print(f"wrote {BITMAPS_NPZ}: {bm.shape}, {int(bm.sum())} edge pixels in all")
    else:
        print(f"{BITMAPS_NPZ}: {cached_bitmaps().shape}; use --regenerate to re-render")


if __name__ == "__main__":
    main()
