"""Noise near black on the simulated tiled set (tests/bench/sim_tiles.py), level by level, against
its known truth.

    python tests/bench/sim_tiles_probe.py [--out target/simtiles] [--references noise] [--cli] [--json F]

The set (``--out``, sim_tiles.py's cache, written when missing with ``--references``) is
calibrated into ``OUT/sim.pack`` and ``OUT/sim-plain.pack`` (``calibrate --plain``), the packs the
benchmark takes; with ``--cli`` by the ``noisecal`` command first on ``PATH``, whose calibration
lines are kept in ``OUT/calibrate-*.log``. Then, for each level of sim_tiles.py's ``EVAL`` up to
``--max-level`` DN above black, over the evaluation frames' clean image at that level
(``flat(level, EVAL_SHAPE)``: the fixed pattern included, ``EVAL_SHAPE`` pixels):

- **truth**: the variance of ``noisy − round(clean)`` for this sensor (the pack's convention: a
  clean code stands for the levels that round to it), computed from its law: per pixel of clean
  level ``c``, ``noisy = clip(round(c + e), 0, WHITE)``, ``e ~ N(0, A·max(c − BLACK, 0) + B)``, so
  ``P(noisy = k) = Φ((k + ½ − c)/σ) − Φ((k − ½ − c)/σ)`` with the clamp's mass on 0 (and
  ``WHITE``); minus ``round(c)``, the second rounding; the PMFs of all the level's pixels pooled
  (the mixture over the fixed pattern, as a held-out frame pools them). Its mean and 0.1 % /
  99.9 % quantiles come from the same PMF. **Checked by Monte Carlo** (``--mc`` frames of
  ``sim_tiles.noisy``): the probe stops with an error where the two differ by more than 4
  standard errors.
- **uniform**: the same variance with each pixel's clean level moved to a uniformly spread phase
  within its code (same code, same σ): what a code holds for a scene whose levels fill it. At
  sub-DN noise the variance of ``noisy − round(c)`` depends on where ``c`` sits in its code
  (near a half code the two roundings disagree most), so a pack, which is indexed by the whole
  code, cannot hold both; the levels of ``EVAL`` sit at set 002's phases.
- **tables**: the pack's pixel PMFs (``Pack.tables(200)``) pooled over the same pixels (each pixel
  its position's bin of its code): the pack's own variance there.
- **synthetic**: ``Pack.synth`` onto ``round(clean)``, ``--seeds`` images, default components
  (``default``), the components a clean image from one's own captures takes (``own``: no
  ``fpn``, the pattern is in the clean image already), ``pixel`` alone, and the plain pack
  (``plain``); each as variance and its ratio to the truth.

The calibration steps' own levels up to ``--max-level`` (3.5, 7, … DN: codes whose bins hold
their own samples) are printed too, marked ``*``. A second table gives the mean and the 0.1 % /
99.9 % quantiles of each. Last, the calibration's lines on refused, normalised or flickering
frames (the pack's warnings name the frames normalised as drift or flicker; frames *refused* are
listed only by ``noisecal calibrate``'s output, with ``--cli``: with the ordered references, 7 at
the 3.5 and 10.5 DN steps, as tests/e2e/tests/sim_tiles_references.rs's small set also shows) and
how often each reference burst's clean image ``round(mean)`` differs from ``round(clean)`` at the
steps up to ``--max-level``.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

import noisecal
import sim_tiles as sim

ISO = 200  # the target ISO of the set's calibration
LINES = re.compile(r"refus|flicker|normalis|brightness|drift|moved", re.IGNORECASE)
_erf = np.vectorize(math.erf, otypes=[np.float64])


def phi(z: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + _erf(z / math.sqrt(2.0)))


def code_pmf(clean: np.ndarray, span: int) -> tuple[np.ndarray, np.ndarray]:
    """The PMF of ``noisy − round(clean)`` per pixel: (values ``−span … span``, (pixels, values))."""
    c = clean.reshape(-1, 1)
    sd = np.sqrt(sim.variance(c))
    k = np.rint(c) + np.arange(-span, span + 1)[None, :]
    upper = np.where(k >= sim.WHITE, 1.0, phi((k + 0.5 - c) / sd))
    lower = np.where(k <= 0, 0.0, phi((k - 0.5 - c) / sd))
    p = np.where((k < 0) | (k > sim.WHITE), 0.0, upper - lower)
    return np.arange(-span, span + 1), p


def pooled(values: np.ndarray, p: np.ndarray) -> dict:
    """Mean, variance and 0.1 % / 99.9 % quantiles of the mixture of the rows of ``p``."""
    w = p.sum(axis=0)
    w = w / w.sum()
    mean = float((values * w).sum())
    var = float(((values - mean) ** 2 * w).sum())
    cdf = np.cumsum(w)
    q = [int(values[min(np.searchsorted(cdf, t), len(values) - 1)]) for t in (0.001, 0.999)]
    return {"var": var, "mean": mean, "q001": q[0], "q999": q[1]}


def sample_stats(d: np.ndarray) -> dict:
    q = np.quantile(d, [0.001, 0.999], method="inverted_cdf")
    return {"var": float(d.var()), "mean": float(d.mean()), "q001": int(q[0]), "q999": int(q[1])}


def table_stats(tables: dict, code: np.ndarray) -> dict:
    """The pack's pixel PMFs pooled over the pixels of ``code`` (h, w): each pixel its position's bin."""
    h, w = code.shape
    pos = (np.arange(h)[:, None] % 2) * 2 + (np.arange(w)[None, :] % 2)
    cdf, first, lut = tables["cdf"], tables["first"], tables["lut"]
    lo, hi = int(first.min()), int(first.max()) + cdf.shape[2]
    values = np.arange(lo, hi)
    acc = np.zeros(len(values))
    for p in range(4):
        for b, n in zip(*np.unique(lut[p][code[pos == p]], return_counts=True)):
            c = cdf[p, b].astype(np.float64) / 2.0**32
            pmf = np.diff(np.concatenate([[0.0], np.minimum(c, 1.0)]))
            acc[first[p, b] - lo : first[p, b] - lo + len(pmf)] += n * pmf
    return pooled(values, acc[None, :])


def calibrate(out: Path, cli: bool, say) -> list[str]:
    """Makes the missing packs; returns the calibration's lines on refused or normalised frames."""
    lines = []
    for name, is_plain in (("sim.pack", False), ("sim-plain.pack", True)):
        log = out / f"calibrate-{name.removesuffix('.pack')}.log"
        if not (out / name).exists():
            say(f"calibrating {name} from cal/" + (" (noisecal on PATH)" if cli else ""))
            if cli:
                cmd = ["noisecal", "calibrate", str(out / "cal"), "-o", str(out / name)] + ["--plain"] * is_plain
                got = subprocess.run(cmd, capture_output=True, text=True, check=True)
                log.write_text(got.stdout + got.stderr)
            else:
                noisecal.calibrate(out / "cal", plain=is_plain).save(out / name)
        if is_plain:
            continue
        text = log.read_text().splitlines() if log.exists() else list(noisecal.Pack.load(out / name).warnings)
        lines += [f"{name}: {v}" for v in text if LINES.search(v)]
    return lines


