"""A greyscale PNG reader for the EMVA 1288 data sets' frames (tests/bench/emva1288.py,
tests/bench/emva1288_ladder.py and tests/data/emva001/make_crop.py), written here rather than taken
from an image library: the sets' frames are one narrow case (16-bit grey for set 001, 8-bit grey
for set 002, no interlace, filter type 0 on every row) and numpy with the standard library's zlib
reads it in a few lines, where Pillow or pypng would be one more dependency for the bench's
users."""

from __future__ import annotations

import struct
import zlib

import numpy as np


class ConvertError(ValueError):
    """The data set is not what this script expects (the message names the file)."""


def read_png16(data: bytes, name: str) -> np.ndarray:
    """A 16-bit greyscale, non-interlaced PNG (filter type 0 on every row) as uint16 (H, W)."""
    return read_png_grey(data, name, depths=(16,))


def read_png_grey(data: bytes, name: str, depths: tuple[int, ...] = (8, 16)) -> np.ndarray:
    """An 8- or 16-bit (``depths``) greyscale, non-interlaced PNG (filter type 0 on every row) as
    uint16 (H, W), the samples unchanged."""
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ConvertError(f"{name}: not a PNG file")
    at, idat, head = 8, [], None
    while at < len(data):
        (n,) = struct.unpack(">I", data[at : at + 4])
        kind, body = data[at + 4 : at + 8], data[at + 8 : at + 8 + n]
        at += 12 + n
        if kind == b"IHDR":
            head = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
    if head is None:
        raise ConvertError(f"{name}: a PNG without its IHDR header")
    w, h, depth, colour, _, _, interlace = head
    if depth not in depths or (colour, interlace) != (0, 0):
        want = " or ".join(f"{d}-bit" for d in depths)
        raise ConvertError(f"{name}: a {depth}-bit PNG of colour type {colour}, interlace {interlace}: want {want} grey")
    size = depth // 8
    rows = np.frombuffer(zlib.decompress(b"".join(idat)), np.uint8).reshape(h, size * w + 1)
    if rows[:, 0].any():
        raise ConvertError(f"{name}: PNG row filters {sorted(set(rows[:, 0].tolist()))}; only filter 0 is read here")
    samples = rows[:, 1:].copy()
    return (samples.view(">u2") if size == 2 else samples).astype(np.uint16)
