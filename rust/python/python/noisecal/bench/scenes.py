"""The built-in clean training images: natural-statistics scenes (dead leaves) mosaiced for a
pack's CFA, channel gains and black/white levels (``--generate``, ``--generate-levels``, ``--mono``),
or grey tile scenes (``--tiles``: a few large flat regions, edges blurred as by a lens), the kind of
the real-data benchmark's tiled evaluation scenes (tests/bench/emva1288.py, ``--scenes tiles``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from .errors import BenchError
from .layout import mosaic, per_position


def dead_leaves(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """A natural-statistics RGB scene (H, W, 3) in [0, 1]: opaque discs front to back, radii with
    density ∝ r⁻³ (1.5 px … a quarter of the larger side), log-uniform luminance over 0.004 … 0.9,
    random chroma, under a smooth illumination gradient of up to 2 stops (as ``Chart::natural``)."""
    img = np.zeros((height, width, 3))
    covered = np.zeros((height, width), dtype=bool)
    rmin, rmax = 1.5, max(2.0, max(height, width) / 4)
    a, b = rmin**-2, rmax**-2
    yy, xx = np.mgrid[0:height, 0:width] + 0.5
    for _ in range(20000):
        if covered.all():
            break
        r = (a - rng.random() * (a - b)) ** -0.5
        cx, cy = rng.random() * (width + 2 * r) - r, rng.random() * (height + 2 * r) - r
        lum = math.exp(math.log(0.004) + rng.random() * math.log(0.9 / 0.004))
        chroma = 0.6 + 0.8 * rng.random(3)
        color = np.minimum(lum * chroma / chroma.mean(), 1.0)
        y0, y1 = max(0, int(cy - r)), min(height, int(cy + r) + 1)
        x0, x1 = max(0, int(cx - r)), min(width, int(cx + r) + 1)
        if y0 >= y1 or x0 >= x1:
            continue
        disc = ((yy[y0:y1, x0:x1] - cy) ** 2 + (xx[y0:y1, x0:x1] - cx) ** 2 <= r * r) & ~covered[y0:y1, x0:x1]
        img[y0:y1, x0:x1][disc] = color
        covered[y0:y1, x0:x1] |= disc
    g = rng.random(2) * 2 - 1
    norm = max(abs(g).sum(), 1e-9)
    e = 2 * ((g[0] * xx / width + g[1] * yy / height) - np.maximum(g, 0).sum()) / norm
    return img * np.exp2(e)[..., None]


def generate_clean(
    n: int,
    height: int,
    width: int,
    layout: Mapping[str, Any],
    seed: int,
    mono: bool = False,
    levels: tuple[float, float] | None = None,
) -> list[np.ndarray]:
    """``n`` clean raw images (uint16 DN, black included) of natural-statistics scenes mosaiced for
    the pack's CFA with lamp × channel gains (R, G, B) = (0.6, 1, 0.75), the brightest green at
    0.6 … 0.95 of the range and each image 0 … 3 EV darker in turn (low light included). ``mono``:
    grey scenes at gain 1 on every CFA position (a monochrome sensor read as a mosaic).
    ``levels`` (lo, hi) in DN above black: each scene's values spread linearly over that band
    instead (for a pack whose measured levels are a narrow band, e.g. calibrated on a flat field:
    outside its levels a non-parametric pack has no samples to draw from)."""
    rng = np.random.default_rng(seed)
    black = np.asarray(layout["black"], dtype=np.float64)
    white = float(layout["white"])
    out = []
    for i in range(n):
        rgb = dead_leaves(height, width, rng)
        rgb = rgb.mean(-1, keepdims=True).repeat(3, -1) if mono else rgb * np.array([0.6, 1.0, 0.75])
        raw = mosaic(rgb, layout["cfa"]) * (0.6 + 0.35 * rng.random()) / 2 ** (i % 4)
        b = per_position(black, (height, width))
        if levels is not None:
            lo, hi = levels
            v = np.clip(raw, 0, None)
            v = (v - v.min()) / max(float(v.max() - v.min()), 1e-12)
            out.append(np.rint(np.clip(b + lo + v * (hi - lo), 0, white)).astype(np.uint16))
            continue
        out.append(np.rint(np.clip(b + raw * (white - b), 0, white)).astype(np.uint16))
    return out


def tile_labels(height: int, width: int, tiles: int, rng: np.random.Generator) -> np.ndarray:
    """A map of ``tiles`` large regions (int, 0 … tiles − 1): the Voronoi cells of ``tiles``
    points uniform over the image, each pixel labelled by its nearest point. Cells average
    height·width/tiles pixels, convex, with straight edges at every angle."""
    pts = rng.random((tiles, 2)) * np.array([height, width])
    yy, xx = np.mgrid[0:height, 0:width] + 0.5
    best = np.zeros((height, width), dtype=np.int64)
    dist = np.full((height, width), np.inf)
    for i, (py, px) in enumerate(pts):
        d = (yy - py) ** 2 + (xx - px) ** 2
        closer = d < dist
        best[closer], dist[closer] = i, d[closer]
    return best


def gaussian_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """``img`` (H, W) filtered by a normalised Gaussian of ``sigma`` pixels (separable, radius
    ⌈3σ⌉, edges reflected); ``sigma`` 0 returns it unchanged. A lens's blur of an edge: a constant
    region stays constant, a step becomes a ramp over about ±2σ."""
    x = np.asarray(img, np.float64)
    if sigma <= 0:
        return x.copy()
    r = max(1, math.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    p = np.pad(x, r, mode="reflect")
    p = sum(k[i] * p[i : i + x.shape[0], :] for i in range(2 * r + 1))
    return sum(k[i] * p[:, i : i + x.shape[1]] for i in range(2 * r + 1))


def generate_tiles(
    n: int,
    height: int,
    width: int,
    layout: Mapping[str, Any],
    seed: int,
    tiles: int,
    blur: float,
    levels: tuple[float, float],
    ladder: list[float] | None = None,
    texture: tuple[float, float] = (0.0, 0.0),
    rounded: bool = True,
) -> list[np.ndarray]:
    """``n`` clean raw images (uint16 DN, black included) of grey tile scenes (``--tiles``): the
    :func:`tile_labels` map of ``tiles`` regions, each region one level uniform over ``levels``
    (lo, hi DN above black), blurred by :func:`gaussian_blur` of ``blur`` pixels, at gain 1 on
    every CFA position (a monochrome sensor read as a mosaic). The training scenes of the real-data
    benchmark's tiled evaluation mosaics: the same kind of regions and edges, other levels and
    shapes (their own seed).

    ``ladder`` (DN above black): the evaluation set's levels: each region takes one of them, and
    each blurred pixel the ladder level nearest it, as the tiled evaluation scenes are made (their
    edges are stairs of real levels, not smooth ramps). ``texture`` (t0, t1): a fixed pattern of
    white Gaussian texture with SD ``t0 + t1·level`` DN added to the clean image, as the real clean
    images (a burst's mean) carry the sensor's DSNU and PRNU, which a denoiser must keep.

    ``rounded=False``: the same scenes as float64 DN before the rounding to whole DN (a simulated
    sensor's captures are drawn about these, as real frames are about the scene's true level)."""
    rng = np.random.default_rng(seed)
    lo, hi = levels
    white = float(layout["white"])
    b = per_position(np.asarray(layout["black"], dtype=np.float64), (height, width))
    steps = None if not ladder else np.sort(np.asarray(ladder, dtype=np.float64))
    out = []
    for _ in range(n):
        lab = tile_labels(height, width, tiles, rng)
        if steps is None:
            v = gaussian_blur((lo + (hi - lo) * rng.random(tiles))[lab], blur)
        else:
            v = gaussian_blur(rng.choice(steps, tiles)[lab], blur)
            v = steps[np.argmin(np.abs(v[..., None] - steps), axis=-1)]
        t0, t1 = texture
        if t0 or t1:
            v = v + (t0 + t1 * np.clip(v, 0, None)) * rng.standard_normal(v.shape)
        scene = np.clip(b + v, 0, white)
        out.append(np.rint(scene).astype(np.uint16) if rounded else scene)
    return out


def parse_levels(text: str | None, layout: Mapping[str, Any]) -> tuple[float, float] | None:
    """``--generate-levels LO,HI`` (DN above black), checked against the pack's range."""
    if text is None:
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise BenchError(f"--generate-levels {text!r}: give LO,HI in DN above black, e.g. 1900,2060") from None
    top = float(layout["white"]) - max(layout["black"])
    if not 0 <= lo < hi <= top:
        raise BenchError(f"--generate-levels {text!r}: need 0 ≤ LO < HI ≤ {top:g} (white less black)")
    return lo, hi
