"""A simulated tiled benchmark set where the truth is known: an 8-bit sensor like EMVA 1288 set
002 (sub-DN noise near black, a clamp at 0), laid out as set 002's tiled run
(tests/bench/emva1288_ladder.py) but with the sensor's own noise known, so the ``oracle`` row can
run.

    python tests/bench/sim_tiles.py --out /tmp/simtiles [noisecal-bench options]

- **The sensor** (``noisy``): ``clip(round(clean + N(0, A·(clean − BLACK) + B)), 0, WHITE)``, clean
  levels float DN; black 2.87 DN, ``A`` 0.019 DN per DN and ``B`` 0.01 DN² (set 002's slope; its
  black is the rounding alone). Clean images carry a fixed pattern (DSNU 0.1 DN, PRNU 0.5 %).
- **Calibration** (``OUT/cal``): a ladder of ``STEPS`` levels 3.5 DN apart from black, each one
  target frame ("ISO 200") against a burst of ``REF_FRAMES`` reference frames ("ISO 100", twice
  the exposure), and a 64-frame dark burst.
- **The reference bursts are the sensor's own frames** (``--references noise``, the default): each
  frame ``clip(round(clean + N(0, A_REF·(clean − BLACK) + B)), 0, WHITE)``, ``A_REF = A/2`` (ISO 100
  is half the gain at twice the exposure: the same DN, half the shot noise's variance in DN; the
  read noise ``B`` as the dark burst's ISO 100 half has it), drawn per pixel and frame. That is
  what a real reference burst gives: every frame rounded by the ADC with the sensor's noise
  before it, so its mean carries the lattice's bias ``E[round(c + e)] − c`` (at 0.2 DN of noise
  the frames mostly agree on ``round(c)``), and each frame's mean over the image moves only by
  ``σ/√N``. Until tiles11 they were an *ordered* dither, frame ``j`` ``floor(clean + (j + ½)/8)``
  (``--references ordered``, kept to measure against): one phase for every pixel of a frame, so
  whole frames moved by up to 0.94 DN (3.13 … 4.13 DN at the 3.5 DN step), which the calibration
  rightly refuses or normalises as a flickering lamp (docs/method.md, "The brightness rule at dim
  steps"). ``--references dither`` draws ``floor(clean + u)``, ``u`` uniform per pixel and frame:
  a noiseless, quantised burst whose mean is the clean level without the lattice's bias, and
  whose rounding errors are uniform whatever the noise, which no sub-DN sensor's are: its clean
  image ``round(mean)`` misses ``round(clean)`` at 4.3 / 17.2 / 1.2 / 29.8 / 5.6 / 18.2 / 2.5 %
  of the pixels of the steps 0 … 21 DN above black, the sensor's own bursts at 0.05 / 10.6 /
  0.5 / 26.3 / 5.9 / 18.9 / 3.6 % (``sim_tiles_probe.py``): more where the noise is far below
  1 DN, about as many from 14 DN up. The references draw from their own generator (``REF_SEED``): every other frame
  of the set is the same whichever kind is chosen. The kind is stamped in ``OUT/set.json``; a
  cache written with another kind is refused, not mixed.
- **Evaluation** (``OUT/eval-tiles``): held-out frames at set 002's 15 evaluated levels, as tiled
  scenes (tests/bench/emva1288.py's ``write_tiles``).
- **Training** (``OUT/train``, ``OUT/captures``): tile scenes of the evaluation's kind
  (``noisecal.bench.generate_tiles`` with the ladder and the fixed pattern's SD), and
  ``CAPTURES`` captures of each by the sensor, drawn about the scene before its rounding to
  whole DN: the oracle's training data; the float scene beside each clean DNG (``.npy``) is the
  oracle's target.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import noisecal
from noisecal import bench
from emva1288 import tile_training, write_tiles

WHITE, BLACK, CFA = 255, 2.87, "RGGB"
A, B = 0.019, 0.01  # the sensor's variance law before rounding: A·(level above black) + B (DN²)
A_REF = A / 2  # the reference ISO (100): half the gain at twice the exposure
REF_FRAMES = 8  # frames of each reference burst
REFERENCES = ("noise", "dither", "ordered")  # the kinds of reference burst (module docstring)
SEED, REF_SEED = 2002, 2003
DSNU, PRNU = 0.1, 0.005
STEPS = 37  # calibration levels 0, 3.5, … 126 DN above black
EVAL = [0.0, 0.1, 1.69, 4.7, 8.14, 11.59, 15.29, 19.02, 22.65, 36.88, 50.96, 64.12, 76.83, 89.04, 101.27]
CAL_SHAPE, EVAL_SHAPE, TRAIN_SHAPE = (256, 512), (256, 256), (256, 256)
TRAIN, CAPTURES = 24, 4
MAKE, MODEL = "simulated", "8-bit sub-DN sensor (sim_tiles.py)"


def variance(clean: np.ndarray, a: float = A) -> np.ndarray:
    """The sensor's noise variance before rounding at the float clean image ``clean`` (DN²)."""
    return a * np.maximum(clean - BLACK, 0.0) + B


