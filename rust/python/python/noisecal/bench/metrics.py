"""Image metrics on packed normalised raw (numpy): PSNR, SSIM (Wang et al. 2004), both per
brightness band of the clean level, and the mean/spread summary over training seeds."""

from __future__ import annotations

import math

import numpy as np

# Brightness bands by the clean level, normalised to [0, 1] between black and white.
BANDS = (("dark", 0.0, 0.02), ("shadow", 0.02, 0.1), ("mid", 0.1, 0.4), ("bright", 0.4, math.inf))


def psnr(pred: np.ndarray, ref: np.ndarray, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB: 10·log10(range² / MSE); inf for identical images."""
    mse = float(np.mean((np.asarray(pred, np.float64) - np.asarray(ref, np.float64)) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(data_range**2 / mse)


def _gauss_filter(x: np.ndarray, size: int = 11, sigma: float = 1.5) -> np.ndarray:
    """'Valid' separable Gaussian filtering of the last two axes."""
    k = np.exp(-0.5 * ((np.arange(size) - (size - 1) / 2) / sigma) ** 2)
    k /= k.sum()
    v = np.lib.stride_tricks.sliding_window_view(x, size, axis=-2)
    x = np.tensordot(v, k, axes=([-1], [0]))
    h = np.lib.stride_tricks.sliding_window_view(x, size, axis=-1)
    return np.tensordot(h, k, axes=([-1], [0]))


def ssim_map(pred: np.ndarray, ref: np.ndarray, data_range: float = 1.0) -> np.ndarray:
    """The SSIM map of Wang et al. (2004) with their constants (11×11 Gaussian window, σ 1.5,
    K1 0.01, K2 0.03) over the last two axes, on the 'valid' region (5 px cropped per side)."""
    x = np.asarray(pred, np.float64)
    y = np.asarray(ref, np.float64)
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mx, my = _gauss_filter(x), _gauss_filter(y)
    sxx = _gauss_filter(x * x) - mx * mx
    syy = _gauss_filter(y * y) - my * my
    sxy = _gauss_filter(x * y) - mx * my
    return ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))


def ssim(pred: np.ndarray, ref: np.ndarray, data_range: float = 1.0) -> float:
    """Mean SSIM (channels of a packed image each filtered on their own)."""
    return float(np.mean(ssim_map(pred, ref, data_range)))


def band_masks(clean_norm: np.ndarray) -> dict:
    """Per brightness band, the mask of packed pixels whose clean level falls in it."""
    return {name: (clean_norm >= lo) & (clean_norm < hi) for name, lo, hi in BANDS}


# Region types by the clean image's local variation (``region_masks``).
REGIONS = ("flat", "edge")


def region_masks(clean_norm: np.ndarray, tolerance: float, radius: int = 2) -> dict:
    """Per region type, the mask of packed pixels: ``flat`` where the clean image varies by at
    most ``tolerance`` (normalised units) over the (2·radius + 1)² window of its packed channel
    (edges replicated), ``edge`` the rest — the band along edges, about ``radius`` packed pixels
    either side, and any texture. Flat interiors reward smoothing; edge bands punish it."""
    c = np.asarray(clean_norm, np.float64)
    r = radius
    p = np.pad(c, ((0, 0), (r, r), (r, r)), mode="edge")
    h, w = c.shape[1:]
    hi, lo = c.copy(), c.copy()
    for dy in range(2 * r + 1):
        for dx in range(2 * r + 1):
            v = p[:, dy : dy + h, dx : dx + w]
            np.maximum(hi, v, out=hi)
            np.minimum(lo, v, out=lo)
    flat = hi - lo <= tolerance
    return {"flat": flat, "edge": ~flat}


def score(preds: list[np.ndarray], cleans: list[np.ndarray], flat_tolerance: float | None = None) -> dict:
    """PSNR (mean over images) and SSIM (mean) of packed normalised predictions, and per brightness
    band the PSNR of the pooled squared error and the mean SSIM over the band's pixels. With
    ``flat_tolerance``, also per region type (:func:`region_masks`: flat interior, edge band) the
    PSNR of the pooled squared error and the region's share of the pixels (``regions``)."""
    ps, ss = [], []
    sq = {b[0]: [0.0, 0] for b in BANDS}
    sm = {b[0]: [0.0, 0] for b in BANDS}
    rq = {name: [0.0, 0] for name in REGIONS}
    for p, c in zip(preds, cleans):
        ps.append(psnr(p, c))
        m = ssim_map(p, c)
        ss.append(float(m.mean()))
        err = (p.astype(np.float64) - c) ** 2
        masks = band_masks(c)
        for name, mask in masks.items():
            sq[name][0] += float(err[mask].sum())
            sq[name][1] += int(mask.sum())
            mv = mask[..., 5:-5, 5:-5]
            sm[name][0] += float(m[mv].sum())
            sm[name][1] += int(mv.sum())
        if flat_tolerance is not None:
            for name, mask in region_masks(c, flat_tolerance).items():
                rq[name][0] += float(err[mask].sum())
                rq[name][1] += int(mask.sum())
    bands = {}
    for name, *_ in BANDS:
        if sq[name][1]:
            mse = sq[name][0] / sq[name][1]
            bands[name] = {
                "psnr": math.inf if mse == 0 else 10 * math.log10(1 / mse),
                "ssim": sm[name][0] / sm[name][1] if sm[name][1] else None,
                "fraction": sq[name][1] / sum(v[1] for v in sq.values()),
            }
    out = {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "bands": bands}
    if flat_tolerance is not None:
        total = sum(v[1] for v in rq.values())
        out["regions"] = {
            name: {"psnr": math.inf if v[0] == 0 else 10 * math.log10(v[1] / v[0]), "fraction": v[1] / total}
            for name, v in rq.items()
            if v[1]
        }
    return out


def summarise(values: list[float]) -> dict:
    """Mean, sample standard deviation (0 for one value), min and max."""
    v = np.asarray(values, dtype=np.float64)
    return {
        "mean": float(v.mean()),
        "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
        "min": float(v.min()),
        "max": float(v.max()),
        "n": len(v),
    }