def reference_misses(out: Path, pattern, max_level: float) -> list[tuple[float, float]]:
    """Per calibration step up to ``max_level``: the share of pixels whose reference burst's
    ``round(mean)`` (the calibration's clean image) is not ``round(clean)``."""
    got = []
    for k in range(sim.STEPS):
        level = 3.5 * k
        if level > max_level:
            break
        frames = [noisecal.read_dng(out / "cal" / f"ref_{k:03}_{j}.dng")[0].astype(np.float64) for j in range(sim.REF_FRAMES)]
        clean = sim.flat(level, sim.CAL_SHAPE, pattern)
        got.append((level, float(np.mean(np.rint(np.mean(frames, axis=0)) != np.rint(clean)))))
    return got


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=Path("target/simtiles"), help="sim_tiles.py's cache [default: %(default)s]")
    p.add_argument("--references", choices=sim.REFERENCES, default="noise", help="sim_tiles.py's --references [default: %(default)s]")
    p.add_argument("--cli", action="store_true", help="calibrate missing packs with the `noisecal` command on PATH")
    p.add_argument("--seeds", type=int, default=4, help="synthetic images per level and model [default: %(default)s]")
    p.add_argument("--mc", type=int, default=16, help="Monte Carlo frames per level checking the truth [default: %(default)s]")
    p.add_argument("--max-level", type=float, default=23.0, help="levels of EVAL up to this, DN above black [default: %(default)s]")
    p.add_argument("--json", type=Path, help="also write every figure here")
    args = p.parse_args(argv)

    def say(*a):
        print(*a, file=sys.stderr, flush=True)

    sim.convert(args.out, say, args.references)
    refused = calibrate(args.out, args.cli, say)
    pack = noisecal.Pack.load(args.out / "sim.pack")
    plain = noisecal.Pack.load(args.out / "sim-plain.pack")
    tables = pack.tables(ISO)
    pattern = sim.fixed_pattern(np.random.default_rng(sim.SEED))
    rng = np.random.default_rng(7)
    rows = (("default", pack, None), ("own", pack, "pixel,row,column,frame"), ("pixel", pack, "pixel"), ("plain", plain, None))
    record = {"references": args.references, "levels": []}
    head = f"{'level':>6} {'codes':>14} {'truth':>7} {'MC':>7} {'uniform':>7} {'tables':>15}" + "".join(f" {n:>15}" for n, _, _ in rows)
    print(f"variance of noisy − round(clean) (DN²) at ISO {ISO}, references {args.references}; (ratio to the truth); * a calibration step's level")
    print(head)
    tails = []
    steps = [3.5 * k for k in range(1, sim.STEPS) if 3.5 * k <= args.max_level]
    for level in sorted([v for v in sim.EVAL if v <= args.max_level] + steps):
        clean = sim.flat(level, sim.EVAL_SHAPE, pattern)
        code = np.rint(clean)
        span = int(math.ceil(8 * math.sqrt(float(sim.variance(clean).max())))) + 2
        values, pmf = code_pmf(clean, span)
        truth = pooled(values, pmf)
        mc = np.concatenate([(sim.noisy(clean, rng) - code).ravel() for _ in range(args.mc)])
        mc_var = float(mc.var())
        se = math.sqrt(max(float(np.mean((mc - mc.mean()) ** 4)) - mc_var**2, 0.0) / len(mc))
        if abs(mc_var - truth["var"]) > 4 * se + 1e-12:
            raise SystemExit(f"sim_tiles_probe.py: at {level} DN the law's variance {truth['var']:.5f} and the Monte Carlo's {mc_var:.5f} differ by more than 4 SE ({se:.5f})")
        phases = (np.arange(clean.size) % 64 + 0.5) / 64 - 0.5
        uniform = pooled(*code_pmf(code.ravel() + phases.reshape(-1), span))
        codes, counts = np.unique(code, return_counts=True)
        shares = "/".join(f"{int(c)}:{n / code.size:.0%}" for c, n in zip(codes, counts) if n / code.size >= 0.01)
        tab = table_stats(tables, code.astype(np.int64))
        entry = {"level": level, "step": level in steps, "codes": {int(c): int(n) for c, n in zip(codes, counts)}, "truth": truth, "mc_var": mc_var, "mc_se": se, "uniform": uniform, "tables": tab, "models": {}}
        cells = []
        flat_code = code.astype(np.uint16)
        for name, pk, comp in rows:
            d = np.concatenate([(pk.synth(flat_code, ISO, s, components=comp).astype(np.float64) - code).ravel() for s in range(args.seeds)])
            entry["models"][name] = sample_stats(d)
            cells.append(f"{d.var():.4f} ({d.var() / truth['var']:.2f}×)")
        record["levels"].append(entry)
        tails.append(entry)
        print(f"{level:6.2f}{'*' if level in steps else ' '}{shares:>14} {truth['var']:7.4f} {mc_var:7.4f} {uniform['var']:7.4f} {tab['var']:.4f} ({tab['var'] / truth['var']:.2f}×)" + "".join(f" {c:>15}" for c in cells))
    print("mean (DN) and 0.1 % / 99.9 % quantiles of noisy − round(clean)")
    names = ["truth", "uniform", "tables"] + [n for n, _, _ in rows]
    print(f"{'level':>6} " + "".join(f" {n:>17}" for n in names))
    for e in tails:
        got = [e["truth"], e["uniform"], e["tables"]] + [e["models"][n] for n, _, _ in rows]
        print(f"{e['level']:6.2f}{'*' if e['step'] else ' '}" + "".join(f" {g['mean']:+7.3f} {g['q001']:+3d}/{g['q999']:+3d}  " for g in got))
    misses = reference_misses(args.out, pattern, args.max_level)
    record["reference_misses"] = misses
    record["calibration_lines"] = refused
    print("reference bursts: share of pixels whose round(mean) is not round(clean), per step (DN above black): "
          + ", ".join(f"{lv:g}: {m:.2%}" for lv, m in misses))  # fmt: skip
    print(f"calibration: {len(refused)} lines on refused, normalised or flickering frames")
    for v in refused:
        print("  " + v)
    if args.json:
        args.json.write_text(json.dumps(record, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
