"""Noise near black on EMVA 1288 reference set 002, level by level: the real held-out frames
against what a pack synthesizes, and what the dark burst says the variance at black is.

    python tests/bench/emva1288_black.py --repo DATASETS [--out target/emva002] [--seeds 2]

The cache ``--out`` is ``tests/bench/emva1288_ladder.py``'s (converted and calibrated the same
way; made here when missing). The packs are made by the Python extension, or with ``--cli`` by
the ``noisecal`` command first on ``PATH`` (to measure a calibration change without rebuilding
the extension; synthesis is the extension's either way). For every whole clean code from 1 DN up
to 16 DN (and the ``--also`` codes) that at least 1 000 held-out pixels round to:

- **real**: the held-out frames' ``frame − round(clean)`` (the pack's convention: a clean code
  stands for the clean levels that round to it) and ``frame − clean`` (the float clean image);
- **synthetic**: the pack's synthesis onto a flat image at that code, default components,
  ``own`` (every component but the fixed pattern, ``pixel,row,column,frame``: what a clean image
  averaged from the sensor's own frames calls for, as this one is) and ``pixel`` (the pixel PMFs
  alone), and the plain per-bin histogram pack of the same frames
  (``ladder-plain.pack``, ``calibrate --plain``: the yardstick no smoothing step may lose to),
  ``--seeds`` images of the evaluated width; and the benchmark's HG rows drawn as
  ``noisecal-bench`` draws their training pairs (``noisecal.bench.models.make_pairs``): ``hg``,
  ``wrong`` (½ HG's variance), ``loud`` (2×) and ``loud4`` (4×), so a rank of the benchmark's
  rows can be read against the real noise they were taught.

For each, the variance (and its ratio to the real ``−round`` one), then a second table with the
0.1 % / 99.9 % quantiles and the share of samples at each noise value from −2 to +2 DN: at
sub-DN noise the PMF over three or four codes is the whole model.

**Like with like, both ways** (a third table, one row per evaluated exposure up to 16 DN, every
pixel of its held-out frame). The clean images here are the flat field's own mean (the dark
burst's mean plus the pairs' mean signal times the flat field's shape), so they carry the
sensor's fixed pattern and ``noisy − round(clean)`` holds none of it:

- (a) real ``noisy − round(clean)`` against the ``own`` components (no ``fpn``) synthesized onto
  that same ``round(clean)``: the pattern on neither side;
- (b) real ``noisy − level``, ``level`` the exposure's clean image's spatial mean per CFA
  position (the pattern kept in the real residual), against the default components synthesized
  onto a pattern-free flat image at ``round(level)`` per position, less ``level``: the pattern on
  both sides (the fixed pattern the dark burst measured; the flat field's gain pattern, PRNU, is
  not a component of the pack: at a level ``s`` above black it adds about ``s²·Var(F)``; the
  clean image's whole pattern variance about its level is printed).

Pixel-only onto each side's clean image is printed beside them.

Then, per half of the dark burst (the calibration's ISO 100 and ISO 200 dark steps): ``T`` (half
the median variance of consecutive frame differences, ``calibrate/dark.rs``), ``T + 1/12`` (what
``derive/fine_levels.rs::variance_at_black`` assumes: the clean image's rounding independent of
the sensor's), ``T + Var(r)`` with ``r`` each pixel's burst mean less its rounding, and the
variance of a frame less its rounded leave-one-out burst mean (what a sample at black holds). The
last two agree; the second does not when the noise at black is well below 1 DN, because then
the reference's rounding and the frame's are of the same pixel mean (docs/bench.md, "Noise at
black on set 002").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

import noisecal
import emva1288_ladder as ladder
from emva1288 import MOSAIC_SEED, Source, mosaic_labels, read_descriptor
from png16 import read_png_grey
from noisecal.bench.models import make_pairs, parse_model

MIN_PIXELS = 1000
# The fixed pattern's convention (docs/method.md, *Fixed pattern*): a clean image averaged from the
# sensor's own frames carries the pattern already; synthesis onto it adds every other component.
OWN = "pixel,row,column,frame"


def dark_terms(frames: np.ndarray) -> dict:
    """The variance at black of a dark burst ``frames`` (n, h, w), four ways (module docstring)."""
    n = len(frames)
    t = float(np.median([d.var() for d in np.diff(frames, axis=0)]) / 2)
    mean = frames.mean(axis=0)
    r = mean - np.rint(mean)
    total = frames.sum(axis=0)
    loo = np.stack([f - np.rint((total - f) / (n - 1)) for f in frames])
    return {"T": t, "T+1/12": t + 1 / 12, "T+Var(r)": t + float(r.var()), "frame-round(loo)": float(loo.var())}


def exposure_map(shape: tuple[int, int], k: int) -> np.ndarray:
    """(k, h, w): which held-out exposure each pixel of mosaic scene ``m`` shows
    (tests/bench/emva1288.py's ``write_mosaics``: ``(label + m) mod k``)."""
    labels = mosaic_labels(shape, k, MOSAIC_SEED)
    return np.stack([(labels + m) % k for m in range(k)])


def cfa_position(shape: tuple[int, int]) -> np.ndarray:
    """(h, w): each pixel's CFA position, 2·(row % 2) + column % 2."""
    return (np.arange(shape[0])[:, None] % 2) * 2 + np.arange(shape[1])[None, :] % 2


def like_with_like(frame: np.ndarray, clean: np.ndarray, black: list, pack, seeds: int, say) -> list[dict]:
    """The third table (module docstring): per held-out exposure up to 16 DN, (a) real
    ``noisy − round(clean)`` against ``own`` onto ``round(clean)``, (b) real ``noisy − level``
    against the default onto ``round(level)``, pixel-only beside each; variances (DN²) and the
    ratios synthetic / real."""
    k, shape = len(frame), frame.shape[1:]
    which = exposure_map(shape, k)
    pos = np.broadcast_to(cfa_position(shape), frame.shape)
    level = np.zeros((k, 4))
    for j in range(k):
        for p in range(4):
            level[j, p] = clean[(which == j) & (pos == p)].mean()
    # Each pixel's exposure's level at its position, and the clean image of each exposure whole.
    lvl = level[which, pos]
    order = np.argsort(level.mean(axis=1))
    black_mean = float(np.mean(black))
    rows = []
    say("like with like, per held-out exposure: (a) real noisy − round(clean) vs own onto round(clean); "
        "(b) real noisy − level (pattern kept) vs default onto round(level); variance DN² (synthetic / real)")  # fmt: skip
    say(f"{'above':>6} {'levels':>19} {'pixels':>8} {'(a) real':>9} {'own':>16} {'pixel':>16} "
        f"{'(b) real':>9} {'default':>16} {'own':>16} {'pixel':>16} {'pattern':>7}")  # fmt: skip
    for j in order:
        if level[j].max() > 16.5:
            continue
        at = which == j
        # The exposure's clean image whole: scene m holds exposure j where which[m] == j.
        clean_j = np.zeros(shape)
        frame_j = np.zeros(shape)
        for m in range(k):
            clean_j[which[m] == j] = clean[m][which[m] == j]
            frame_j[which[m] == j] = frame[m][which[m] == j]
        lvl_j = level[j][cfa_position(shape)]
        rc = np.rint(clean_j)
        real_a = float((frame_j - rc).var())
        real_b = float((frame_j - lvl_j).var())
        flat = np.rint(lvl_j).astype(np.uint16)
        onto = rc.astype(np.uint16)

        def var_of(img, comps, less):
            d = np.concatenate([(pack.synth(img, 200, s, components=comps).astype(np.float64) - less).ravel() for s in range(seeds)])
            return float(d.var())

        a_own, a_pix = var_of(onto, OWN, rc), var_of(onto, "pixel", rc)
        b_def, b_own, b_pix = var_of(flat, None, lvl_j), var_of(flat, OWN, lvl_j), var_of(flat, "pixel", lvl_j)
        # The clean image's whole pattern about its level (DSNU and PRNU): what real (b) holds.
        pattern = float((clean_j - lvl_j).var())
        row = {
            "above_black": float(level[j].mean() - black_mean),
            "levels": [float(v) for v in level[j]],
            "pixels": int(at.sum()),
            "a": {"real": real_a, "own": a_own, "pixel": a_pix},
            "b": {"real": real_b, "default": b_def, "own": b_own, "pixel": b_pix},
            "clean_pattern_var": pattern,
        }
        rows.append(row)
        r = lambda v, ref: f"{v:.4f} ({v / ref:.2f}×)"  # noqa: E731
        say(f"{row['above_black']:6.2f} {' '.join(f'{v:4.1f}' for v in level[j]):>19} {row['pixels']:8d} {real_a:9.4f} "
            f"{r(a_own, real_a):>16} {r(a_pix, real_a):>16} {real_b:9.4f} {r(b_def, real_b):>16} {r(b_own, real_b):>16} "
            f"{r(b_pix, real_b):>16} {pattern:7.4f}")  # fmt: skip
    say("(pattern: the variance of the exposure's clean image about its level, the whole pattern real (b) holds; "
        "the pack's fixed pattern is the dark burst's part of it)")  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repo", type=Path, required=True, help="a clone of EMVA1288/datasets (bare or not)")
    p.add_argument("--out", type=Path, default=Path("target/emva002"), help="the ladder's cache [default: %(default)s]")
    p.add_argument("--seeds", type=int, default=2, help="synthetic images per code and model [default: %(default)s]")
    p.add_argument("--cli", action="store_true", help="make missing packs with the `noisecal` command on PATH")
    p.add_argument("--json", type=Path, help="also write the per-code variances (DN²) and tails here")
    p.add_argument("--also", default="", help="codes above 16 to add, comma-separated (e.g. 22,54,104)")
    args = p.parse_args(argv)

    def say(*a):
        print(*a, file=sys.stderr, flush=True)

    try:
        src = Source(args.repo, ladder.SET)
        got = ladder.convert(src, args.out, say)
        for name, is_plain in (("ladder.pack", False), ("ladder-plain.pack", True)):
            if (args.out / name).exists():
                continue
            if args.cli:
                cmd = ["noisecal", "--quiet", "calibrate", str(args.out / "cal"), "-o", str(args.out / name)]
                subprocess.run(cmd + ["--plain"] * is_plain, check=True)
            else:
                noisecal.calibrate(args.out / "cal", plain=is_plain).save(args.out / name)
        pack = noisecal.Pack.load(args.out / "ladder.pack")
        plain = noisecal.Pack.load(args.out / "ladder-plain.pack")
        # mosaic_<m>: scene m (by number: "mosaic_10" sorts before "mosaic_2").
        scenes = sorted((d for d in (args.out / "eval-mosaic").iterdir() if d.is_dir()), key=lambda d: int(d.name.split("_")[-1]))
        frame = np.stack([noisecal.read_dng(d / "frame.dng")[0].astype(np.float64) for d in scenes])
        clean = np.stack([np.load(d / "clean.npy") for d in scenes])
        blocks = read_descriptor(src.read("EMVA1288_Data.txt").decode("utf-8", "replace"))
        burst = max((b for b in blocks if b.kind == "d"), key=lambda b: len(b.images))
        dark = np.stack([ladder.centre(read_png_grey(src.read(q), q, depths=(8,)), ladder.CAL_W) for q in burst.images]).astype(np.float64)
    except (ladder.ConvertError, noisecal.NoisecalError, OSError, subprocess.CalledProcessError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    black = float(np.mean(got["black"]))
    code = np.rint(clean)
    models = (("default", pack, None), ("own", pack, OWN), ("pixel", pack, "pixel"), ("plain", plain, None))
    # The benchmark's HG rows, drawn as its training pairs are (at the target ISO's brightness).
    bench_rows = ("hg", "wrong", "loud", "loud4=loud:4")

    def draw(name, pk, comp, flat):
        if comp == "bench":
            pairs = make_pairs(parse_model(name), 200, [flat], args.seeds, pk, {}, 0, {})
            return [n.astype(np.float64) for n in pairs.noisy[0]]
        return [pk.synth(flat, 200, k, components=comp).astype(np.float64) for k in range(args.seeds)]

    models += tuple((name.split("=")[0], pack, "bench") for name in bench_rows)
    full = {"default": None, "own": None, "pixel": None, "plain": None, **{n.split("=")[0]: n for n in bench_rows}}
    record: dict = {"black": None, "codes": []}
    print(f"black {black:.3f} DN; variance of noisy − clean (DN²), synthetic / real (−round) in brackets")
    print(f"{'code':>4} {'above':>6} {'pixels':>8} {'real −round':>12} {'real −float':>12}" + "".join(f" {m:>16}" for m, _, _ in models))
    shapes = []
    for c in list(range(1, 17)) + [int(v) for v in args.also.split(",") if v.strip()]:
        at = code == c
        if at.sum() < MIN_PIXELS:
            continue
        real_d = frame[at] - c
        real = float(real_d.var())
        flat = np.full(frame.shape[1:], c, np.uint16)
        row = []
        shapes.append((c, "real", real_d))
        entry = {"code": c, "above_black": c - float(np.mean(got["black"])), "pixels": int(at.sum()), "real": real, "real_float": float((frame[at] - clean[at]).var()), "models": {}}
        for name, pk, comp in models:
            s = np.concatenate([d.ravel() - c for d in draw(full[name] or name, pk, comp, flat)])
            row.append(f"{s.var():.4f} ({s.var() / real:.2f}×)")
            shapes.append((c, name, s))
            q = np.quantile(s, [0.001, 0.999], method="inverted_cdf")
            entry["models"][name] = {"var": float(s.var()), "mean": float(s.mean()), "q001": float(q[0]), "q999": float(q[1])}
        q = np.quantile(real_d, [0.001, 0.999], method="inverted_cdf")
        entry.update(real_mean=float(real_d.mean()), real_q001=float(q[0]), real_q999=float(q[1]))
        record["codes"].append(entry)
        print(f"{c:4d} {c - black:6.2f} {int(at.sum()):8d} {real:12.4f} {float((frame[at] - clean[at]).var()):12.4f}" + "".join(f" {r:>16}" for r in row))
    print("tails and shape of noisy − round(clean): 0.1 % / 99.9 % quantiles (DN), share of samples at −2 … +2 DN")
    print(f"{'code':>4} {'model':>8} {'q0.1%':>6} {'q99.9%':>6}" + "".join(f" {v:>+7d}" for v in range(-2, 3)))
    for c, name, d in shapes:
        q = np.quantile(d, [0.001, 0.999], method="inverted_cdf")
        share = [float(np.mean(d == v)) for v in range(-2, 3)]
        print(f"{c:4d} {name:>8} {q[0]:+6.0f} {q[1]:+6.0f}" + "".join(f" {v:7.4f}" for v in share))
    record["black"] = black
    record["exposures"] = like_with_like(frame, clean, got["black"], pack, args.seeds, print)
    if args.json:
        args.json.write_text(json.dumps(record, indent=1) + "\n")
    half = len(dark) // 2
    for name, part in (("ISO 100 (dark frames 1–50)", dark[:half]), ("ISO 200 (dark frames 51–100)", dark[half:])):
        terms = dark_terms(part)
        print(f"dark burst, {name}: " + ", ".join(f"{k} {v:.4f}" for k, v in terms.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
