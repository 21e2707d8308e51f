"""The denoiser benchmark on real captures: the EMVA 1288 reference set 001, in one command.

    python tests/bench/emva1288.py --repo DATASETS [--out target/emva001] [noisecal-bench options]

``DATASETS`` is a clone (bare or not) of the EMVA 1288 datasets repository (``EMVA1288/datasets``
on GitHub: ``git clone --bare https://github.com/EMVA1288/datasets target/emva/datasets.git``).
Its set 001 (Basler AG, CC BY-SA 3.0) is a 12-bit monochrome CCD, 640×480: a flat field lit at
50 exposures (photon-transfer pairs, two frames each, with dark pairs), a 50-frame burst at 5.16 ms
(about half scale) and a 50-frame dark burst. This script converts it to DNGs in ``--out`` (a cache:
kept and reused), calibrates a pack and a plain per-bin pack from it, and runs ``noisecal-bench``
with the models ``noisecal,hg,pg,plain,wrong,loud`` on generated grey dead-leaves scenes (``--generate
--mono``); options after the script's own go to ``noisecal-bench`` (``--steps``, ``--seeds``,
``--input-scale``, …).

By default it benchmarks **low light**, where noise matters: the packs (``OUT/low.pack``,
``OUT/low-plain.pack``) are calibrated from ``OUT/cal-low`` — the burst's step and the dark burst
of ``OUT/cal``, plus the photon-transfer exposures up to 20 % of the range, each a reference burst
of 8 noiseless frames dithered to the exposure's derived clean image (below) with frame 0 of the
pair as its target. Held out: frame 1 of the pairs below 10 % of the range (0.04, 0.32, 0.62,
0.90 ms: 16–346 DN above black), against the same clean images (``OUT/eval-low``). Flat fields
reward smoothing, not fidelity (a network trained on too much noise smooths more and wins), so the
evaluation set is made of them as **real-noise mosaics** (``OUT/eval-mosaic``, 4 scenes): scene m
shows at each pixel the held-out frame of exposure (label + m) mod 4, the label a dead-leaves map
split into 4 equal areas, with that frame's clean image — every pixel and its noise real, at its
own level and position, each used once over the 4 scenes, and edges between levels that a network
must keep (``--flat-eval`` evaluates on the flat fields themselves). ``--scenes tiles`` (the
default; ``--scenes mosaic`` for the dead-leaves mosaics above) evaluates on **tiled** mosaics (``OUT/eval-tiles``, :func:`write_tiles`: ``TILES`` large Voronoi
regions, edges blurred by a Gaussian of ``TILE_BLUR`` px, each edge pixel the real pixel of the
held-out frame nearest the blurred level) and trains on generated tile scenes of the same kind
(``noisecal-bench --tiles``, with the held-out levels as ``--tile-ladder`` and the clean images'
fixed pattern as ``--tile-texture``, :func:`tile_training`): the dead-leaves mosaics are mostly edge, and a network trained on
other scenes than it is scored on is not ranked by how right its noise is (docs/bench.md, "Tiled
real-noise scenes"). The training scenes are
spread over the evaluated levels (0 to the brightest evaluated clean level). ``--band`` runs the earlier configuration instead: the packs from ``OUT/cal`` alone,
evaluated on the held-out burst frames at half scale (``OUT/eval``).

What is assumed, and why (docs/bench.md, "Real data: EMVA 1288 set 001"):

- **A CFA on a mono sensor.** noisecal keeps its models per CFA position; the DNGs say RGGB, so
  the four positions are four interleaved quarters of one monochrome sensor, modelled apart.
- **ISO labels.** The camera has one gain. As for the earlier calibration of this burst, its first
  25 frames are the reference burst at "ISO 100" with twice the exposure and its other frames the
  targets at "ISO 200" at 5.16 ms: the same ISO × exposure, the same (true) gain, so the pack's
  ISO 200 is this sensor's noise. Frames 25–36 calibrate; frames 37–49 are held out for evaluation.
- **The dark burst** is the dark step (the fixed pattern), 25 frames at each label, and its mean
  per CFA position is the black level the DNGs carry.
- **One band of levels (``--band``).** The set's only bursts are at one exposure: a pack from them
  is measured on the flat field's clean levels (1944–1995 DN above black), and a non-parametric
  pack has no samples elsewhere (no noisecal pack extrapolates a level it never saw). So the
  training scenes are grey dead leaves spread over that band (``--generate-levels``, measured
  here from the burst), and the evaluation set (``OUT/eval``) is the held-out burst frames against the reference burst's mean.
  ``--flat`` trains on flat fields instead (``OUT/train-flat``: 12 constant images at levels
  across the band), the evaluation scene's own kind: texture within the band is no stronger
  than the noise, so generated scenes teach a network little.
- **The photon-transfer pairs** (two frames per exposure) cannot calibrate against one of their own
  frames: a one-frame reference keeps its whole noise in the samples (the reference's error is part
  of them by convention), which doubles the variance. Against their *derived* clean image (below)
  they can: that image's error is the dark burst mean's (SD ≈ 3.7/√50 ≈ 0.5 DN) times 1 − s and the
  burst mean's (SD ≈ 24/√25 ≈ 4.9 DN) times the exposure's scale s, 0.5–0.9 DN on the evaluated
  exposures against a noise SD of 3.7–10.5 DN (0.7–1.9 % of the variance; in the evaluation it
  adds the same small floor to every model's error). It is handed to the calibrator as a burst of 8 frames
  ``floor(clean + (i + ½)/8)``, whose mean is the clean image within 1/16 DN (``OUT/cal-low``).
  Every 4th pair below 80 % is also written as an evaluation scene of its own in ``OUT/eval-pairs``
  (``--eval OUT/eval-pairs`` runs them; every pair below 80 % of the range, every 4th exposure),
  each with its clean image as ``clean.npy``: the flat field is the same at every exposure up to
  its scale, so clean(t) = D + s·(B − D) + (d̄(t) − D̄), with B the burst's clean image, D the dark
  burst's mean, s the pair's mean signal over B's (over all 307 200 pixels: its sampling error is
  ~10⁻⁴ of the level), and d̄(t) − D̄ the dark pair's shift of the black level at t. They lie
  outside the pack's band: a run on them shows what a pack does off its levels.
- **No oracle.** Nobody knows this sensor's noise; the controls are the wrong model (HG at half
  its variance), which must score clearly worst, and the noisy input.

The frames are read from the repository's 16-bit greyscale PNGs (numpy and zlib alone: the
package keeps numpy as its only dependency; filter type 0, as every frame of set 001 has; another
filter is refused by name).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import noisecal
from noisecal import bench
from png16 import ConvertError, read_png16

SET = "EMVA1288_ReferenceSet_001_CCD_12Bit"
BURST_EXPOSURE_NS = 5_160_000
REFERENCE = 25  # burst frames that make the reference burst (the clean image)
CALIBRATION_TARGETS = 12  # burst frames after those that calibrate; the rest are held out
WHITE = 4095
CFA = "RGGB"
MAKE, MODEL = "Basler (EMVA 1288 set 001)", "12-bit mono CCD, read as RGGB"
PAIR_EVERY = 4  # every 4th photon-transfer exposure is an evaluation scene
PAIR_MAX = 0.8  # of the range above black: brighter pairs are left out (near saturation)
FLAT_TRAIN = 12  # flat training images for --flat
LOW_CAL_MAX = 0.2  # of the range above black: photon-transfer exposures up to this level calibrate the low pack
LOW_EVAL_MAX = 0.1  # of the range above black: photon-transfer exposures below this level are evaluated (low light)
LOW_REF_FRAMES = 8  # frames of each derived (noiseless, dithered) reference burst
MOSAIC_SEED = 1288  # the dead-leaves label maps of the real-noise mosaics (OUT/eval-mosaic)


@dataclass
class Block:
    """One line of the set's descriptor: a bright (``b``) or dark (``d``) setting and its images."""

    kind: str
    exposure_ns: int
    images: list[str] = field(default_factory=list)


