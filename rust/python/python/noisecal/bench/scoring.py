"""Scoring: networks and the noisy input on the evaluation pairs, the per-(model, ISO) summary
over seeds with the paired difference to HG, and the controls (oracle best, wrong clearly worst)."""

from __future__ import annotations

import numpy as np

from .metrics import BANDS, REGIONS, score, summarise
from .network import _torch


def score_input(pairs: list[tuple[np.ndarray, np.ndarray]], flat_tolerance: float | None = None) -> dict:
    """The noisy evaluation frames themselves scored against the clean images (no network)."""
    return score([n for n, _ in pairs], [c for _, c in pairs], flat_tolerance)


def noise_rms(pairs: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """The RMS of noisy − clean over the evaluation pairs (normalised units)."""
    sq = sum(float(np.sum((np.asarray(n, np.float64) - c) ** 2)) for n, c in pairs)
    return float(np.sqrt(sq / sum(n.size for n, _ in pairs)))


def evaluate(net, pairs: list[tuple[np.ndarray, np.ndarray]], device, flat_tolerance: float | None = None) -> dict:
    """``net``'s output on every evaluation pair (:func:`eval_pairs`), scored (per region type
    too, with ``flat_tolerance``: :func:`noisecal.bench.metrics.score`)."""
    torch = _torch()
    preds = []
    with torch.no_grad():
        for noisy, _ in pairs:
            preds.append(net(torch.from_numpy(noisy[None]).to(device))[0].cpu().numpy())
    return score(preds, [c for _, c in pairs], flat_tolerance)


def summary(results: list[dict]) -> list[dict]:
    """Per (model, ISO): PSNR/SSIM mean and spread over seeds, per band, and the paired difference
    to HG (same seed, same data order)."""
    rows = []
    by: dict[tuple[str, int], dict[int, dict]] = {}
    for r in results:
        by.setdefault((r["model"], r["iso"]), {})[r["seed"]] = r
    for (model, iso), per in by.items():
        row = {
            "model": model,
            "kind": next(iter(per.values()))["kind"],
            "iso": iso,
            "psnr": summarise([r["psnr"] for r in per.values()]),
            "psnr_per_seed": {str(k): v["psnr"] for k, v in sorted(per.items())},
            "ssim": summarise([r["ssim"] for r in per.values()]),
            "bands": {},
        }
        for name, *_ in BANDS:
            vals = [r["bands"][name]["psnr"] for r in per.values() if name in r["bands"]]
            if vals:
                row["bands"][name] = summarise(vals)
        for name in REGIONS:
            vals = [r["regions"][name]["psnr"] for r in per.values() if name in r.get("regions", {})]
            if vals:
                row.setdefault("regions", {})[name] = summarise(vals)
        hg = by.get(("hg", iso))
        if hg and model != "hg":
            common = sorted(set(per) & set(hg))
            if common:
                row["delta_hg"] = summarise([per[s]["psnr"] - hg[s]["psnr"] for s in common])
        rows.append(row)
    return rows


def controls(rows: list[dict]) -> dict:
    """Per ISO, among the rows trained on synthetic or real noise at that ISO (noise on noise left
    out): is the oracle best — strictly, and within the training-seed spread (``oracle_gap_db`` ≤
    max(0.1 dB, 2 × the largest seed std at the ISO)) — and is the wrong model worst, and clearly
    (``wrong_clear``: every other row beats it at every training seed, paired — same seed, same
    data — and by ``wrong_margin_db`` > 0.3 dB on the means)? With a ``loud`` row (HG at twice its
    variance): does it score below HG at every seed (``loud_below_hg``, ``loud_margin_db``)? If not,
    the evaluation rewards smoothing more than fidelity (e.g. scenes without texture), and a model
    with more noise than the sensor wins. The loud row is a control, not a row the wrong model
    must beat.)"""
    out = {}
    for iso in sorted({r["iso"] for r in rows}):
        at = {r["model"]: r for r in rows if r["iso"] == iso and r.get("kind") != "renoise"}
        mean = {k: r["psnr"]["mean"] for k, r in at.items()}
        spread = max((r["psnr"]["std"] for r in at.values()), default=0.0)
        c = {"spread_db": spread}
        oracle = [k for k, r in at.items() if r.get("kind") == "oracle"]
        if oracle:
            o = mean[oracle[0]]
            c["oracle_best"] = o == max(mean.values())
            c["oracle_gap_db"] = max(mean.values()) - o
            c["oracle_within_spread"] = c["oracle_gap_db"] <= max(0.1, 2 * spread)
        wrong = [k for k, r in at.items() if r.get("kind") == "wrong"]
        if wrong:
            w = at[wrong[0]]
            others = {k: r for k, r in at.items() if k != wrong[0] and r.get("kind") != "loud"}
            c["wrong_worst"] = all(mean[w["model"]] < r["psnr"]["mean"] for r in others.values())
            c["wrong_margin_db"] = (min(r["psnr"]["mean"] for r in others.values()) - mean[w["model"]]) if others else None
            ws = w.get("psnr_per_seed", {})
            paired = all(
                seed in r.get("psnr_per_seed", {}) and r["psnr_per_seed"][seed] > v
                for r in others.values()
                for seed, v in ws.items()
            )
            c["wrong_clear"] = bool(others) and bool(ws) and paired and c["wrong_margin_db"] > 0.3
            # The rows that do not clearly beat it (by 0.3 dB on the means and at every seed).
            c["wrong_not_below"] = sorted(
                k
                for k, r in others.items()
                if not (
                    r["psnr"]["mean"] - mean[w["model"]] > 0.3
                    and all(seed in r.get("psnr_per_seed", {}) and r["psnr_per_seed"][seed] > v for seed, v in ws.items())
                )
            )
        loud = [k for k, r in at.items() if r.get("kind") == "loud"]
        hg = [k for k, r in at.items() if r.get("kind") == "hg"]
        if loud and hg:
            lo, h = at[loud[0]], at[hg[0]]
            hs, ls = h.get("psnr_per_seed", {}), lo.get("psnr_per_seed", {})
            c["loud_margin_db"] = mean[hg[0]] - mean[loud[0]]
            c["loud_below_hg"] = bool(ls) and all(seed in hs and hs[seed] > v for seed, v in ls.items())
        c["failed"] = failed_controls(c)
        c["ordered"] = None if not has_controls(c) else not c["failed"]
        out[iso] = c
    return out


# Each control's check, its key in :func:`controls`' result and how the verdict names its failure.
CONTROL_CHECKS = (
    ("oracle_best", "oracle not best within the seed spread"),
    ("wrong_worst", "wrong (HG at ½ its variance) not clearly last"),
    ("loud_below_hg", "loud (HG at 2× its variance) not below HG at every seed"),
)


def has_controls(c: dict) -> bool:
    """Whether the run had any control row at the ISO (an oracle, a wrong or a loud one with HG)."""
    return any(key in c for key, _ in CONTROL_CHECKS)


def failed_controls(c: dict) -> list[str]:
    """The controls at one ISO (:func:`controls`) that did not order as expected: the oracle
    neither best nor within the seed spread, the wrong model not *clearly* last (worst on the
    mean by 0.3 dB or less, or above some row at some seed, counts as a failure), the loud model
    not below HG at every seed."""
    out = []
    if "oracle_best" in c and not (c["oracle_best"] or c["oracle_within_spread"]):
        out.append(CONTROL_CHECKS[0][1])
    if "wrong_worst" in c and not c["wrong_clear"]:
        rows = c.get("wrong_not_below")
        out.append(CONTROL_CHECKS[1][1] + (f" (not clearly above it: {', '.join(rows)})" if rows else ""))
    if "loud_below_hg" in c and not c["loud_below_hg"]:
        out.append(CONTROL_CHECKS[2][1])
    return out
