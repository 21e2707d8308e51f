"""The paired test behind the controls' verdict: is row A below row B, seed for seed?

Every row of a run is trained on the same data in the same order with the same initialisation
per training seed, so two rows' PSNRs at one seed share most of their luck: the seed-to-seed
spread of a row (0.1–0.3 dB on set 002) is mostly common to every row, and the difference at
each seed is the measurement. The test is Student's one-sided paired t-test on those differences
at a stated false-alarm rate (:data:`FALSE_ALARM`, 5 %): when A is in truth not below B (and the
differences are Gaussian), it says "below" at most 5 % of the time, whatever the number of seeds.
More seeds make it more sensitive, where the earlier rule ("below at every seed") made a real
gap harder to pass with every seed added. A gap under :data:`MIN_GAP_DB` on the means is never
"clearly" below, however consistent.

With 2 seeds the critical t is 6.31: the two differences must agree to about a fifth of their
mean; 4 or more seeds (t 2.35 and below) are what a verdict on close rows needs."""

from __future__ import annotations

import math

import numpy as np

# One-sided false-alarm rate of the test.
FALSE_ALARM = 0.05
# The least gap on the means (dB) that counts as clearly below.
MIN_GAP_DB = 0.1
# Student's t at the one-sided 95 % point, 1 to 30 degrees of freedom.
_T95 = (
    6.3138, 2.9200, 2.3534, 2.1318, 2.0150, 1.9432, 1.8946, 1.8595, 1.8331, 1.8125,
    1.7959, 1.7823, 1.7709, 1.7613, 1.7531, 1.7459, 1.7396, 1.7341, 1.7291, 1.7247,
    1.7207, 1.7171, 1.7139, 1.7109, 1.7081, 1.7056, 1.7033, 1.7011, 1.6991, 1.6973,
)  # fmt: skip
_Z95 = 1.6448536269514722


def t_critical(df: int) -> float:
    """Student's t at the one-sided 95 % point for ``df`` ≥ 1 degrees of freedom (the table to
    30, then the Cornish–Fisher expansion, within 10⁻⁴ of the exact value)."""
    if df < 1:
        raise ValueError(f"degrees of freedom must be ≥ 1, got {df}")
    if df <= len(_T95):
        return _T95[df - 1]
    z = _Z95
    return z + (z**3 + z) / (4 * df) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * df**2)


def paired_below(low: dict[str, float], high: dict[str, float]) -> dict:
    """Whether the row with per-seed scores ``low`` is clearly below the one with ``high`` (both
    ``{seed: PSNR}``), paired over their common seeds: ``below`` when there are ≥ 2 of them, the
    mean difference ``high − low`` is at least :data:`MIN_GAP_DB` and its t exceeds
    :func:`t_critical` (all differences equal and positive: t infinite). Also returns ``n``,
    ``gap_db`` (mean difference), ``sd_db`` (their sample SD), ``t`` and ``t_critical``."""
    seeds = sorted(set(low) & set(high))
    d = np.array([high[s] - low[s] for s in seeds], dtype=np.float64)
    n = len(d)
    out: dict = {"n": n, "gap_db": float(d.mean()) if n else None, "sd_db": None, "t": None, "t_critical": None, "below": False}
    if n < 2:
        return out
    sd = float(d.std(ddof=1))
    gap = float(d.mean())
    t = gap / (sd / math.sqrt(n)) if sd > 0 else (math.inf if gap > 0 else 0.0)
    crit = t_critical(n - 1)
    out.update(sd_db=sd, t=t, t_critical=crit, below=bool(gap >= MIN_GAP_DB and t > crit))
    return out
