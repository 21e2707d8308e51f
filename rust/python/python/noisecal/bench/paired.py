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
mean; 4 or more seeds (t 2.35 and below) are what a verdict on close rows needs.

Every test also gives ``detectable_db``: the gap on the means its critical t reaches at the
differences' measured spread (t_critical × SD / √n, at least :data:`MIN_GAP_DB`), the smallest
difference this many seeds would call clearly below (about half the time at that true gap).

Against the best row (:func:`below_best`) the row to beat is chosen by the data (the highest
mean), which doubles the one-sided test's false alarms between two equal rows; that test runs at
:data:`BEST_FALSE_ALARM` per side, so two equal rows are called apart at the stated 5 %."""

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
# Student's t at the one-sided 97.5 % point, 1 to 30 degrees of freedom.
_T975 = (
    12.7062, 4.3027, 3.1824, 2.7764, 2.5706, 2.4469, 2.3646, 2.3060, 2.2622, 2.2281,
    2.2010, 2.1788, 2.1604, 2.1448, 2.1314, 2.1199, 2.1098, 2.1009, 2.0930, 2.0860,
    2.0796, 2.0739, 2.0687, 2.0639, 2.0595, 2.0555, 2.0518, 2.0484, 2.0452, 2.0423,
)  # fmt: skip
_Z975 = 1.959963984540054
# The one-sided rate of the test against the best row (:func:`below_best`): half of FALSE_ALARM.
BEST_FALSE_ALARM = FALSE_ALARM / 2
_TABLES = {FALSE_ALARM: (_T95, _Z95), BEST_FALSE_ALARM: (_T975, _Z975)}


def t_critical(df: int, false_alarm: float = FALSE_ALARM) -> float:
    """Student's t at the one-sided ``1 − false_alarm`` point (:data:`FALSE_ALARM` or
    :data:`BEST_FALSE_ALARM`) for ``df`` ≥ 1 degrees of freedom (the table to 30, then the
    Cornish–Fisher expansion, within 10⁻³ of the exact value)."""
    if df < 1:
        raise ValueError(f"degrees of freedom must be ≥ 1, got {df}")
    if false_alarm not in _TABLES:
        raise ValueError(f"false-alarm rate {false_alarm}: use one of {', '.join(str(a) for a in _TABLES)}")
    table, z = _TABLES[false_alarm]
    if df <= len(table):
        return table[df - 1]
    return z + (z**3 + z) / (4 * df) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * df**2)


def paired_below(low: dict[str, float], high: dict[str, float], false_alarm: float = FALSE_ALARM) -> dict:
    """Whether the row with per-seed scores ``low`` is clearly below the one with ``high`` (both
    ``{seed: PSNR}``), paired over their common seeds: ``below`` when there are ≥ 2 of them, the
    mean difference ``high − low`` is at least :data:`MIN_GAP_DB` and its t exceeds
    :func:`t_critical` at ``false_alarm`` (all differences equal and positive: t infinite). Also
    returns ``n``, ``gap_db`` (mean difference), ``sd_db`` (their sample SD), ``t``,
    ``t_critical`` and ``detectable_db`` (module docstring)."""
    seeds = sorted(set(low) & set(high))
    d = np.array([high[s] - low[s] for s in seeds], dtype=np.float64)
    n = len(d)
    out: dict = {"n": n, "gap_db": float(d.mean()) if n else None, "sd_db": None, "t": None, "t_critical": None, "detectable_db": None, "below": False}
    if n < 2:
        return out
    sd = float(d.std(ddof=1))
    gap = float(d.mean())
    t = gap / (sd / math.sqrt(n)) if sd > 0 else (math.inf if gap > 0 else 0.0)
    crit = t_critical(n - 1, false_alarm)
    detectable = max(MIN_GAP_DB, crit * sd / math.sqrt(n))
    out.update(sd_db=sd, t=t, t_critical=crit, detectable_db=detectable, below=bool(gap >= MIN_GAP_DB and t > crit))
    return out


def below_best(per_seed: dict[str, dict[str, float]]) -> dict:
    """Every row against the best one: ``per_seed`` maps each row to its ``{seed: PSNR}``; the
    best is the highest mean over the seeds every row has. Returns ``best`` (its name), ``vs``
    (per other row, :func:`paired_below` at :data:`BEST_FALSE_ALARM`), ``level`` (the rows the
    test does not put clearly below the best, the best first) and ``below``. With no row or no
    common seed, ``best`` is None."""
    common = set.intersection(*(set(s) for s in per_seed.values())) if per_seed else set()
    if not common:
        return {"best": None, "vs": {}, "level": [], "below": []}
    mean = {k: float(np.mean([s[x] for x in common])) for k, s in per_seed.items()}
    best = max(sorted(mean), key=lambda k: mean[k])
    vs = {k: paired_below(s, per_seed[best], BEST_FALSE_ALARM) for k, s in sorted(per_seed.items()) if k != best}
    level = [best] + sorted((k for k, t in vs.items() if not t["below"]), key=lambda k: -mean[k])
    below = sorted((k for k, t in vs.items() if t["below"]), key=lambda k: -mean[k])
    return {"best": best, "vs": vs, "level": level, "below": below}
