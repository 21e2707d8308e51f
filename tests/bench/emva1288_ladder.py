"""The denoiser benchmark on a real ladder of levels from black up: EMVA 1288 reference set 002.

    python tests/bench/emva1288_ladder.py --repo DATASETS [--out target/emva002] [noisecal-bench options]

``DATASETS`` is a clone (bare or not) of ``EMVA1288/datasets`` on GitHub. Its set 002 (Copyright
(C) 2011 STEMMER IMAGING GmbH, author Manfred Wuetschner; Creative Commons Attribution-ShareAlike
3.0 Unported, as its ``EMVA1288_Data.txt`` states; fetched, not committed here) is an 8-bit
monochrome CMOS camera, 2048×512: a flat field at 100
exposures 40 µs apart (photon-transfer pairs, two frames each, with a dark pair at each of the
first 26 exposures), a 100-frame burst at 140 µs and a 100-frame dark burst. Its exposures climb
about 3.5 DN apart from black (2.9 DN) to saturation, so it holds several real levels in the bench's
dark band (< 2 % of the range: 0, 0.1, 1.6 and 4.6 DN above black) where set 001
(tests/bench/emva1288.py) holds one (16 DN; docs/bench.md, "why the EMVA set does not rank the
models"). This script converts it to DNGs in ``--out`` (a cache: kept and reused), calibrates a
pack and a plain per-bin pack, and runs ``noisecal-bench`` with the models
``noisecal,hg,pg,plain,wrong,loud`` on generated grey dead-leaves scenes over the evaluated
levels; options after the script's own go to ``noisecal-bench``.

- **Clean images.** Each exposure's clean image is the flat field at its level:
  ``clean(t) = D + d(t) + s(t)·F``, with ``D`` the dark burst's mean (100 frames), ``d(t)`` the
  shift of the black level at ``t`` (its dark pair's mean minus ``D``'s; 0 where the set has no
  dark pair), ``s(t)`` the pair's mean signal and ``F`` the flat field's shape (mean 1): the sum
  of the pairs' signals between 2 % and 80 % of the range over the sum of their mean signals,
  the held-out frames left out. ``F`` pools about 120 frames, so its error at the evaluated levels
  is a small fraction of a DN (the noise is 0.3–1.4 DN). (The set's burst is at 6 DN above black: scaling its mean up to 100 DN, as set
  001's script does with its half-scale burst, would multiply its error by 16.)
- **Calibration** (``OUT/cal``, the frames' central ``CAL_W`` columns): every pair up to
  ``CAL_MAX`` of the range, its frame 0 a target ("ISO 200") against its clean image handed to
  the calibrator as a burst of 8 noiseless frames dithered to it ("ISO 100", twice the exposure:
  the same gain); the dark burst as the dark step.
- **Evaluation** (``OUT/eval-mosaic``, the central ``EVAL_W`` columns): frame 1 of each
  evaluated pair, held out, against its clean image, recombined into real-noise mosaics (scene m
  shows at each pixel the frame of level (label + m) mod k for a dead-leaves label map of k equal
  areas; tests/bench/emva1288.py's ``write_mosaics``): every pixel and its noise real. The
  evaluated pairs are every exposure below ``EVERY_BELOW`` of the range and every ``THEN_EVERY``th
  above it up to ``EVAL_MAX``. ``--scenes tiles`` (the default; ``--scenes mosaic`` the
  dead-leaves ones): the same frames as tiled mosaics
  (``OUT/eval-tiles``, tests/bench/emva1288.py's ``write_tiles``: a few large regions, edges
  blurred as by the optics), and training on generated tile scenes of that kind (``--tiles``, the
  held-out levels and the clean images' fixed pattern: ``tile_training``).
- **A CFA on a mono sensor**, as for set 001: the DNGs say RGGB; the four positions are four
  interleaved quarters of one sensor, modelled apart.
- **No oracle and no noiseprofile**: nobody knows this sensor's noise and its PNGs carry no
  NoiseProfile. The controls are the wrong model (HG at half its variance) and the loud one (HG
  at twice).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import noisecal
from noisecal import bench
from emva1288 import Block, Source, read_descriptor, tile_args, tile_training, write_mosaics, write_tiles
from png16 import ConvertError, read_png_grey

SET = "EMVA1288_ReferenceSet_002_CMOS_08Bit"
WHITE = 255
CFA = "RGGB"
MAKE, MODEL = "STEMMER IMAGING (EMVA 1288 set 002)", "8-bit mono CMOS, read as RGGB"
SHAPE_MAX = 0.8  # of the range above black: pairs below it make the flat field's shape F
CAL_MAX = 0.5  # of the range above black: pairs up to it calibrate
EVAL_MAX = 0.4  # of the range above black: pairs up to it may be evaluated
EVERY_BELOW = 0.1  # every pair below this is evaluated (the dark and shadow bands)
THEN_EVERY = 4  # above it, every 4th pair
REF_FRAMES = 8  # frames of each dithered reference burst
EXPOSURE_UNIT_NS = 1000  # set 002's descriptor gives exposure times in µs (set 001's in ns)
CAL_W = 1024  # central columns calibrated (of 2048)
EVAL_W = 512  # central columns evaluated


def dithered(clean: np.ndarray, n: int) -> list[np.ndarray]:
    """``n`` uint16 frames without noise whose mean is ``clean`` within 1/(2n) DN (tests/bench/emva1288.py's
    ``dithered_burst`` at this set's white level)."""
    return [np.clip(np.floor(clean + (i + 0.5) / n), 0, WHITE).astype(np.uint16) for i in range(n)]


def flat_shape(signals: list[np.ndarray]) -> np.ndarray:
    """The flat field's shape, mean 1: the pooled signal over its mean (each ``signal`` a pair's
    mean frame minus the black level at its exposure)."""
    total = np.sum(signals, axis=0)
    return total / float(total.mean())


def ladder(levels: list[float]) -> list[int]:
    """Which of the pairs (their levels, a fraction of the range, ascending) are evaluated."""
    low = [i for i, v in enumerate(levels) if v < EVERY_BELOW]
    high = [i for i, v in enumerate(levels) if EVERY_BELOW <= v <= EVAL_MAX]
    return low + high[THEN_EVERY - 1 :: THEN_EVERY]


def centre(img: np.ndarray, width: int) -> np.ndarray:
    x0 = (img.shape[1] - width) // 2 // 2 * 2  # even: the CFA phase
    return img[:, x0 : x0 + width]


def convert(src: Source, out: Path, say) -> dict:
    """Writes ``out/cal`` and ``out/eval-mosaic``; returns the black levels, the pairs and the
    evaluated levels."""
    blocks = read_descriptor(src.read("EMVA1288_Data.txt").decode("utf-8", "replace"))
    frames = lambda b: [read_png_grey(src.read(p), p, depths=(8,)) for p in b.images]  # noqa: E731
    bright = [b for b in blocks if b.kind == "b"]
    darks = [b for b in blocks if b.kind == "d"]
    burst_d = max(darks, key=lambda b: len(b.images))
    if len(burst_d.images) < 20:
        raise ConvertError(f"{SET}/EMVA1288_Data.txt: no dark burst (the longest dark block has {len(burst_d.images)} frames)")
    say(f"reading the {len(burst_d.images)}-frame dark burst")
    dark = np.stack(frames(burst_d)).astype(np.float64)
    d_mean = dark.mean(axis=0)
    black = [float(v) for v in bench.pack_raw(d_mean).mean(axis=(1, 2))]
    span = WHITE - float(np.mean(black))
    dark_by_ns = {b.exposure_ns: b for b in darks if len(b.images) == 2}
    pairs: list[tuple[Block, list[np.ndarray], float]] = []
    say(f"reading {sum(len(b.images) == 2 for b in bright)} photon-transfer pairs")
    for b in bright:
        if len(b.images) != 2:
            continue
        pair = [f.astype(np.float64) for f in frames(b)]
        shift = float(np.mean([f.mean() for f in frames(dark_by_ns[b.exposure_ns])])) - float(d_mean.mean()) if b.exposure_ns in dark_by_ns else 0.0
        pairs.append((b, pair, shift))
    pairs.sort(key=lambda x: x[0].exposure_ns)
    signal = [float(np.mean([f.mean() for f in p])) - float(d_mean.mean()) - s for _, p, s in pairs]
    level = [v / span for v in signal]
    evaluated = set(ladder(level))
    # The shape from every pair's frames but the held-out ones (frame 1 of an evaluated pair).
    shape_of = [i for i, v in enumerate(level) if 0.02 < v < SHAPE_MAX]
    shape = flat_shape([np.mean(pairs[i][1][: 1 if i in evaluated else 2], axis=0) - d_mean - pairs[i][2] for i in shape_of])

    def write(path: Path, px: np.ndarray, iso: int, exposure_ns: int):
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists():
            noisecal.write_raw_dng(
                path, px, cfa=CFA, black=black, white=WHITE, iso=iso, exposure_ns=exposure_ns, make=MAKE, model=MODEL
            )

    half = len(dark) // 2
    for i, f in enumerate(dark):
        write(out / "cal" / f"dark_{i:03}.dng", centre(f, CAL_W).astype(np.uint16), 100 if i < half else 200, burst_d.exposure_ns * EXPOSURE_UNIT_NS)
    held = []
    for i, ((b, pair, shift), s, v) in enumerate(zip(pairs, signal, level)):
        if v > CAL_MAX:
            continue
        clean = d_mean + shift + s * shape
        us = b.exposure_ns  # the descriptor's µs (read_descriptor keeps its number as "ns")
        ns = max(us * EXPOSURE_UNIT_NS, 1000)  # the first exposure is 0 µs: a DNG needs one above 0 (1 µs)
        for k, f in enumerate(dithered(centre(clean, CAL_W), REF_FRAMES)):
            write(out / "cal" / f"ref_{us:05}us_{k}.dng", f, 100, 2 * ns)
        write(out / "cal" / f"target_{us:05}us.dng", centre(pair[0], CAL_W).astype(np.uint16), 200, ns)
        if i in evaluated:
            held.append((centre(pair[1], EVAL_W).astype(np.uint16), centre(clean, EVAL_W), ns))
    write_mosaics(out / "eval-mosaic", held, write)
    write_tiles(out / "eval-tiles", held, write)
    top = max(float(c.max()) for _, c, _ in held) - min(black)
    levels = sorted(round(float(c.mean()) - float(np.mean(black)), 2) for _, c, _ in held)
    say(f"black levels {[round(v, 3) for v in black]} DN; {sum(v <= CAL_MAX for v in level)} pairs calibrate; "
        f"{len(held)} evaluated, clean levels {levels} DN above black")  # fmt: skip
    return {"black": black, "levels": levels, "top": float(np.ceil(top)), **tile_training(held, black)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repo", type=Path, required=True, help="a clone of EMVA1288/datasets (bare or not)")
    p.add_argument("--out", type=Path, default=Path("target/emva002"), help="the cache [default: %(default)s]")
    p.add_argument("--generate", type=int, default=24, help="generated training scenes [default: %(default)s]")
    p.add_argument(
        "--scenes",
        choices=("mosaic", "tiles"),
        default="tiles",
        help="evaluate on the dead-leaves real-noise mosaics (OUT/eval-mosaic) or on the tiled ones (OUT/eval-tiles: "
        "a few large regions, blurred edges) and train on generated tile scenes of their kind [default: %(default)s]",
    )
    p.add_argument("--json", type=Path, help="noisecal-bench's results JSON [default: OUT/bench.json]")
    args, rest = p.parse_known_args(argv)

    def say(*a):
        print(*a, file=sys.stderr, flush=True)

    try:
        got = convert(Source(args.repo, SET), args.out, say)
        for name, is_plain in (("ladder.pack", False), ("ladder-plain.pack", True)):
            if not (args.out / name).exists():
                say(f"calibrating {name} from cal/")
                noisecal.calibrate(args.out / "cal", plain=is_plain).save(args.out / name)
    except (ConvertError, noisecal.NoisecalError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    out = args.out
    return bench.main(
        [
            "--pack", str(out / "ladder.pack"),
            "--plain-pack", str(out / "ladder-plain.pack"),
            "--eval", str(out / f"eval-{args.scenes}"),
            "--generate", str(args.generate), "--mono", "--generate-levels", f"0,{got['top']:g}",
            *(tile_args(got) if args.scenes == "tiles" else []),
            "--models", "noisecal,hg,pg,plain,wrong,loud",
            "--json", str(args.json or out / "bench.json"),
            *rest,
        ]
    )  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
