"""Resampling colour planes for a stream's resolution scale (``--adapt full``, :mod:`splitrender.pipeline.adapt`).

A server that lowers a stream's resolution codes a smaller picture; the client brings each decoded picture back to
the size the session declared, so the method's client half never sees the difference.  Both directions are one
separable linear filter, written as two small matrices (rows, then columns): a tent whose support widens with the
ratio when shrinking (so shrinking averages, as an area filter does, instead of aliasing) and plain bilinear
interpolation when enlarging, sample centres aligned (half-pixel convention, as OpenGL and FFmpeg's swscale).
"""

from __future__ import annotations

import functools

import numpy as np

from ..errors import CodecError

MIN_SCALE = 0.25
"""The smallest picture a client accepts, as a fraction of the declared width and height."""


def scaled_size(width: int, height: int, scale: float) -> tuple[int, int]:
    """The coded size of a ``width`` x ``height`` stream at ``scale`` (each side rounded to an even number, at least 2)."""
    if not MIN_SCALE <= scale <= 1.0:
        raise ValueError(f"resolution scale {scale} is not in [{MIN_SCALE}, 1]")
    return max(2, 2 * round(width * scale / 2)), max(2, 2 * round(height * scale / 2))


@functools.lru_cache(maxsize=64)
def _weights(n_out: int, n_in: int) -> np.ndarray:
    """The (n_out, n_in) matrix taking n_in samples to n_out (rows sum to 1; samples beyond an edge repeat it)."""
    ratio = n_in / n_out
    support = max(1.0, ratio)                              # tent half-width in input samples
    centres = (np.arange(n_out) + 0.5) * ratio - 0.5       # output sample centres in input coordinates
    reach = int(np.ceil(support)) + 1
    x = np.floor(centres)[:, None] + np.arange(-reach, reach + 1)[None, :]     # taps about each centre
    t = np.maximum(0.0, 1.0 - np.abs(x - centres[:, None]) / support)
    w = np.zeros((n_out, n_in), np.float64)
    rows = np.broadcast_to(np.arange(n_out)[:, None], x.shape)
    np.add.at(w, (rows, np.clip(x, 0, n_in - 1).astype(int)), t)
    w /= w.sum(axis=1, keepdims=True)
    return w.astype(np.float32)


def resize(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """``img`` (H, W) or (H, W, C), uint8, resampled to ``height`` x ``width`` (uint8, rounded)."""
    if img.ndim not in (2, 3) or img.dtype != np.uint8:
        raise CodecError(f"resize: expected an (H, W[, C]) uint8 image, got {img.dtype} {img.shape}")
    h, w = img.shape[:2]
    if (w, h) == (width, height):
        return img
    wy, wx = _weights(height, h), _weights(width, w)
    f = img.astype(np.float32)
    if f.ndim == 2:
        out = wy @ f @ wx.T
    else:    # rows, then columns: two matrix products (BLAS), channels last kept
        out = np.tensordot(np.tensordot(wy, f, axes=(1, 0)), wx, axes=(1, 1)).transpose(0, 2, 1)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def is_scaled(width: int, height: int, declared_w: int, declared_h: int) -> bool:
    """Whether a decoded ``width`` x ``height`` picture is the declared size at some resolution scale in
    [:data:`MIN_SCALE`, 1], its aspect kept within the rounding of :func:`scaled_size`."""
    return (MIN_SCALE * declared_w - 2 <= width <= declared_w and MIN_SCALE * declared_h - 2 <= height <= declared_h
            and abs(width / declared_w * declared_h - height) <= 2.0 + 1e-9)
