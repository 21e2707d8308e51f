"""The terminal table of a run's results (the same data ``--json`` writes and
``noisecal report --bench`` reads)."""

from __future__ import annotations

from .metrics import BANDS, REGIONS
from .scoring import failed_controls, has_controls, rows_below_wrong


def _fmt(m: dict, digits: int = 2) -> str:
    return f"{m['mean']:.{digits}f}±{m['std']:.{digits}f}"


def _input_at(out: dict, iso: int) -> dict | None:
    """The noisy input's scores at ``iso``: keyed by int in a run, by str once read back from --json."""
    inputs = out.get("input", {})
    return inputs.get(iso) or inputs.get(str(iso))


def gains(out: dict) -> list[dict]:
    """Per summary row, the PSNR gain over the noisy input in dB, overall and per brightness band
    (the band's pooled PSNR minus the noisy input's in that band): where the noise is small against
    the signal every row sits near the input, and the gain is what tells a network that learned
    from one that did not."""
    rows = []
    for r in out["summary"]:
        inp = _input_at(out, r["iso"])
        if not inp:
            continue
        g = {"model": r["model"], "iso": r["iso"], "psnr": r["psnr"]["mean"] - inp["psnr"], "bands": {}}
        for b, m in r["bands"].items():
            if b in inp["bands"]:
                g["bands"][b] = m["mean"] - inp["bands"][b]["psnr"]
        rows.append(g)
    return rows


def region_table(out: dict) -> str:
    """Per summary row, the PSNR (mean ± spread over seeds) and the gain over the noisy input in
    the flat interiors and the edge bands (:func:`noisecal.bench.metrics.region_masks`), with the
    regions' shares of the pixels: flat regions reward smoothing and edges punish it, so a model
    with too little noise wins at edges and one with too much in flat regions; empty when the run
    scored no regions."""
    rows = [r for r in out["summary"] if r.get("regions")]
    if not rows:
        return ""
    head = f"{'by region, PSNR dB':<22}{'ISO':>6}  " + "  ".join(f"{n:>12}  {'gain':>7}" for n in REGIONS)
    lines = [head, "-" * len(head)]
    for iso in sorted({r["iso"] for r in rows}):
        inp = (_input_at(out, iso) or {}).get("regions", {})
        for r in [r for r in rows if r["iso"] == iso]:
            cells = []
            for n in REGIONS:
                m = r["regions"].get(n)
                g = f"{m['mean'] - inp[n]['psnr']:>+7.2f}" if m and n in inp else f"{'':>7}"
                cells.append(f"{_fmt(m) if m else '':>12}  {g}")
            lines.append(f"{r['model']:<22}{iso:>6}  " + "  ".join(cells))
        if inp:
            cells = [f"{inp[n]['psnr']:>12.2f}  {'':>7}" if n in inp else f"{'':>12}  {'':>7}" for n in REGIONS]
            lines.append(f"{'(noisy input)':<22}{iso:>6}  " + "  ".join(cells))
            share = ", ".join(f"{n} {100 * inp[n]['fraction']:.0f} %" for n in REGIONS if n in inp)
            lines.append(f"{'':<22}{iso:>6}  pixels: {share}")
    lines.append("regions: flat where the clean image varies less than the evaluation noise's RMS over a 5×5 packed window")
    return "\n".join(lines)


def gain_table(out: dict) -> str:
    """:func:`gains` as lines of text."""
    bands = [b[0] for b in BANDS]
    head = f"{'gain over input, dB':<22}{'ISO':>6}  {'all':>8}  " + "  ".join(f"{b:>8}" for b in bands)
    lines = [head, "-" * len(head)]
    for g in sorted(gains(out), key=lambda g: g["iso"]):
        bs = "  ".join(f"{g['bands'][b]:>+8.2f}" if b in g["bands"] else f"{'':>8}" for b in bands)
        lines.append(f"{g['model']:<22}{g['iso']:>6}  {g['psnr']:>+8.2f}  {bs}")
    return "\n".join(lines)