def read_descriptor(text: str) -> list[Block]:
    """EMVA1288_Data.txt: ``b <exposure ns> <photons>`` / ``d <exposure ns>`` lines, each followed
    by its ``i <image path>`` lines."""
    blocks: list[Block] = []
    for line in text.splitlines():
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        if parts[0] in ("b", "d"):
            blocks.append(Block(parts[0], int(round(float(parts[1])))))
        elif parts[0] == "i":
            if not blocks:
                raise ConvertError(f"EMVA1288_Data.txt: image {parts[1]} before any b/d line")
            blocks[-1].images.append(parts[1].replace("\\", "/"))
    return blocks


class Source:
    """A data set's files (``name``, set 001 unless told), from a git repository (bare or not:
    ``git show HEAD:path``) or a folder."""

    def __init__(self, repo: Path, name: str = SET):
        self.repo, self.name = Path(repo), name
        self.folder = self.repo / name if (self.repo / name).is_dir() else None
        if self.folder is None:
            probe = subprocess.run(["git", "-C", str(self.repo), "rev-parse", "--git-dir"], capture_output=True)
            if probe.returncode != 0:
                raise ConvertError(
                    f"--repo {self.repo}: neither a clone of EMVA1288/datasets nor a folder holding {name}/: clone it "
                    "with git clone --bare https://github.com/EMVA1288/datasets target/emva/datasets.git"
                )

    def read(self, path: str) -> bytes:
        if self.folder is not None:
            return (self.folder / path).read_bytes()
        r = subprocess.run(["git", "-C", str(self.repo), "show", f"HEAD:{self.name}/{path}"], capture_output=True)
        if r.returncode != 0:
            raise ConvertError(f"{self.name}/{path}: not in {self.repo} ({r.stderr.decode(errors='replace').strip()})")
        return r.stdout

    def frames(self, block: Block) -> list[np.ndarray]:
        return [read_png16(self.read(p), p) for p in block.images]


