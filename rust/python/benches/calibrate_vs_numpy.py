"""`noisecal calibrate` against a plain vectorised numpy implementation of the same calibration,
side by side in one run: both are whole processes started on the same DNG folder (16 frames of
12 MP by default: a reference burst of 8 at the base ISO and a target burst of 8 at ISO 800, one
EV step), run alternately, and the medians compared. The bound the project keeps is
noisecal / numpy ≤ 0.25.

    python rust/python/benches/calibrate_vs_numpy.py [--rounds 5] [--session DIR] [--bin PATH]

Needs numpy alone (not the noisecal package): the DNGs are read here from their uncompressed
strips. Without --session a session is simulated with the CLI into a temporary folder
(`NOISECAL_BIN`, --bin, or target/release/noisecal). `--numpy-only DIR` runs the numpy
calibration once on DIR and prints what it found (the subprocess that is timed).

What the numpy side computes, per ISO and CFA position (docs/method.md, *Calibration* and
*Estimation*, as far as whole-array numpy reasonably goes):
- the reference burst summed per pixel, its first frame kept; the clean image `round(mean)`;
- each pixel's spread over the burst; the noise of the mean per level group (64 groups) as a
  line fitted on the groups' mean spreads; flat pixels: within `4.5·√(2·var) + 0.5` DN of their
  four same-position neighbours 2 px away and whose spread stays under 3.5× the line's;
- per target frame (fold `i mod 4`), the histogram of `frame − clean` over flat pixels by bin of
  the clean level (4 DN bins), one `bincount` per frame and position; the gain ratio
  `Σ(target − black) / Σ(clean − black)`;
- the pooling size `m` per position from {0, 16, …, 262144} by 4-fold held-out log-likelihood:
  each bin pooled with its neighbours ring by ring (window sums by cumulative sums over bins, for
  every bin at once) until it holds `m` samples, plus a pseudo-count, scored on the held-out fold;
  the PMFs of the chosen `m` from all folds.
Left out, where noisecal does more: moving pooled neighbours onto the bin by the noise law (the
numpy side pools them as measured), drift and motion checks, clipping, output codes, structured
components. The numpy side thus does less work than noisecal, so the ratio is if anything
flattering to numpy.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[3]
BIN_WIDTH = 4
CANDIDATES = (0, 16, 64, 256, 1024, 4096, 16384, 65536, 262144)
FOLDS = 4


def cli(given: str | None) -> str:
    exe = given or os.environ.get("NOISECAL_BIN") or str(REPO / "target" / "release" / "noisecal")
    if not Path(exe).exists():
        subprocess.run(["cargo", "build", "-q", "--release", "-p", "noisecal-cli"], cwd=REPO, check=True)
    return exe


# --- DNG (uncompressed strips, as the simulator and Android's DngCreator write them) -----------


def read_dng(path: Path) -> tuple[np.ndarray, int, float, np.ndarray, int]:
    """(pixels h×w u16, ISO, exposure s, black per 2×2 position, white)."""
    raw = path.read_bytes()
    bo = "<" if raw[:2] == b"II" else ">"
    sizes = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 7: 1, 10: 8}
    codes = {1: "B", 3: "H", 4: "I", 7: "B"}

    def entries(off: int) -> dict[int, tuple[int, int, int]]:
        (n,) = struct.unpack_from(bo + "H", raw, off)
        out = {}
        for i in range(n):
            tag, typ, cnt = struct.unpack_from(bo + "HHI", raw, off + 2 + 12 * i)
            at = off + 10 + 12 * i
            if sizes.get(typ, 1) * cnt > 4:
                (at,) = struct.unpack_from(bo + "I", raw, at)
            out[tag] = (typ, cnt, at)
        return out

    def values(e: tuple[int, int, int]) -> list[float]:
        typ, cnt, at = e
        if typ in (5, 10):
            f = "I" if typ == 5 else "i"
            pairs = struct.unpack_from(bo + f * (2 * cnt), raw, at)
            return [pairs[2 * i] / pairs[2 * i + 1] for i in range(cnt)]
        return list(struct.unpack_from(bo + codes[typ] * cnt, raw, at))

    (first,) = struct.unpack_from(bo + "I", raw, 4)
    ifd = entries(first)
    w, h = int(values(ifd[256])[0]), int(values(ifd[257])[0])
    if int(values(ifd[259])[0]) != 1 or int(values(ifd[258])[0]) != 16:
        raise SystemExit(f"{path}: only uncompressed 16-bit DNGs are read here")
    offsets, counts = values(ifd[273]), values(ifd[279])
    parts = [np.frombuffer(raw, dtype=bo + "u2", count=int(c) // 2, offset=int(o)) for o, c in zip(offsets, counts)]
    pixels = np.concatenate(parts)[: w * h].reshape(h, w).astype(np.uint16, copy=False)
    exif = entries(int(values(ifd[34665])[0]))
    iso = int(values(exif[34855])[0])
    exposure = float(values(exif[33434])[0])
    black = np.resize(np.array(values(ifd[50714]), dtype=np.float64), 4)
    white = int(values(ifd[50717])[0])
    return pixels, iso, exposure, black, white


# --- the calibration ---------------------------------------------------------------------------


def positions(a: np.ndarray) -> list[np.ndarray]:
    return [a[py::2, px::2] for py in (0, 1) for px in (0, 1)]


def reference_clean(paths: list[Path]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(clean image, per-pixel variance over the burst, flat mask)."""
    first = None
    total = None
    sq = None
    for p in paths:
        px, _, _, _, _ = read_dng(p)
        f = px.astype(np.int32)
        if first is None:
            first, total, sq = f, np.zeros(f.shape, np.int64), np.zeros(f.shape, np.int64)
        d = f - first
        total += d
        sq += d.astype(np.int64) ** 2
    m = len(paths)
    mean = first + total / m
    clean = np.rint(mean).astype(np.int32)
    spread = (sq - total.astype(np.float64) ** 2 / m) / max(m - 1, 1)
    # The noise of the mean per level group, a line fitted on the groups' mean spreads.
    groups = np.clip(clean * 64 // (int(clean.max()) + 1), 0, 63).ravel()
    n = np.bincount(groups, minlength=64)
    s = np.bincount(groups, weights=spread.ravel(), minlength=64)
    lv = np.bincount(groups, weights=clean.ravel().astype(np.float64), minlength=64)
    ok = n > 0
    slope, icpt = np.polyfit(lv[ok] / n[ok], s[ok] / n[ok], 1, w=np.sqrt(n[ok]))
    var_line = np.maximum(icpt + slope * clean, 1e-3)
    thr = 4.5 * np.sqrt(2 * var_line / m) + 0.5
    flat = spread <= 3.5 * var_line
    for dy, dx in ((2, 0), (-2, 0), (0, 2), (0, -2)):
        nb = np.roll(clean, (dy, dx), axis=(0, 1))
        flat &= np.abs(clean - nb) <= thr
    flat[:2, :] = flat[-2:, :] = False
    flat[:, :2] = flat[:, -2:] = False
    return clean, spread, flat


def pooled_scores(hist: np.ndarray) -> tuple[int, np.ndarray]:
    """Per-fold histograms (folds × bins × values) → (chosen m, the PMFs from all folds)."""
    folds, nbins, nvals = hist.shape
    best = None
    for m in CANDIDATES:
        score = 0.0
        for k in range(folds):
            train = hist.sum(axis=0) - hist[k]
            pmf = pool(train, m)
            score += float((hist[k] * np.log(pmf)).sum())
        if best is None or score > best[0]:
            best = (score, m)
    assert best is not None
    return best[1], pool(hist.sum(axis=0), best[1])


def pool(train: np.ndarray, m: int) -> np.ndarray:
    """Each bin's histogram plus its neighbours' ring by ring until it holds `m` samples (at
    most 32 rings), with one pseudo-sample spread evenly; normalised."""
    nbins, nvals = train.shape
    counts = train.sum(axis=1)
    csum = np.concatenate([np.zeros(1), np.cumsum(counts)])
    rings = np.zeros(nbins, dtype=np.int64)
    if m > 0:
        b = np.arange(nbins)
        need = np.ones(nbins, dtype=bool)
        for r in range(33):
            lo, hi = np.clip(b - r, 0, nbins), np.clip(b + r + 1, 0, nbins)
            have = csum[hi] - csum[lo]
            rings[need] = r
            need &= have < m
            if not need.any():
                break
    b = np.arange(nbins)
    lo, hi = np.clip(b - rings, 0, nbins), np.clip(b + rings + 1, 0, nbins)
    c2 = np.concatenate([np.zeros((1, nvals)), np.cumsum(train, axis=0)], axis=0)
    pooled = c2[hi] - c2[lo]
    n = pooled.sum(axis=1, keepdims=True)
    pmf = pooled / np.maximum(n, 1) * (n / (n + 1)) + 1.0 / (n + 1) / nvals
    return pmf


def numpy_calibrate(folder: Path) -> dict:
    files = sorted(folder.glob("*.dng"))
    meta = {}
    for f in files:
        _, iso, exp, black, white = read_dng(f)
        meta[f] = (iso, exp, black, white)
    base = min(v[0] for v in meta.values())
    bursts: dict[tuple[int, float], list[Path]] = {}
    for f, (iso, exp, _, _) in meta.items():
        bursts.setdefault((iso, round(exp, 9)), []).append(f)
    result = {}
    for (iso, exp), frames in sorted(bursts.items()):
        if iso == base:
            continue
        ref = next(v for (i, e), v in bursts.items() if i == base and abs(i * e - iso * exp) <= 0.01 * iso * exp)
        black, white = meta[frames[0]][2], meta[frames[0]][3]
        clean, _, flat = reference_clean(ref)
        cp, fp = positions(clean), positions(flat)
        nb = (white + BIN_WIDTH) // BIN_WIDTH
        bins = [np.clip((c[f] - int(round(black[p]))) // BIN_WIDTH, 0, nb - 1) for p, (c, f) in enumerate(zip(cp, fp))]
        span = 2 * white + 1
        hist = [np.zeros((FOLDS, nb * span), np.int64) for _ in range(4)]
        gain_num, gain_den = np.zeros(4), np.zeros(4)
        for i, path in enumerate(sorted(frames)):
            px, _, _, _, _ = read_dng(path)
            for p, (t, c, f) in enumerate(zip(positions(px.astype(np.int32)), cp, fp)):
                tv, cv = t[f], c[f]
                n = tv - cv + white
                hist[p][i % FOLDS] += np.bincount(bins[p] * span + n, minlength=nb * span)
                gain_num[p] += (tv - black[p]).sum()
                gain_den[p] += (cv - black[p]).sum()
        for p in range(4):
            h = hist[p].reshape(FOLDS, nb, span)
            used = np.nonzero(h.sum(axis=(0, 1)))[0]
            h = h[:, :, used.min() : used.max() + 1].astype(np.float64)
            m, pmf = pooled_scores(h)
            result[(iso, p)] = {"m": m, "gain": gain_num[p] / gain_den[p], "samples": int(h.sum()), "bins": pmf.shape[0]}
    return result


# --- the side-by-side run -----------------------------------------------------------------------


def timed(cmd: list[str]) -> tuple[float, float, float, float]:
    """(wall s, CPU s of the process: user + system, its system s, its minor page faults)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    system = r1.ru_stime - r0.ru_stime
    return wall, (r1.ru_utime - r0.ru_utime) + system, system, float(r1.ru_minflt - r0.ru_minflt)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--session", type=Path, default=None)
    ap.add_argument("--bin", default=None, help="the noisecal binary (several, comma-separated, alternate)")
    ap.add_argument("--numpy-only", type=Path, default=None)
    a = ap.parse_args()
    if a.numpy_only:
        for (iso, p), r in sorted(numpy_calibrate(a.numpy_only).items()):
            print(f"ISO {iso} position {p}: m {r['m']}, gain {r['gain']:.4f}, {r['samples']} samples, {r['bins']} bins")
        return
    exes = [cli(b) for b in (a.bin.split(",") if a.bin else [None])]
    with tempfile.TemporaryDirectory() as t:
        d = Path(t)
        session = a.session
        if session is None:
            session = d / "session"
            subprocess.run([exes[0], "-q", "simulate", "--dngs", str(session), "--width", "4000", "--height", "3000",
                            "--frames", "8", "--isos", "800", "--ev=0", "--seed", "5"], check=True)
        nframes = len(list(session.glob("*.dng")))
        times: dict[str, list[tuple[float, float, float, float]]] = {"numpy": [], **{e: [] for e in exes}}
        for _ in range(a.rounds):
            times["numpy"].append(timed([sys.executable, __file__, "--numpy-only", str(session)]))
            for e in exes:
                times[e].append(timed([e, "-q", "calibrate", str(session), "-o", str(d / "p.pack")]))
    load = os.getloadavg()
    print(f"\ncalibrate, {nframes} frames from {session.name}, {a.rounds} rounds alternating, "
          f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores")
    # Wall time is what a user waits; on a shared machine the CPU time (user + system) of each
    # process says more about the work, so both are given.
    for i, what in enumerate(("wall", "CPU")):
        med = {k: statistics.median(x[i] for x in v) for k, v in times.items()}
        print(f" {what} time:")
        for k, v in times.items():
            print(f"  {k:60s} median {med[k]:7.2f} s  (runs: {', '.join(f'{x[i]:.2f}' for x in v)})")
        for e in exes:
            print(f"  noisecal / numpy ({e}): {med[e] / med['numpy']:.3f}   (bound ≤ 0.25)")
    # Where the system time goes: mostly the kernel zeroing pages faulted in for fresh buffers.
    print(" system time and minor page faults (medians):")
    for k, v in times.items():
        print(f"  {k:60s} system {statistics.median(x[2] for x in v):6.2f} s  "
              f"faults {statistics.median(x[3] for x in v):9.0f}")

if __name__ == "__main__":
    main()
