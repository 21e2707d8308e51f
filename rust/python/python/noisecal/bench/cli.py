"""The command line (``noisecal-bench``, ``python -m noisecal.bench``): options, checks, the
table on stdout and the ``--json`` file."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import noisecal

from .errors import BenchError
from .estimate import DEFAULT_ESTIMATE
from .models import BASE_MODELS, DEFAULT_MODELS, RENOISE_METHODS
from .report import table
from .run import run


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="noisecal-bench",
        description="Train the same small raw denoiser on each noise model's synthetic pairs, score it on real captures.",
    )
    p.add_argument("--pack", help="the calibrated pack")
    p.add_argument("--eval", type=Path, help="evaluation folder: per scene a base-ISO burst and target-ISO frames")
    p.add_argument("--train", type=Path, help="folder of clean raw DNGs (base-ISO brightness)")
    p.add_argument("--generate", type=int, help="train on N built-in natural-statistics scenes instead of --train")
    p.add_argument(
        "--generate-levels",
        help="LO,HI: --generate scenes spread over these DN above black (a pack calibrated on a narrow band of levels)",
    )
    p.add_argument("--mono", action="store_true", help="--generate grey scenes (gain 1 on every CFA position): a monochrome sensor")
    p.add_argument(
        "--tiles",
        type=int,
        help="--generate grey tile scenes of N flat regions (Voronoi cells, levels uniform over --generate-levels) "
        "instead of dead leaves: the kind of a tiled real-data evaluation set (docs/bench.md)",
    )
    p.add_argument("--tile-blur", type=float, default=1.0, help="--tiles: the edges' Gaussian blur in raw pixels [default: %(default)s]")
    p.add_argument(
        "--tile-ladder",
        help="--tiles: L1,L2,…: the evaluation set's levels (DN above black); regions take these levels and blurred "
        "pixels the nearest of them, as tiled evaluation scenes are made",
    )
    p.add_argument(
        "--tile-texture",
        help="--tiles: T0,T1: add a white fixed pattern of SD T0 + T1·level DN to the clean scenes (the DSNU and PRNU a "
        "real clean image, a burst mean, carries) [default: none]",
    )
    p.add_argument("--captures", type=Path, help="real captures of the training scenes (<clean stem>_*.dng): oracle, noise on noise")
    p.add_argument("--set", type=Path, help="a folder laid out as `noisecal simulate --bench` writes it")
    p.add_argument("--models", default=DEFAULT_MODELS, help=f"comma-separated [LABEL=]MODEL[:COMPONENTS][@PACK]; MODEL in {', '.join(BASE_MODELS)}; COMPONENTS e.g. pixel, or own (all but the fixed pattern: training clean images that carry it, e.g. your own burst means) [default: %(default)s]")
    p.add_argument("--components", action="append", help="add a noisecal row with these components (e.g. pixel), repeatable")
    p.add_argument("--plain-pack", help="the plain per-bin pack for the `plain` model (noisecal calibrate --plain)")
    p.add_argument("--isos", help="target ISOs to benchmark (comma-separated) [default: all in --eval]")
    p.add_argument("--renoise-from", type=int, help="noise on noise: train on real ISO-A captures re-noised to --renoise-to")
    p.add_argument("--renoise-to", type=int)
    p.add_argument(
        "--renoise-methods",
        default=",".join(RENOISE_METHODS),
        help="noise-on-noise methods to train, comma-separated [default: %(default)s]",
    )
    p.add_argument(
        "--renoise-estimate",
        default=DEFAULT_ESTIMATE,
        help="the clean estimate that picks each pixel's noise for bridge, quantile and denoised, comma-separated for "
        "several rows: denoiser (a network trained on the pack's ISO-A noise, as the paper), filter (the core's built-in "
        "filter), clean (the known clean training images: a perfect denoiser) [default: %(default)s]",
    )
    p.add_argument("--steps", type=int, default=1500, help="training steps per network [default: %(default)s]")
    p.add_argument("--minutes", type=float, help="time budget for all networks: sets the steps per network (≤ --steps when given)")
    p.add_argument("--seeds", type=int, default=2, help="training seeds per model and ISO [default: %(default)s]")
    p.add_argument("--seed", type=int, default=0, help="first training seed [default: %(default)s]")
    p.add_argument("--data-seed", type=int, default=1, help="seed of the synthetic noise and generated scenes [default: %(default)s]")
    p.add_argument("--realizations", type=int, help="noisy images per clean image and ISO [default: as many as --captures has, else 4]")
    p.add_argument("--batch", type=int, default=16, help="crops per step [default: %(default)s]")
    p.add_argument("--crop", type=int, default=48, help="training crop side in raw pixels, a multiple of 8 [default: %(default)s]")
    p.add_argument("--width", type=int, default=16, help="UNet width (channels at the first scale) [default: %(default)s]")
    p.add_argument(
        "--input-scale",
        type=float,
        default=1.0,
        help="the network's layers see its input (normalised to the range) times this, and their correction is divided "
        "by it: for noise that is a small fraction of the range, e.g. dim frames [default: %(default)s]",
    )
    p.add_argument(
        "--loss",
        choices=("l1", "mse"),
        default="l1",
        help="training loss: l1, or mse (the squared error PSNR scores) [default: %(default)s]",
    )
    p.add_argument(
        "--highpass",
        action="store_true",
        help="the layers see the input's high-pass (less its 5×5 local mean) in units of the evaluation noise's RMS at the "
        "ISO and correct in those units, the same for every model: for noise far below the scene's edges, e.g. 8-bit "
        "frames (docs/bench.md, \"Why nothing learnt on EMVA set 002\"; with --lr 0.01 it diverged on a simulated phone "
        "at ISO 1600, at 0.003 it kept the controls); not with --input-scale",
    )
    p.add_argument("--lr", type=float, default=3e-3, help="Adam learning rate, cosine-decayed to 2 %% of it [default: %(default)s]")
    p.add_argument("--device", default="cpu", help="torch device: cpu, cuda, cuda:1, mps …")
    p.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch CPU threads (0: torch's default) [default: 1: these small networks gain little from more, "
        "and a loaded machine loses much]",
    )
    p.add_argument("--state", help="folder of finished networks' scores: a rerun with the same settings resumes")
    p.add_argument("--json", help="write the full results (per network and summary) to this file")
    p.add_argument("-q", "--quiet", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parser().parse_args(argv)
    args.steps_given = any(a == "--steps" or a.startswith("--steps=") for a in argv)
    try:
        if args.crop % 8 or args.crop < 16:
            raise BenchError(f"--crop {args.crop}: use a multiple of 8, at least 16")
        if not args.input_scale > 0 or not math.isfinite(args.input_scale):
            raise BenchError(f"--input-scale {args.input_scale}: give a positive number (1 leaves the network as it is)")
        if args.highpass and args.input_scale != 1.0:
            raise BenchError("--highpass sets the network's input unit itself: drop --input-scale")
        if args.tiles is not None and (args.tiles < 1 or not 0 <= args.tile_blur <= 16):
            raise BenchError(f"--tiles {args.tiles} --tile-blur {args.tile_blur:g}: give 1 or more tiles and a blur of 0 … 16 px")
        if args.seeds < 1 or args.steps < 1 or args.batch < 1:
            raise BenchError("--seeds, --steps and --batch must be at least 1")
        if not 0 <= args.data_seed < 2**64 or args.seed < 0:
            raise BenchError("--seed and --data-seed must be 0 or more (--data-seed below 2**64)")
        out = run(args)
    except (BenchError, noisecal.NoisecalError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(table(out))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=lambda o: None))
    return 0
