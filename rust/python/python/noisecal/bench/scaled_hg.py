"""The HG controls: HG's noise with a scaled variance at every clean level, drawn as HG draws its
own (a Gaussian rounded to whole DN about the level, clamped to ``[0, white]``). ``wrong`` is
½ (a model that must score clearly worse), ``loud`` 2 (one that must score below HG).

Why not scale HG's drawn noise: HG's output is already whole DN, and ``round(m + (x − m)·√f)``
moves a ±1 DN draw to ±0.71 or ±1.41 DN, which round back to ±1. Where HG's noise is mostly 0 and
±1 DN (a variance below about 0.5 DN², the dark end of an 8-bit sensor such as EMVA 1288 set 002)
the earlier "half variance" kept 0.97–1.0 of HG's variance and the "twice" about 1.0, so neither
control differed from HG there (docs/bench.md, "The controls on set 002"). Here the rounded
Gaussian's own SD is chosen per table so that the *integer* noise has ``f`` times the variance of
HG's table at that level (``noisecal.rounded_gaussian_sd``, the core's rule for HG's own tables)."""

from __future__ import annotations

import numpy as np

# The rounded Gaussian's SD for an integer variance, and that variance for an SD: the core's
# (``derive/baselines/pmf.rs``), the rule HG's own tables are made with.
from .. import rounded_gaussian_sd, rounded_variance


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
