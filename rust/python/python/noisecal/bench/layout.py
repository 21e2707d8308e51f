"""Raw layout: a CFA mosaic packed into 4 channels (one per CFA position), normalised between
black and white, and back; per-position images; mosaicing an RGB scene for a CFA (numpy)."""

from __future__ import annotations

import numpy as np

from .errors import BenchError


def pack_raw(raw: np.ndarray) -> np.ndarray:
    """(H, W) mosaic → (4, H/2, W/2), channel ``p`` = CFA position ``p`` = (row % 2)·2 + col % 2,
    the core's order (so the pack's per-position black levels apply channel by channel)."""
    if raw.ndim != 2 or raw.shape[0] % 2 or raw.shape[1] % 2:
        raise BenchError(f"a raw mosaic of even height and width is needed, got shape {raw.shape}")
    return np.stack([raw[0::2, 0::2], raw[0::2, 1::2], raw[1::2, 0::2], raw[1::2, 1::2]])


def unpack_raw(packed: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pack_raw`."""
    c, h, w = packed.shape
    if c != 4:
        raise BenchError(f"4 packed channels are needed, got {c}")
    out = np.empty((2 * h, 2 * w), dtype=packed.dtype)
    out[0::2, 0::2], out[0::2, 1::2], out[1::2, 0::2], out[1::2, 1::2] = packed
    return out


def normalise(raw: np.ndarray, black, white: float) -> np.ndarray:
    """Packed float32 in units of the range above black: (x − black[p]) / (white − black[p])."""
    b = np.asarray(black, dtype=np.float64).reshape(4, 1, 1)
    return ((pack_raw(np.asarray(raw, dtype=np.float64)) - b) / (white - b)).astype(np.float32)


def per_position(values, shape) -> np.ndarray:
    """A (H, W) float64 image holding ``values[p]`` at every pixel of CFA position ``p``."""
    v = np.asarray(values, dtype=np.float64).reshape(4, 1, 1)
    return unpack_raw(np.broadcast_to(v, (4, shape[0] // 2, shape[1] // 2)).copy())


def mosaic(rgb: np.ndarray, cfa: str) -> np.ndarray:
    """(H, W, 3) → (H, W) keeping each pixel's CFA colour (``cfa``: "RGGB", "GRBG", "GBRG", "BGGR")."""
    idx = {"R": 0, "G": 1, "B": 2}
    cfa = cfa.upper()
    if len(cfa) != 4 or any(c not in idx for c in cfa):
        raise BenchError(f"unknown CFA {cfa!r}: use RGGB, GRBG, GBRG or BGGR")
    out = np.empty(rgb.shape[:2], dtype=rgb.dtype)
    for p, c in enumerate(cfa):
        out[p // 2 :: 2, p % 2 :: 2] = rgb[p // 2 :: 2, p % 2 :: 2, idx[c]]
    return out
