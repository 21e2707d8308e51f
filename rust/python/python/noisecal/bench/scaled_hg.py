"""The HG controls: HG's noise with a scaled variance at every clean level, drawn as HG draws its
own (a Gaussian rounded to whole DN about the level, clamped to ``[0, white]``). ``wrong`` is
½ (a model that must score clearly worse), ``loud`` 2 (one that must score below HG).

Why not scale HG's drawn noise: HG's output is already whole DN, and ``round(m + (x − m)·√f)``
moves a ±1 DN draw to ±0.71 or ±1.41 DN, which round back to ±1. Where HG's noise is mostly 0 and
±1 DN (a variance below about 0.5 DN², the dark end of an 8-bit sensor such as EMVA 1288 set 002)
the earlier "half variance" kept 0.97–1.0 of HG's variance and the "twice" about 1.0, so neither
control differed from HG there (docs/bench.md, "The controls on set 002"). Here the rounded
Gaussian's own SD is chosen per table so that the *integer* noise has ``f`` times the variance of
HG's table at that level (:func:`rounded_gaussian_sd`)."""

from __future__ import annotations

import math

import numpy as np

# Above this variance (DN²) a rounded Gaussian about an integer has the variance s² + 1/12 to within
# 2·10⁻⁸ DN² (Sheppard's correction; the error falls as exp(−2π²s²), s ≥ 1.1 here).
SHEPPARD_FROM = 1.3


def rounded_variance(sd: np.ndarray) -> np.ndarray:
    """Variance of ``round(N(0, sd²))`` on the integers (exact sum over the cells)."""
    sd = np.maximum(np.asarray(sd, dtype=np.float64), 1e-12)
    top = int(math.ceil(8.0 * float(sd.max()) + 2.0))
    k = np.arange(1, top + 1, dtype=np.float64)
    erf = np.frompyfunc(math.erf, 1, 1)
    cdf = lambda x: 0.5 * (1.0 + erf(x / math.sqrt(2.0)).astype(np.float64))  # noqa: E731
    hi = cdf((k + 0.5) / sd[..., None])
    lo = cdf((k - 0.5) / sd[..., None])
    return 2.0 * ((hi - lo) * k * k).sum(axis=-1)


def rounded_gaussian_sd(var: np.ndarray) -> np.ndarray:
    """The SD ``s`` for which ``round(N(0, s²))`` has the integer variance ``var`` (DN², any
    non-negative value; 0 gives 0). Above :data:`SHEPPARD_FROM` it is ``√(var − 1/12)``; below,
    bisection on :func:`rounded_variance`, which rises from 0 with ``s``."""
    var = np.asarray(var, dtype=np.float64)
    out = np.sqrt(np.maximum(var - 1.0 / 12.0, 0.0))
    small = var < SHEPPARD_FROM
    if small.any():
        want = var[small]
        lo = np.zeros_like(want)
        hi = np.full_like(want, math.sqrt(SHEPPARD_FROM) + 0.5)
        for _ in range(60):  # 2⁻⁶⁰ of the bracket
            mid = 0.5 * (lo + hi)
            below = rounded_variance(mid) < want
            lo = np.where(below, mid, lo)
            hi = np.where(below, hi, mid)
        out[small] = np.where(want > 0, 0.5 * (lo + hi), 0.0)
    return out


class ScaledHg:
    """HG's noise at ``factor`` times its variance for clean images at the target ISO's
    brightness (as the bench hands HG its clean images, ``models.at_target_brightness``): per CFA
    position and HG table (``pack.tables(iso, model="hg", clean_at="target")``, one per run of
    levels whose law's variance stays within 0.5 %) the table's integer variance ``v`` and mean
    ``μ``, and the SD whose rounded Gaussian has the variance ``factor·v``."""

    def __init__(self, pack, iso: int, factor: float):
        t = pack.tables(iso, model="hg", clean_at="target")
        cdf = t["cdf"].astype(np.float64) / 2.0**32
        pmf = np.diff(cdf, axis=-1, prepend=0.0)
        x = t["first"][..., None] + np.arange(pmf.shape[-1])
        mean = (pmf * x).sum(-1)
        var = (pmf * (x - mean[..., None]) ** 2).sum(-1)
        self.lut = t["lut"]
        self.white = int(t["white"])
        # HG's tables are centred on the level (zero mean); their whole-DN mean is kept.
        self.centre = np.rint(mean).astype(np.int64)
        self.sd = rounded_gaussian_sd(factor * var)
        self.var = var

    def draw(self, at: np.ndarray, seed: int) -> np.ndarray:
        """``at`` (uint16, the clean image at the target brightness) plus the scaled noise,
        clamped to ``[0, white]``; the same ``seed`` gives the same image."""
        h, w = at.shape
        pos = (np.arange(h)[:, None] % 2) * 2 + np.arange(w)[None, :] % 2
        level = np.minimum(at.astype(np.int64), self.white)
        table = self.lut[pos, level]
        z = np.random.default_rng(seed).standard_normal(at.shape)
        out = level + self.centre[pos, table] + np.rint(self.sd[pos, table] * z)
        return np.clip(out, 0, self.white).astype(np.uint16)
