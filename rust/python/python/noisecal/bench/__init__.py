"""The denoiser benchmark: does a network trained on a pack's synthetic noise denoise real captures?

``noisecal-bench --pack my.pack --eval eval/ --train clean/`` (or ``python -m noisecal.bench``)
trains the same small network (a compact UNet on packed 4-channel raw) on each noise model's
synthetic pairs — the same clean crops in the same order, the same seeds — and scores every network
on the real evaluation pairs: PSNR and SSIM per target ISO and per brightness band, over several
training seeds, with the difference to HG (the paper's Table 1). ``--renoise-from A --renoise-to B``
adds noise on noise (Table 2): networks trained on real ISO-A captures re-noised to ISO B by each
method, scored on real ISO-B pairs, beside real ISO-B training data.

Controls: ``oracle`` trains on the sensor's own noise (real captures of the training scenes, known
for a simulated sensor: ``noisecal simulate --bench``) and ``wrong`` on HG noise with half the
variance; the oracle should score best and the wrong model clearly worst, which shows the benchmark
can tell models apart on this data before its verdict on the others is trusted.

Inputs:

- ``--eval DIR``: one sub-folder per scene holding DNGs: a burst at the lowest ISO in the folder
  (the base ISO; its mean is the clean image) and frames at target ISOs (same ISO × exposure).
  Frames are told apart by their ISO metadata, never by name.
- ``--train DIR``: clean raw DNGs at the base ISO's brightness (e.g. burst means), or
  ``--generate N`` natural-statistics scenes (dead leaves) mosaiced for the pack's CFA, black and
  white levels. ``--set DIR`` takes the layout ``noisecal simulate --bench DIR`` writes
  (``eval/``, ``train/clean/``, ``train/captures/``).
- ``--captures DIR``: real captures of the training scenes, ``<clean file stem>_*.dng`` at target
  ISOs: the ``oracle`` model's training data and the ISO-A frames noise on noise starts from.

The package itself needs numpy alone; the training needs torch (``pip install noisecal[torch]``).
The metric and data-layout functions here are numpy and import without torch.

The package, one concern per module: ``layout`` (packed raw), ``scenes`` (generated training
scenes), ``data`` (the evaluation set and training images from disk), ``metrics`` (PSNR, SSIM,
bands, flat and edge regions), ``headroom`` (how much noise a filter removes), ``models`` (each model's training pairs), ``network`` (the UNet), ``training``,
``estimate`` (the clean estimate noise on noise starts from), ``scoring`` (networks scored, the
summary and the controls), ``paired`` (the paired test over training seeds: the controls', and every row against the best), ``report`` (the table), ``run``
(a whole run) and ``cli``. The names below are its public API.
"""

from __future__ import annotations

from .errors import BenchError
from .layout import mosaic, normalise, pack_raw, per_position, unpack_raw
from .scenes import dead_leaves, gaussian_blur, generate_clean, generate_tiles, parse_levels, tile_labels
from .data import EvalScene, eval_pairs, load_captures, load_clean, load_eval, load_float_clean
from .metrics import BANDS, REGIONS, band_masks, psnr, region_masks, score, ssim, ssim_map, summarise
from .headroom import guided_gain, headroom, linear_gain
from .models import (
    BASE_MODELS,
    DEFAULT_MODELS,
    PARAMETRIC,
    RENOISE_METHODS,
    ModelSpec,
    Pairs,
    at_target_brightness,
    interpolation_notes,
    make_pairs,
    parse_model,
    synth_seed,
)
from .scaled_hg import ScaledHg, rounded_gaussian_sd, rounded_variance
from .network import make_net
from .estimate import DEFAULT_ESTIMATE, ESTIMATES, denoise, estimates_for, parse_estimates
from .training import batch_plan, train_one
from .paired import BEST_FALSE_ALARM, FALSE_ALARM, MIN_GAP_DB, below_best, paired_below, t_critical
from .scoring import controls, evaluate, failed_controls, noise_rms, rows_below_wrong, score_input, summary
from .report import gain_table, gains, headroom_lines, region_table, table, verdict_line
from .run import CAPTURED, networks_trained, run, steps_for_minutes, training_targets
from .cli import main, parser

__all__ = [
    "BANDS",
    "CAPTURED",
    "BASE_MODELS",
    "BenchError",
    "DEFAULT_ESTIMATE",
    "DEFAULT_MODELS",
    "ESTIMATES",
    "EvalScene",
    "ModelSpec",
    "PARAMETRIC",
    "REGIONS",
    "Pairs",
    "RENOISE_METHODS",
    "ScaledHg",
    "at_target_brightness",
    "band_masks",
    "batch_plan",
    "controls",
    "dead_leaves",
    "denoise",
    "estimates_for",
    "eval_pairs",
    "evaluate",
    "failed_controls",
    "rows_below_wrong",
    "BEST_FALSE_ALARM",
    "below_best",
    "FALSE_ALARM",
    "MIN_GAP_DB",
    "paired_below",
    "t_critical",
    "gain_table",
    "gains",
    "guided_gain",
    "headroom",
    "headroom_lines",
    "gaussian_blur",
    "generate_clean",
    "generate_tiles",
    "interpolation_notes",
    "linear_gain",
    "load_captures",
    "load_clean",
    "load_eval",
    "load_float_clean",
    "main",
    "make_net",
    "make_pairs",
    "networks_trained",
    "noise_rms",
    "mosaic",
    "normalise",
    "pack_raw",
    "parse_estimates",
    "parse_levels",
    "parse_model",
    "parser",
    "per_position",
    "psnr",
    "region_masks",
    "region_table",
    "rounded_gaussian_sd",
    "rounded_variance",
    "run",
    "score",
    "score_input",
    "ssim",
    "ssim_map",
    "steps_for_minutes",
    "summarise",
    "summary",
    "synth_seed",
    "table",
    "verdict_line",
    "tile_labels",
    "train_one",
    "training_targets",
    "unpack_raw",
]