def pair_clean(burst_clean: np.ndarray, dark: np.ndarray, pair: list[np.ndarray], dark_pair: list[np.ndarray]) -> np.ndarray:
    """The clean flat field of a photon-transfer pair (module docstring): the burst's clean image
    scaled to the pair's mean signal, on the black level of the pair's dark frames."""
    d_mean = float(dark.mean())
    d_shift = float(np.mean([f.mean() for f in dark_pair])) - d_mean
    signal = float(np.mean([f.mean() for f in pair])) - d_mean - d_shift
    s = signal / (float(burst_clean.mean()) - d_mean)
    return dark + s * (burst_clean - dark) + d_shift


def dithered_burst(clean: np.ndarray, n: int) -> list[np.ndarray]:
    """``n`` uint16 frames without noise whose mean is ``clean`` to within 1/(2n) DN: frame ``i`` is
    ``floor(clean + (i + ½)/n)`` (a derived clean image handed to the calibrator as a reference burst)."""
    return [np.clip(np.floor(clean + (i + 0.5) / n), 0, WHITE).astype(np.uint16) for i in range(n)]


def mosaic_labels(shape: tuple[int, int], classes: int, seed: int) -> np.ndarray:
    """A dead-leaves label map (0 … classes − 1, about equal areas): grey dead leaves split at their
    quantiles, so the mosaic's regions have the natural scenes' edges and sizes."""
    grey = bench.dead_leaves(shape[0], shape[1], np.random.default_rng(seed)).mean(-1)
    cuts = np.quantile(grey, np.linspace(0, 1, classes + 1)[1:-1])
    return np.searchsorted(cuts, grey, side="right")


def write_mosaics(folder: Path, held: list, write) -> None:
    """Real-noise mosaics: evaluation scenes with edges whose every pixel is a real noisy pixel.
    The held-out frames are flat fields at a few levels; scene ``m`` shows, at each pixel, the
    frame of exposure ``(label + m) mod k`` (``label`` from :func:`mosaic_labels`) with that frame's
    clean image, so each real pixel appears once over the ``k`` scenes, at its own level and
    position (its noise is the sensor's, untouched), and a network that smooths across an edge
    between levels pays for it, which flat fields never make it do."""
    k = len(held)
    if k < 2:
        return
    labels = mosaic_labels(held[0][0].shape, k, MOSAIC_SEED)
    for m in range(k):
        pick = (labels + m) % k
        frame = np.choose(pick, [f for f, _, _ in held]).astype(np.uint16)
        clean = np.choose(pick, [c for _, c, _ in held])
        scene = folder / f"mosaic_{m}"
        scene.mkdir(parents=True, exist_ok=True)
        if not (scene / "clean.npy").exists():
            np.save(scene / "clean.npy", clean)
        write(scene / "frame.dng", frame, 200, held[0][2])


TILES = 24  # --scenes tiles: regions per tiled evaluation scene
TILE_BLUR = 1.0  # --scenes tiles: the edges' Gaussian blur in raw pixels (a sharp lens's)