# Below this gain of the best linear filter, a network starting from the identity has no first
# step to take (docs/bench.md, "Why nothing learnt on EMVA set 002").
LINEAR_FLOOR_DB = 0.05


def headroom_lines(out: dict) -> list[str]:
    """Per ISO, the evaluation set's headroom (:mod:`.headroom`), and a warning where only an
    edge-aware filter can remove its noise."""
    lines = []
    for iso, h in out.get("headroom", {}).items():
        lin, guided = h.get("linear_db"), h.get("guided_db")
        if lin is None or guided is None:
            continue
        line = f"headroom at ISO {iso}: best linear 5×5 filter {lin:+.2f} dB, clean-guided flat filter {guided:+.2f} dB over the noisy input"
        if lin < LINEAR_FLOOR_DB and guided > 1.0:
            line += (
                ": only an edge-aware filter removes this noise; a row at the noisy input's PSNR did not learn it "
                "and ranks nothing (--highpass --loss mse may help: docs/bench.md)"
            )
        lines.append(line)
    return lines


def verdict_line(iso, c: dict) -> str:
    """The run's verdict at one ISO from its controls (``scoring.controls``): whether they ordered
    as expected, and if not which did not — the other rows' ranking is then not established on
    this data. Older JSONs without ``failed`` are judged from the same fields."""
    failed = c.get("failed", failed_controls(c))
    if not has_controls(c):
        return f"verdict at ISO {iso}: UNCHECKED: no control row (oracle, wrong, loud with hg), so nothing shows the benchmark can tell models apart here"
    if failed:
        return (
            f"verdict at ISO {iso}: the controls did NOT order as expected ({'; '.join(failed)}): the ranking of the "
            "other rows is not established on this data (more steps, scenes or seeds, or scenes with texture)"
        )
    below = rows_below_wrong(c)
    note = f"; not clearly above the wrong control: {', '.join(below)}" if below else ""
    return f"verdict at ISO {iso}: the controls ordered as expected: the benchmark tells models apart on this data{note}"


def vs_best_line(iso, vb: dict | None) -> str:
    """Every row against the best one (``scoring.controls``' ``vs_best``): the rows level with it
    and the rows clearly below, each with its gap, t and the smallest gap its seeds detect."""
    if not vb or vb.get("best") is None or not vb.get("vs"):
        return ""

    def one(k: str) -> str:
        t = vb["vs"][k]
        if t.get("t") is None:
            return f"{k} (one common seed: untested)"
        return f"{k} {t['gap_db']:.2f} dB (t {t['t']:.2f} vs {t['t_critical']:.2f}, detects ≥ {t['detectable_db']:.2f})"

    level = [one(k) for k in vb["level"][1:]]
    below = [one(k) for k in vb["below"]]
    return (
        f"against the best row at ISO {iso} ({vb['best']}; paired test, 5 % false alarms between two equal rows): "
        f"level: {', '.join(level) or 'none'}; clearly below: {', '.join(below) or 'none'}"
    )


def _paired(t: dict | None) -> str:
    """A paired test's figures (``paired.paired_below``), for the controls line."""
    if not t or t.get("t") is None:
        return ""
    return f", paired t {t['t']:.2f} vs {t['t_critical']:.2f} over {t['n']} seeds"