def noisy(clean: np.ndarray, rng: np.random.Generator, a: float = A) -> np.ndarray:
    """One frame of the sensor at the float clean image ``clean`` (DN, black included); ``a`` the
    shot noise's slope (``A`` at the target ISO, ``A_REF`` at the reference ISO)."""
    return np.clip(np.rint(clean + rng.standard_normal(clean.shape) * np.sqrt(variance(clean, a))), 0, WHITE).astype(np.uint16)


def reference_burst(clean: np.ndarray, rng: np.random.Generator, kind: str) -> list[np.ndarray]:
    """The ``REF_FRAMES`` reference frames of a step at ``clean`` (module docstring)."""
    if kind == "noise":
        return [noisy(clean, rng, A_REF) for _ in range(REF_FRAMES)]
    if kind == "dither":
        return [np.clip(np.floor(clean + rng.random(clean.shape)), 0, WHITE).astype(np.uint16) for _ in range(REF_FRAMES)]
    if kind == "ordered":
        return [np.clip(np.floor(clean + (j + 0.5) / REF_FRAMES), 0, WHITE).astype(np.uint16) for j in range(REF_FRAMES)]
    raise ValueError(f"references {kind!r}: one of {', '.join(REFERENCES)}")


def fixed_pattern(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The clean images' fixed pattern over ``CAL_SHAPE`` (DSNU in DN, PRNU as a fraction): the
    first draws of the set's generator ``default_rng(SEED)``."""
    h, w = CAL_SHAPE
    return rng.standard_normal((h, w)) * DSNU, rng.standard_normal((h, w)) * PRNU


def flat(level: float, shape: tuple[int, int], pattern: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The clean image of a flat field ``level`` DN above black, with the sensor's fixed pattern."""
    dsnu, prnu = pattern
    return BLACK + dsnu[: shape[0], : shape[1]] + level * (1.0 + prnu[: shape[0], : shape[1]])


def write(path: Path, px: np.ndarray, iso: int, exposure_ns: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists():
        noisecal.write_raw_dng(path, px, cfa=CFA, black=[BLACK] * 4, white=WHITE, iso=iso, exposure_ns=exposure_ns, make=MAKE, model=MODEL)


def stamp(out: Path, references: str) -> None:
    """Records the reference kind in ``out/set.json``; refuses a cache written with another one
    (``write`` keeps existing files, so the two would mix)."""
    f = out / "set.json"
    if f.exists():
        got = json.loads(f.read_text()).get("references")
        if got != references:
            raise SystemExit(f"sim_tiles.py: {out} holds a set with references {got!r}, not {references!r}: pass another --out or delete it")
    elif (out / "cal").exists():
        raise SystemExit(f"sim_tiles.py: {out}/cal has no set.json (written before tiles11, ordered references): pass another --out or delete it")
    else:
        out.mkdir(parents=True, exist_ok=True)
        f.write_text(json.dumps({"references": references}) + "\n")


def convert(out: Path, say, references: str = "noise") -> dict:
    stamp(out, references)
    rng = np.random.default_rng(SEED)
    ref_rng = np.random.default_rng(REF_SEED)
    pattern = fixed_pattern(rng)
    for i in range(64):
        write(out / "cal" / f"dark_{i:03}.dng", noisy(flat(0.0, CAL_SHAPE, pattern), rng), 100 if i < 32 else 200, 1000)
    for k in range(STEPS):
        clean = flat(3.5 * k, CAL_SHAPE, pattern)
        ns = 40_000 * (k + 1)
        for j, ref in enumerate(reference_burst(clean, ref_rng, references)):
            write(out / "cal" / f"ref_{k:03}_{j}.dng", ref, 100, 2 * ns)
        write(out / "cal" / f"target_{k:03}.dng", noisy(clean, rng), 200, ns)
    held = []
    for i, level in enumerate(EVAL):
        clean = flat(level, EVAL_SHAPE, pattern)
        held.append((noisy(clean, rng), clean, 40_000 * (i + 1)))
    write_tiles(out / "eval-tiles", held, write)
    got = tile_training(held, [BLACK] * 4)
    layout = {"black": [BLACK] * 4, "white": WHITE}
    # The scenes before rounding: the captures are drawn about them, as the evaluation frames are
    # about the float clean image. Each scene is written twice: as a DNG rounded to whole DN (the
    # clean image every synthetic model draws its noise onto, and is trained to return) and as
    # ``.npy`` (float DN), the oracle's target (noisecal.bench.data.load_float_clean): its pairs are
    # then a capture against the clean image it was drawn about, as the evaluation's are. With the
    # DNG as its target (until bench9) the oracle was taught to return the rounding, which no
    # evaluation pair asks for (docs/bench.md, "the oracle's clean image").
    scenes = bench.generate_tiles(TRAIN, *TRAIN_SHAPE, layout, 7, 24, 1.0, (0.0, 105.0), got["ladder"], got["texture"], rounded=False)
    for j, scene in enumerate(scenes):
        write(out / "train" / f"tile{j:02}.dng", np.rint(scene).astype(np.uint16), 100, 80_000)
        if not (out / "train" / f"tile{j:02}.npy").exists():
            np.save(out / "train" / f"tile{j:02}.npy", scene)  # the float clean image: the oracle's target
        for k in range(CAPTURES):
            write(out / "captures" / f"tile{j:02}_{k}.dng", noisy(scene, rng), 200, 40_000)
    say(f"simulated set in {out}: {STEPS} calibration levels, {len(held)} evaluated, {TRAIN} training scenes × {CAPTURES} captures")
    return got


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=Path("target/simtiles"), help="the cache [default: %(default)s]")
    p.add_argument("--json", type=Path, help="noisecal-bench's results JSON [default: OUT/bench.json]")
    p.add_argument("--references", choices=REFERENCES, default="noise", help="the reference bursts (module docstring) [default: %(default)s]")
    args, rest = p.parse_known_args(argv)

    def say(*a):
        print(*a, file=sys.stderr, flush=True)

    convert(args.out, say, args.references)
    for name, is_plain in (("sim.pack", False), ("sim-plain.pack", True)):
        if not (args.out / name).exists():
            say(f"calibrating {name} from cal/")
            noisecal.calibrate(args.out / "cal", plain=is_plain).save(args.out / name)
    out = args.out
    return bench.main(
        [
            "--pack", str(out / "sim.pack"), "--plain-pack", str(out / "sim-plain.pack"),
            "--eval", str(out / "eval-tiles"), "--train", str(out / "train"), "--captures", str(out / "captures"),
            "--models", "oracle,noisecal,hg,pg,plain,wrong,loud",
            "--json", str(args.json or out / "bench.json"),
            *rest,
        ]
    )  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