def tile_plan(shape: tuple[int, int], k: int, tiles: int, seed: int) -> np.ndarray:
    """The tiled scenes' class map (0 … k − 1): :func:`noisecal.bench.tile_labels`'s ``tiles``
    Voronoi cells, dealt to the ``k`` classes in a random order so that each class gets
    ``tiles // k`` or one more cells."""
    rng = np.random.default_rng(seed)
    cells = bench.tile_labels(shape[0], shape[1], tiles, rng)
    return (rng.permutation(tiles) % k)[cells]


def write_tiles(folder: Path, held: list, write, tiles: int = TILES, blur: float = TILE_BLUR, seed: int = MOSAIC_SEED) -> None:
    """Tiled real-noise scenes (``--scenes tiles``): the mosaics of :func:`write_mosaics` with a
    few large regions (``tiles`` Voronoi cells, :func:`tile_plan`) and edges blurred as by the
    optics. Scene ``m`` gives each pixel the level of class ``(class + m) mod k`` (``k`` held-out
    frames, their mean clean levels), blurred by a Gaussian of ``blur`` raw pixels; the pixel is
    then the real noisy pixel, with its clean value, of the held-out frame whose level is nearest
    the blurred one. In the interiors (the blur sees one class) that is the class's own frame, so
    each interior pixel shows every frame once over the ``k`` scenes; an edge becomes a ramp of
    real pixels from the frames between its two sides' levels. Every pixel and its noise stay
    real, and every clean value is its frame's."""
    k = len(held)
    if k < 2:
        return
    cls = tile_plan(held[0][0].shape, k, tiles, seed)
    levels = np.array([float(np.mean(c)) for _, c, _ in held])
    frames = np.stack([f for f, _, _ in held])
    cleans = np.stack([c for _, c, _ in held])
    for m in range(k):
        target = bench.gaussian_blur(levels[(cls + m) % k], blur)
        pick = np.argmin(np.abs(target[None] - levels[:, None, None]), axis=0)
        frame = np.take_along_axis(frames, pick[None], 0)[0].astype(np.uint16)
        clean = np.take_along_axis(cleans, pick[None], 0)[0]
        scene = folder / f"tiles_{m:02}"
        scene.mkdir(parents=True, exist_ok=True)
        if not (scene / "clean.npy").exists():
            np.save(scene / "clean.npy", clean)
        write(scene / "frame.dng", frame, 200, held[0][2])


def tile_training(held: list, black: list[float]) -> dict:
    """What the tile training scenes take from the held-out frames' clean images (no noisy pixel):
    ``ladder``, their mean levels above black, and ``texture`` (t0, t1), the least-squares line
    through their fixed pattern's SD against the level, each SD from differences of same-colour
    neighbours two pixels apart (/√2: white DSNU and PRNU; the smooth shading cancels)."""
    b = float(np.mean(black))
    lv = np.array([float(np.mean(c)) - b for _, c, _ in held])
    sd = np.array([float(np.std(c[:, 2:] - c[:, :-2])) / np.sqrt(2) for _, c, _ in held])
    t1, t0 = np.polyfit(lv, sd, 1) if len(held) > 1 else (0.0, float(sd[0]))
    return {"ladder": [round(float(v), 3) for v in lv], "texture": (max(float(t0), 0.0), max(float(t1), 0.0))}


def tile_args(got: dict) -> list[str]:
    """noisecal-bench's options for the tile training scenes (``--scenes tiles``)."""
    t0, t1 = got["texture"]
    return [
        "--tiles", str(TILES), "--tile-blur", f"{TILE_BLUR:g}",
        "--tile-ladder", ",".join(f"{v:g}" for v in got["ladder"]),
        "--tile-texture", f"{t0:.4f},{t1:.5f}",
    ]  # fmt: skip


