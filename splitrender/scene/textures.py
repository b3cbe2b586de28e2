"""Deterministic procedural textures (sRGB uint8, HxWx3) that stress video codecs."""

from __future__ import annotations

import numpy as np


def checker(size: int = 256, tiles: int = 8, a=(200, 200, 200), b=(60, 60, 70)) -> np.ndarray:
    y, x = np.mgrid[0:size, 0:size]
    m = ((x * tiles // size) + (y * tiles // size)) % 2
    out = np.where(m[..., None] == 0, np.array(a, np.uint8), np.array(b, np.uint8))
    return out.astype(np.uint8)


def bricks(size: int = 256, rows: int = 8, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    h = size / rows
    row = (y // h).astype(int)
    xo = x + (row % 2) * h
    mortar = ((y % h) < 3) | ((xo % (2 * h)) < 3)
    tint = rng.uniform(0.75, 1.1, size=(rows + 1, 2 * rows + 2))
    t = tint[row, (xo // (2 * h)).astype(int) % (2 * rows + 2)]
    noise = rng.normal(0, 10, (size, size))
    base = np.stack([150 * t + noise, 70 * t + noise * 0.6, 50 * t + noise * 0.4], -1)
    base[mortar] = (190, 185, 175)
    return np.clip(base, 0, 255).astype(np.uint8)


def noise_stripes(size: int = 256, seed: int = 2, color=(70, 120, 190)) -> np.ndarray:
    """High-frequency noise with fine stripes: hard for block-based codecs."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    stripes = 0.5 + 0.5 * np.sin(x / size * 2 * np.pi * 24)
    n = rng.uniform(-40, 40, (size, size))
    c = np.array(color, np.float64)
    img = c[None, None, :] * (0.6 + 0.4 * stripes[..., None]) + n[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def text_panel(size: int = 256, seed: int = 3) -> np.ndarray:
    """Dark panel with small light glyph-like marks (fine detail, like signage or text)."""
    rng = np.random.default_rng(seed)
    img = np.full((size, size, 3), (30, 34, 40), np.uint8)
    cell = 8
    for r in range(2, size // cell - 2):
        if r % 3 == 0:
            continue
        for c in range(2, size // cell - 2):
            if rng.random() < 0.7:
                pat = rng.random((cell - 2, cell - 2)) < 0.45
                ys, xs = r * cell + 1, c * cell + 1
                img[ys : ys + cell - 2, xs : xs + cell - 2][pat] = (235, 230, 200)
    return img