def table(out: dict) -> str:
    lines = []
    bands = [b[0] for b in BANDS]
    head = f"{'model':<22}{'ISO':>6}  {'PSNR dB':>12}  {'SSIM':>14}  {'Δ HG dB':>12}  " + "  ".join(f"{b:>12}" for b in bands)
    lines.append(head)
    lines.append("-" * len(head))
    calibrated = set(out.get("calibrated_isos", []))
    for iso in out["isos"] + sorted({r["iso"] for r in out["summary"]} - set(out["isos"])):
        for r in [r for r in out["summary"] if r["iso"] == iso]:
            d = _fmt(r["delta_hg"]) if "delta_hg" in r else ""
            bs = "  ".join(f"{_fmt(r['bands'][b]):>12}" if b in r["bands"] else f"{'':>12}" for b in bands)
            name = r["model"]
            if r["model"].split(":")[0] == "noisecal" and iso not in calibrated:
                name += " (interp)"
            lines.append(f"{name:<22}{iso:>6}  {_fmt(r['psnr']):>12}  {_fmt(r['ssim'], 4):>14}  {d:>12}  {bs}")
        inp = _input_at(out, iso)
        if inp:
            bs = "  ".join(f"{inp['bands'][b]['psnr']:>12.2f}" if b in inp["bands"] else f"{'':>12}" for b in bands)
            lines.append(f"{'(noisy input)':<22}{iso:>6}  {inp['psnr']:>12.2f}  {inp['ssim']:>14.4f}  {'':>12}  {bs}")
        lines.append("")
    for iso, c in out["controls"].items():
        parts = []
        if "oracle_best" in c:
            verdict = "yes" if c["oracle_best"] else ("within the seed spread" if c["oracle_within_spread"] else "NO")
            parts.append(f"oracle best: {verdict} (best − oracle {c['oracle_gap_db']:.2f} dB)")
        if "wrong_vs" in c:
            for k in c.get("wrong_judged_against", []):
                t = c["wrong_vs"][k]
                verdict = "yes, clearly" if t["below"] else "NOT clearly"
                gap = f"by {t['gap_db']:.2f} dB" if t["gap_db"] is not None else "no common seed"
                parts.append(f"wrong below {k}: {verdict} ({gap}{_paired(t)})")
            parts.append(f"wrong worst on the means: {'yes' if c['wrong_worst'] else 'no'}")
        elif "wrong_worst" in c:
            verdict = "yes, clearly" if c["wrong_clear"] else ("yes, but not clearly" if c["wrong_worst"] else "NO")
            parts.append(f"wrong worst: {verdict} (by {c['wrong_margin_db']:.2f} dB)")
        if "loud_below_hg" in c:
            verdict = "yes" if c["loud_below_hg"] else "NO: the evaluation rewards smoothing, not fidelity"
            parts.append(f"loud (2× HG variance) below HG: {verdict} (by {c['loud_margin_db']:.2f} dB{_paired(c.get('loud_vs_hg'))})")
            # Loud rows at other factors (``loud:4``): how wide a model must be before this set shows it.
            for k, t in list(c.get("loud_rows_vs_hg", {}).items())[1:]:
                seen = "yes, clearly" if t["below"] else "NOT clearly"
                gap = f"by {t['gap_db']:.2f} dB" if t["gap_db"] is not None else "no common seed"
                parts.append(f"{k} ({t['factor']:g}× HG variance) below HG: {seen} ({gap}{_paired(t)})")
        if parts:
            lines.append(f"controls at ISO {iso}: " + "; ".join(parts))
        lines.append(verdict_line(iso, c))
        best_line = vs_best_line(iso, c.get("vs_best"))
        if best_line:
            lines.append(best_line)
    lines += headroom_lines(out)
    lines += [f"note: {n}" for n in out.get("notes", [])]
    n = len(out["networks"])
    lines.append(
        f"{n} networks, {out['config']['steps']} steps each (batch {out['config']['batch']}, crop {out['config']['crop']}, "
        f"width {out['config']['width']}), seeds {out['seeds']}, {out['wall_seconds'] / 60:.1f} min"
    )
    lines.append("PSNR/SSIM: mean±std over training seeds; bands: PSNR of the pooled error by clean level (dark < 2 % of range)")
    if any(out.get("input", {}).values()):
        lines += ["", gain_table(out)]
    regions = region_table(out)
    if regions:
        lines += ["", regions]
    return "\n".join(lines)