def convert(src: Source, out: Path, say) -> dict:
    """Writes ``out/cal`` (the calibration DNGs) and ``out/eval`` (the evaluation scenes); returns
    what it measured (black levels, the pairs kept)."""
    blocks = read_descriptor(src.read("EMVA1288_Data.txt").decode("utf-8", "replace"))
    bright = [b for b in blocks if b.kind == "b"]
    dark = [b for b in blocks if b.kind == "d"]
    burst_b = next((b for b in bright if len(b.images) >= 2 * REFERENCE), None)
    burst_d = next((b for b in dark if len(b.images) >= 2 * REFERENCE), None)
    if burst_b is None or burst_d is None or burst_b.exposure_ns != BURST_EXPOSURE_NS:
        raise ConvertError(f"EMVA1288_Data.txt: no {2 * REFERENCE}-frame bright and dark bursts at {BURST_EXPOSURE_NS} ns")
    say(f"reading the {len(burst_b.images)}-frame burst and the {len(burst_d.images)}-frame dark burst")
    frames, darks = src.frames(burst_b), src.frames(burst_d)
    dark_mean = np.mean(np.stack(darks).astype(np.float64), axis=0)
    black = [float(v) for v in bench.pack_raw(dark_mean).mean(axis=(1, 2))]
    clean = np.mean(np.stack(frames[:REFERENCE]).astype(np.float64), axis=0)

    def write(path: Path, px: np.ndarray, iso: int, exposure_ns: int):
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists():
            noisecal.write_raw_dng(
                path, px, cfa=CFA, black=black, white=WHITE, iso=iso, exposure_ns=exposure_ns, make=MAKE, model=MODEL
            )

    ref_ns = 2 * BURST_EXPOSURE_NS
    for i, f in enumerate(frames[:REFERENCE]):
        write(out / "cal" / f"ref_{i:02}.dng", f, 100, ref_ns)
        write(out / "eval" / "burst" / f"ref_{i:02}.dng", f, 100, ref_ns)
    for i, f in enumerate(frames[REFERENCE : REFERENCE + CALIBRATION_TARGETS]):
        write(out / "cal" / f"target_{i:02}.dng", f, 200, BURST_EXPOSURE_NS)
    for i, f in enumerate(frames[REFERENCE + CALIBRATION_TARGETS :]):
        write(out / "eval" / "burst" / f"heldout_{i:02}.dng", f, 200, BURST_EXPOSURE_NS)
    half = len(darks) // 2
    for i, f in enumerate(darks):  # at their true exposure: the ISO-100 half matches no step
        write(out / "cal" / f"dark_{i:02}.dng", f, 100 if i < half else 200, BURST_EXPOSURE_NS)
    pairs, low, held = [], [], []
    dark_by_ns = {b.exposure_ns: b for b in dark}
    for k, b in enumerate(x for x in bright if x is not burst_b):
        if b.exposure_ns not in dark_by_ns:
            continue
        pair, dpair = src.frames(b), src.frames(dark_by_ns[b.exposure_ns])
        level = (np.mean([f.mean() for f in pair]) - np.mean(black)) / (WHITE - np.mean(black))
        # The low-light pack (module docstring): frame 0 of each dim pair calibrates against the
        # pair's derived clean image; frame 1 of the dimmest is held out for evaluation. An exposure
        # within 1 % of the burst's would join the burst's step (grouping by ISO × exposure): skipped.
        if level <= LOW_CAL_MAX and abs(b.exposure_ns / BURST_EXPOSURE_NS - 1) > 0.01:
            pc = pair_clean(clean, dark_mean, pair, dpair)
            us = b.exposure_ns // 1000
            for i, f in enumerate(dithered_burst(pc, LOW_REF_FRAMES)):
                write(out / "cal-low" / f"ref_{us:05}us_{i}.dng", f, 100, 2 * b.exposure_ns)
            write(out / "cal-low" / f"target_{us:05}us.dng", pair[0], 200, b.exposure_ns)
            if level < LOW_EVAL_MAX:
                scene = out / "eval-low" / f"pt_{us:05}us"
                scene.mkdir(parents=True, exist_ok=True)
                if not (scene / "clean.npy").exists():
                    np.save(scene / "clean.npy", pc)
                write(scene / "frame_1.dng", pair[1], 200, b.exposure_ns)
                held.append((pair[1], pc, b.exposure_ns))
            low.append({"exposure_ns": b.exposure_ns, "level": float(level), "evaluated": bool(level < LOW_EVAL_MAX)})
        if k % PAIR_EVERY or level > PAIR_MAX:
            continue
        scene = out / "eval-pairs" / f"pair_{b.exposure_ns // 1000:05}us"
        scene.mkdir(parents=True, exist_ok=True)
        if not (scene / "clean.npy").exists():
            np.save(scene / "clean.npy", pair_clean(clean, dark_mean, pair, dpair))
        for i, f in enumerate(pair):
            write(scene / f"frame_{i}.dng", f, 200, b.exposure_ns)
        pairs.append({"exposure_ns": b.exposure_ns, "level": float(level)})
    above = clean - np.mean(black)
    lo, hi = np.percentile(above, 0.5), np.percentile(above, 99.5)
    for i in range(FLAT_TRAIN):  # --flat: flat fields at levels spread over the band
        level = np.mean(black) + lo + (hi - lo) * (i + 0.5) / FLAT_TRAIN
        write(out / "train-flat" / f"flat_{i:02}.dng", np.full(clean.shape, round(level), np.uint16), 100, ref_ns)
    levels = (float(np.floor(np.percentile(above, 0.5))), float(np.ceil(np.percentile(above, 99.5))))
    write_mosaics(out / "eval-mosaic", held, write)
    write_tiles(out / "eval-tiles", held, write)
    # The low pack also holds the burst's step and the dark burst (the same frames as OUT/cal).
    for f in sorted((out / "cal").glob("*.dng")):
        if not (out / "cal-low" / f.name).exists():
            (out / "cal-low" / f.name).write_bytes(f.read_bytes())
    low_top = max(float(np.load(d / "clean.npy").max()) - min(black) for d in sorted((out / "eval-low").iterdir()))
    say(
        f"black levels {[round(v, 3) for v in black]} DN; burst clean levels {levels} DN above black; {len(pairs)} pairs; "
        f"{len(low)} low-light exposures calibrate, {sum(x['evaluated'] for x in low)} evaluated (clean up to {low_top:.0f} DN)"
    )
    return {
        "black": black, "pairs": pairs, "levels": levels, "low": low, "low_levels": (0.0, float(np.ceil(low_top))),
        **tile_training(held, black),
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repo", type=Path, required=True, help="a clone of EMVA1288/datasets (bare or not)")
    p.add_argument("--out", type=Path, default=Path("target/emva001"), help="the cache [default: %(default)s]")
    p.add_argument("--generate", type=int, default=24, help="generated training scenes [default: %(default)s]")
    p.add_argument(
        "--band",
        action="store_true",
        help="the burst's band instead of low light: packs from OUT/cal, evaluated on the held-out burst frames (OUT/eval)",
    )
    p.add_argument(
        "--flat",
        action="store_true",
        help="with --band: train on flat fields at levels across the pack's band (OUT/train-flat) instead of generated scenes",
    )
    p.add_argument(
        "--flat-eval",
        action="store_true",
        help="evaluate on the held-out low-light flat fields themselves (OUT/eval-low) rather than the real-noise "
        "mosaics made of them (OUT/eval-mosaic); flat fields reward smoothing, not fidelity",
    )
    p.add_argument(
        "--scenes",
        choices=("mosaic", "tiles"),
        default="tiles",
        help="low light: evaluate on the dead-leaves real-noise mosaics (OUT/eval-mosaic) or on the tiled ones "
        "(OUT/eval-tiles: a few large regions, blurred edges) and train on generated tile scenes of their kind "
        "[default: %(default)s]",
    )
    p.add_argument("--json", type=Path, help="noisecal-bench's results JSON [default: OUT/bench.json]")
    args, rest = p.parse_known_args(argv)

    def say(*a):
        print(*a, file=sys.stderr, flush=True)

    cal, full, plain = ("cal", "full.pack", "plain.pack") if args.band else ("cal-low", "low.pack", "low-plain.pack")
    try:
        got = convert(Source(args.repo), args.out, say)
        for name, is_plain in ((full, False), (plain, True)):
            if not (args.out / name).exists():
                say(f"calibrating {name} from {cal}/")
                noisecal.calibrate(args.out / cal, plain=is_plain).save(args.out / name)
    except (ConvertError, noisecal.NoisecalError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    out = args.out
    lo, hi = got["levels"] if args.band else got["low_levels"]
    return bench.main(
        [
            "--pack", str(out / full),
            "--plain-pack", str(out / plain),
            "--eval", str(out / ("eval" if args.band else "eval-low" if args.flat_eval else f"eval-{args.scenes}")),
            *(["--train", str(out / "train-flat")] if args.flat else
              ["--generate", str(args.generate), "--mono", "--generate-levels", f"{lo:g},{hi:g}"]),
            *(tile_args(got) if args.scenes == "tiles" and not args.band else []),
            "--models", "noisecal,hg,pg,plain,wrong,loud",
            "--json", str(args.json or out / "bench.json"),
            *rest,
        ]
    )  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
