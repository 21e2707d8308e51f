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
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import sys
import time
from typing import Any
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import noisecal

# Brightness bands by the clean level, normalised to [0, 1] between black and white.
BANDS = (("dark", 0.0, 0.02), ("shadow", 0.02, 0.1), ("mid", 0.1, 0.4), ("bright", 0.4, math.inf))
BASE_MODELS = ("noisecal", "hg", "pg", "noiseprofile", "plain", "wrong", "oracle")
RENOISE_METHODS = ("bridge", "quantile", "denoised", "naive")
DEFAULT_MODELS = "oracle,noisecal,hg,pg,wrong"


class BenchError(ValueError):
    """A bad input to the benchmark (the message names it and the fix)."""


# ----------------------------------------------------------------------------------------------
# Data layout (numpy)


def pack_raw(raw: np.ndarray) -> np.ndarray:
    """(H, W) mosaic → (4, H/2, W/2), channel ``p`` = CFA position ``p`` = (row % 2)·2 + col % 2,
    the core's order (so the pack's per-position black levels apply channel by channel)."""
    if raw.ndim != 2 or raw.shape[0] % 2 or raw.shape[1] % 2:
        raise BenchError(f"a raw mosaic of even height and width is needed, got shape {raw.shape}")
    return np.stack([raw[0::2, 0::2], raw[0::2, 1::2], raw[1::2, 0::2], raw[1::2, 1::2]])


def unpack_raw(packed: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pack_raw`."""
    c, h, w = packed.shape
    if c != 4:
        raise BenchError(f"4 packed channels are needed, got {c}")
    out = np.empty((2 * h, 2 * w), dtype=packed.dtype)
    out[0::2, 0::2], out[0::2, 1::2], out[1::2, 0::2], out[1::2, 1::2] = packed
    return out


def normalise(raw: np.ndarray, black, white: float) -> np.ndarray:
    """Packed float32 in units of the range above black: (x − black[p]) / (white − black[p])."""
    b = np.asarray(black, dtype=np.float64).reshape(4, 1, 1)
    return ((pack_raw(np.asarray(raw, dtype=np.float64)) - b) / (white - b)).astype(np.float32)


def per_position(values, shape) -> np.ndarray:
    """A (H, W) float64 image holding ``values[p]`` at every pixel of CFA position ``p``."""
    v = np.asarray(values, dtype=np.float64).reshape(4, 1, 1)
    return unpack_raw(np.broadcast_to(v, (4, shape[0] // 2, shape[1] // 2)).copy())


def mosaic(rgb: np.ndarray, cfa: str) -> np.ndarray:
    """(H, W, 3) → (H, W) keeping each pixel's CFA colour (``cfa``: "RGGB", "GRBG", "GBRG", "BGGR")."""
    idx = {"R": 0, "G": 1, "B": 2}
    cfa = cfa.upper()
    if len(cfa) != 4 or any(c not in idx for c in cfa):
        raise BenchError(f"unknown CFA {cfa!r}: use RGGB, GRBG, GBRG or BGGR")
    out = np.empty(rgb.shape[:2], dtype=rgb.dtype)
    for p, c in enumerate(cfa):
        out[p // 2 :: 2, p % 2 :: 2] = rgb[p // 2 :: 2, p % 2 :: 2, idx[c]]
    return out


def dead_leaves(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """A natural-statistics RGB scene (H, W, 3) in [0, 1]: opaque discs front to back, radii with
    density ∝ r⁻³ (1.5 px … a quarter of the larger side), log-uniform luminance over 0.004 … 0.9,
    random chroma, under a smooth illumination gradient of up to 2 stops (as ``Chart::natural``)."""
    img = np.zeros((height, width, 3))
    covered = np.zeros((height, width), dtype=bool)
    rmin, rmax = 1.5, max(2.0, max(height, width) / 4)
    a, b = rmin**-2, rmax**-2
    yy, xx = np.mgrid[0:height, 0:width] + 0.5
    for _ in range(20000):
        if covered.all():
            break
        r = (a - rng.random() * (a - b)) ** -0.5
        cx, cy = rng.random() * (width + 2 * r) - r, rng.random() * (height + 2 * r) - r
        lum = math.exp(math.log(0.004) + rng.random() * math.log(0.9 / 0.004))
        chroma = 0.6 + 0.8 * rng.random(3)
        color = np.minimum(lum * chroma / chroma.mean(), 1.0)
        y0, y1 = max(0, int(cy - r)), min(height, int(cy + r) + 1)
        x0, x1 = max(0, int(cx - r)), min(width, int(cx + r) + 1)
        if y0 >= y1 or x0 >= x1:
            continue
        disc = ((yy[y0:y1, x0:x1] - cy) ** 2 + (xx[y0:y1, x0:x1] - cx) ** 2 <= r * r) & ~covered[y0:y1, x0:x1]
        img[y0:y1, x0:x1][disc] = color
        covered[y0:y1, x0:x1] |= disc
    g = rng.random(2) * 2 - 1
    norm = max(abs(g).sum(), 1e-9)
    e = 2 * ((g[0] * xx / width + g[1] * yy / height) - np.maximum(g, 0).sum()) / norm
    return img * np.exp2(e)[..., None]


def generate_clean(
    n: int,
    height: int,
    width: int,
    layout: Mapping[str, Any],
    seed: int,
    mono: bool = False,
    levels: tuple[float, float] | None = None,
) -> list[np.ndarray]:
    """``n`` clean raw images (uint16 DN, black included) of natural-statistics scenes mosaiced for
    the pack's CFA with lamp × channel gains (R, G, B) = (0.6, 1, 0.75), the brightest green at
    0.6 … 0.95 of the range and each image 0 … 3 EV darker in turn (low light included). ``mono``:
    grey scenes at gain 1 on every CFA position (a monochrome sensor read as a mosaic).
    ``levels`` (lo, hi) in DN above black: each scene's values spread linearly over that band
    instead (for a pack whose measured levels are a narrow band, e.g. calibrated on a flat field:
    outside its levels a non-parametric pack has no samples to draw from)."""
    rng = np.random.default_rng(seed)
    black = np.asarray(layout["black"], dtype=np.float64)
    white = float(layout["white"])
    out = []
    for i in range(n):
        rgb = dead_leaves(height, width, rng)
        rgb = rgb.mean(-1, keepdims=True).repeat(3, -1) if mono else rgb * np.array([0.6, 1.0, 0.75])
        raw = mosaic(rgb, layout["cfa"]) * (0.6 + 0.35 * rng.random()) / 2 ** (i % 4)
        b = per_position(black, (height, width))
        if levels is not None:
            lo, hi = levels
            v = np.clip(raw, 0, None)
            v = (v - v.min()) / max(float(v.max() - v.min()), 1e-12)
            out.append(np.rint(np.clip(b + lo + v * (hi - lo), 0, white)).astype(np.uint16))
            continue
        out.append(np.rint(np.clip(b + raw * (white - b), 0, white)).astype(np.uint16))
    return out


def parse_levels(text: str | None, layout: Mapping[str, Any]) -> tuple[float, float] | None:
    """``--generate-levels LO,HI`` (DN above black), checked against the pack's range."""
    if text is None:
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise BenchError(f"--generate-levels {text!r}: give LO,HI in DN above black, e.g. 1900,2060") from None
    top = float(layout["white"]) - max(layout["black"])
    if not 0 <= lo < hi <= top:
        raise BenchError(f"--generate-levels {text!r}: need 0 ≤ LO < HI ≤ {top:g} (white less black)")
    return lo, hi


@dataclass
class EvalScene:
    name: str
    clean: np.ndarray  # float64 (H, W): mean of the base-ISO burst (or the scene's clean.npy), DN
    base_iso: int | None  # None: the clean image was given (clean.npy), not a burst
    frames: dict = field(default_factory=dict)  # target ISO -> list of uint16 (H, W)


def _dngs(d: Path) -> list[Path]:
    return sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() == ".dng")


def _given_clean(d: Path, frames: list) -> np.ndarray:
    """A scene's ``clean.npy``: its clean image in DN (black included), for real data whose clean
    image is derived rather than a burst's mean (a flat field at another exposure, scaled from a
    long burst); every DNG of the folder is then a target frame."""
    try:
        clean = np.load(d / "clean.npy", allow_pickle=False)
    except (OSError, ValueError) as e:
        raise BenchError(f"--eval: {d / 'clean.npy'} is not a numpy array file ({e}): save it with np.save") from e
    shape = frames[0][0].shape
    if clean.ndim != 2 or clean.shape != shape or not np.issubdtype(clean.dtype, np.number):
        raise BenchError(f"--eval: {d / 'clean.npy'} is {clean.dtype} {clean.shape}; the frames are {shape}: give one number per pixel")
    if not np.isfinite(clean).all():
        raise BenchError(f"--eval: {d / 'clean.npy'} holds NaN or infinite values")
    return clean.astype(np.float64)


def load_eval(eval_dir: Path, pack) -> list[EvalScene]:
    """Scenes of an evaluation folder (one sub-folder per scene; see the module docstring)."""
    eval_dir = Path(eval_dir)
    if not eval_dir.is_dir():
        raise BenchError(f"--eval {eval_dir}: not a folder (give one sub-folder per scene of DNGs)")
    dirs = sorted(d for d in eval_dir.iterdir() if d.is_dir())
    if not dirs:
        raise BenchError(
            f"--eval {eval_dir}: no scene sub-folders; lay it out as eval/<scene>/*.dng (a base-ISO burst and "
            "frames at target ISOs), e.g. with `noisecal simulate --bench DIR`"
        )
    scenes = []
    for d in dirs:
        frames = [noisecal.read_dng(p, pack=pack) for p in _dngs(d)]
        if not frames:
            raise BenchError(f"--eval: scene folder {d} has no DNGs")
        shapes = {px.shape for px, _ in frames}
        if len(shapes) != 1:
            raise BenchError(f"--eval: scene {d.name} mixes image sizes {sorted(shapes)}")
        isos = sorted({int(m["iso"]) for _, m in frames})
        if (d / "clean.npy").exists():
            s = EvalScene(d.name, _given_clean(d, frames), None)
            for px, m in frames:
                s.frames.setdefault(int(m["iso"]), []).append(px)
            scenes.append(s)
            continue
        base = isos[0]
        burst = [px for px, m in frames if int(m["iso"]) == base]
        if len(burst) < 2:
            raise BenchError(
                f"--eval: scene {d.name} has {len(burst)} frame at its lowest ISO {base}: the clean image is the mean "
                "of a base-ISO burst, so give at least 2 (16 or more for a clean mean), or its clean image as clean.npy"
            )
        if len(isos) < 2:
            raise BenchError(f"--eval: scene {d.name} has frames at ISO {base} only: add frames at the target ISOs")
        clean = np.mean(np.stack(burst).astype(np.float64), axis=0)
        s = EvalScene(d.name, clean, base)
        for px, m in frames:
            if int(m["iso"]) != base:
                s.frames.setdefault(int(m["iso"]), []).append(px)
        scenes.append(s)
    bases = {s.base_iso for s in scenes if s.base_iso is not None}
    if len(bases) > 1:
        raise BenchError(f"--eval: scenes have different base ISOs {sorted(bases)}: use one base ISO for all")
    return scenes


def load_clean(train_dir: Path, pack) -> tuple[list[str], list[np.ndarray]]:
    train_dir = Path(train_dir)
    if not train_dir.is_dir():
        raise BenchError(f"--train {train_dir}: not a folder of clean DNGs")
    paths = _dngs(train_dir)
    if not paths:
        raise BenchError(f"--train {train_dir}: no DNGs; give clean raw DNGs, or --generate N for built-in scenes")
    return [p.stem for p in paths], [noisecal.read_dng(p, pack=pack)[0] for p in paths]


def load_captures(cap_dir: Path, names: list[str], pack) -> dict:
    """``{(clean index, ISO): [uint16 frames]}`` from ``<clean stem>_*.dng`` files."""
    cap_dir = Path(cap_dir)
    if not cap_dir.is_dir():
        raise BenchError(f"--captures {cap_dir}: not a folder")
    out: dict = {}
    index = {n: i for i, n in enumerate(names)}
    for p in _dngs(cap_dir):
        # The longest clean stem the file name starts with, followed by "_".
        match = max((n for n in names if p.stem.startswith(n + "_")), key=len, default=None)
        if match is None:
            raise BenchError(
                f"--captures: {p.name} names no clean training image (want <clean stem>_*.dng, clean stems e.g. {names[0]})"
            )
        px, m = noisecal.read_dng(p, pack=pack)
        out.setdefault((index[match], int(m["iso"])), []).append(px)
    return out


# ----------------------------------------------------------------------------------------------
# Metrics (numpy)


def psnr(pred: np.ndarray, ref: np.ndarray, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB: 10·log10(range² / MSE); inf for identical images."""
    mse = float(np.mean((np.asarray(pred, np.float64) - np.asarray(ref, np.float64)) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(data_range**2 / mse)


def _gauss_filter(x: np.ndarray, size: int = 11, sigma: float = 1.5) -> np.ndarray:
    """'Valid' separable Gaussian filtering of the last two axes."""
    k = np.exp(-0.5 * ((np.arange(size) - (size - 1) / 2) / sigma) ** 2)
    k /= k.sum()
    v = np.lib.stride_tricks.sliding_window_view(x, size, axis=-2)
    x = np.tensordot(v, k, axes=([-1], [0]))
    h = np.lib.stride_tricks.sliding_window_view(x, size, axis=-1)
    return np.tensordot(h, k, axes=([-1], [0]))


def ssim_map(pred: np.ndarray, ref: np.ndarray, data_range: float = 1.0) -> np.ndarray:
    """The SSIM map of Wang et al. (2004) with their constants (11×11 Gaussian window, σ 1.5,
    K1 0.01, K2 0.03) over the last two axes, on the 'valid' region (5 px cropped per side)."""
    x = np.asarray(pred, np.float64)
    y = np.asarray(ref, np.float64)
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mx, my = _gauss_filter(x), _gauss_filter(y)
    sxx = _gauss_filter(x * x) - mx * mx
    syy = _gauss_filter(y * y) - my * my
    sxy = _gauss_filter(x * y) - mx * my
    return ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))


def ssim(pred: np.ndarray, ref: np.ndarray, data_range: float = 1.0) -> float:
    """Mean SSIM (channels of a packed image each filtered on their own)."""
    return float(np.mean(ssim_map(pred, ref, data_range)))


def band_masks(clean_norm: np.ndarray) -> dict:
    """Per brightness band, the mask of packed pixels whose clean level falls in it."""
    return {name: (clean_norm >= lo) & (clean_norm < hi) for name, lo, hi in BANDS}


def score(preds: list[np.ndarray], cleans: list[np.ndarray]) -> dict:
    """PSNR (mean over images) and SSIM (mean) of packed normalised predictions, and per brightness
    band the PSNR of the pooled squared error and the mean SSIM over the band's pixels."""
    ps, ss = [], []
    sq = {b[0]: [0.0, 0] for b in BANDS}
    sm = {b[0]: [0.0, 0] for b in BANDS}
    for p, c in zip(preds, cleans):
        ps.append(psnr(p, c))
        m = ssim_map(p, c)
        ss.append(float(m.mean()))
        err = (p.astype(np.float64) - c) ** 2
        masks = band_masks(c)
        for name, mask in masks.items():
            sq[name][0] += float(err[mask].sum())
            sq[name][1] += int(mask.sum())
            mv = mask[..., 5:-5, 5:-5]
            sm[name][0] += float(m[mv].sum())
            sm[name][1] += int(mv.sum())
    bands = {}
    for name, *_ in BANDS:
        if sq[name][1]:
            mse = sq[name][0] / sq[name][1]
            bands[name] = {
                "psnr": math.inf if mse == 0 else 10 * math.log10(1 / mse),
                "ssim": sm[name][0] / sm[name][1] if sm[name][1] else None,
                "fraction": sq[name][1] / sum(v[1] for v in sq.values()),
            }
    return {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss)), "bands": bands}


def summarise(values: list[float]) -> dict:
    """Mean, sample standard deviation (0 for one value), min and max."""
    v = np.asarray(values, dtype=np.float64)
    return {
        "mean": float(v.mean()),
        "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
        "min": float(v.min()),
        "max": float(v.max()),
        "n": len(v),
    }


# ----------------------------------------------------------------------------------------------
# Models: what produces each model's training pairs


@dataclass
class ModelSpec:
    label: str
    kind: str  # one of BASE_MODELS, or "renoise"
    components: str | None = None
    pack_path: str | None = None
    method: str | None = None  # renoise method
    from_iso: int | None = None


def parse_model(text: str, plain_pack: str | None = None) -> ModelSpec:
    """``[LABEL=]MODEL[:COMPONENTS][@PACK]``: e.g. ``hg``, ``noisecal:pixel``,
    ``interp=noisecal@held-out-isos.pack``, ``plain@plain.pack``."""
    label, _, rest = text.rpartition("=")
    rest = rest.strip()
    pack_path = None
    if "@" in rest:
        rest, pack_path = rest.split("@", 1)
    kind, _, comps = rest.partition(":")
    kind = kind.strip().lower()
    if kind not in BASE_MODELS:
        raise BenchError(f"--models: unknown model {kind!r} in {text!r}: use {', '.join(BASE_MODELS)}")
    if kind == "plain" and pack_path is None:
        pack_path = plain_pack
        if pack_path is None:
            raise BenchError(
                "--models plain needs the plain per-bin pack: --plain-pack plain.pack "
                "(made by `noisecal calibrate captures/ -o plain.pack --plain`) or plain@plain.pack"
            )
    if comps and kind in ("oracle", "wrong"):
        raise BenchError(f"--models {text!r}: components apply to pack models, not {kind}")
    return ModelSpec(label.strip() or text.strip(), kind, comps.strip() or None, pack_path)


class Pairs:
    """Training pairs of one model at one ISO: ``noisy[j][k]`` (uint16) for clean image ``j`` and
    realization ``k``."""

    def __init__(self, noisy: list[list[np.ndarray]]):
        self.noisy = noisy


def synth_seed(data_seed: int, j: int, k: int, iso: int) -> int:
    """The noise seed of realization ``k`` of clean training image ``j`` at ``iso``: the package's
    rule for a keyed sample, :func:`noisecal.seed_for` of ``"train/j/k/iso"`` under the data seed,
    so no two (image, realization, ISO) share a seed (a linear mix of the three can collide)."""
    return noisecal.seed_for(f"train/{j}/{k}/{iso}", data_seed)


def make_pairs(
    spec: ModelSpec,
    iso: int,
    cleans: list[np.ndarray],
    realizations: int,
    pack,
    captures: dict,
    data_seed: int,
    packs: dict,
) -> Pairs:
    """The model's noisy training images for ``cleans`` at ``iso`` (the same seeds for every
    model: common random numbers)."""
    if spec.kind == "oracle" or spec.kind == "renoise":
        need_iso = iso if spec.kind == "oracle" else spec.from_iso
        out = []
        for j in range(len(cleans)):
            frames = captures.get((j, need_iso), [])
            if len(frames) < realizations:
                raise BenchError(
                    f"model {spec.label}: {len(frames)} real capture(s) of training image {j} at ISO {need_iso}, "
                    f"{realizations} needed: give --captures with <clean stem>_*.dng at that ISO (noisecal simulate "
                    "--bench writes them) or lower --realizations"
                )
            if spec.kind == "oracle":
                out.append(list(frames[:realizations]))
            else:
                out.append(
                    [
                        pack.renoise(f, need_iso, iso, synth_seed(data_seed, j, k, iso), method=spec.method)
                        for k, f in enumerate(frames[:realizations])
                    ]
                )
        return Pairs(out)
    p = packs[spec.pack_path] if spec.pack_path else pack
    model = {"plain": "noisecal", "wrong": "hg"}.get(spec.kind, spec.kind)
    offset = hg_mean_offset(p, iso) if spec.kind == "wrong" else None
    out = []
    for j, c in enumerate(cleans):
        row = []
        for k in range(realizations):
            s = synth_seed(data_seed, j, k, iso)
            try:
                n = p.synth(c, iso, s, model=model, components=spec.components)
            except noisecal.NoisecalError as e:
                raise BenchError(f"model {spec.label} at ISO {iso}: {e}") from e
            if spec.kind == "wrong":
                n = half_variance(n, c, p, iso, offset)
            row.append(n)
        out.append(row)
    return Pairs(out)


def hg_mean_offset(pack, iso: int) -> np.ndarray:
    """(4, white + 1): the mean of HG's noise (output − clean level) per CFA position and clean
    level, from the sampler tables ``pack.tables(iso, model="hg")`` (the gain shift included)."""
    t = pack.tables(iso, model="hg")
    cdf = t["cdf"].astype(np.float64) / 2.0**32
    pmf = np.diff(cdf, axis=-1, prepend=0.0)
    per_bin = (pmf * (t["first"][..., None] + np.arange(pmf.shape[-1]))).sum(-1)  # (4, bins)
    return np.take_along_axis(per_bin, t["lut"], axis=1)


def half_variance(noisy: np.ndarray, clean: np.ndarray, pack, iso: int, offset: np.ndarray | None = None) -> np.ndarray:
    """The deliberately wrong control: HG noise with half its variance, ``m + (x − m)/√2`` about
    HG's own mean ``m`` (the clean level plus :func:`hg_mean_offset`)."""
    offset = hg_mean_offset(pack, iso) if offset is None else offset
    white = int(pack.layout["white"])
    level = np.minimum(clean.astype(np.int64), white)
    pos = (np.arange(clean.shape[0])[:, None] % 2) * 2 + np.arange(clean.shape[1])[None, :] % 2
    m = level + offset[pos, level]
    out = m + (noisy.astype(np.float64) - m) / math.sqrt(2)
    return np.rint(np.clip(out, 0, white)).astype(np.uint16)


# ----------------------------------------------------------------------------------------------
# Network and training (torch)


def _torch():
    try:
        import torch
    except ImportError as e:
        raise BenchError(
            "the benchmark trains networks with torch, which is not installed: pip install torch (or "
            "pip install 'noisecal[torch]')"
        ) from e
    return torch


def make_net(width: int):
    """A compact UNet on packed 4-channel raw (two scales, residual output)."""
    torch = _torch()
    nn = torch.nn

    def block(i, o):
        return nn.Sequential(nn.Conv2d(i, o, 3, padding=1), nn.LeakyReLU(0.2), nn.Conv2d(o, o, 3, padding=1), nn.LeakyReLU(0.2))

    class UNet(nn.Module):  # type: ignore[name-defined]  # torch is imported at run time (optional extra)
        def __init__(self):
            super().__init__()
            w = width
            self.e1, self.e2, self.mid = block(4, w), block(w, 2 * w), block(2 * w, 4 * w)
            self.pool = nn.AvgPool2d(2)
            self.u2, self.d2 = nn.ConvTranspose2d(4 * w, 2 * w, 2, stride=2), block(4 * w, 2 * w)
            self.u1, self.d1 = nn.ConvTranspose2d(2 * w, w, 2, stride=2), block(2 * w, w)
            self.out = nn.Conv2d(w, 4, 1)

        def forward(self, x):
            a = self.e1(x)
            b = self.e2(self.pool(a))
            c = self.mid(self.pool(b))
            b = self.d2(torch.cat([self.u2(c), b], 1))
            a = self.d1(torch.cat([self.u1(b), a], 1))
            return x + self.out(a)

    return UNet()


def batch_plan(seed: int, steps: int, batch: int, images: int, realizations: int, shape, crop: int) -> np.ndarray:
    """The data order, (steps, batch, 4): image, realization, top and left (even: the crop keeps
    its CFA phase) of every sample. Depends on the seed and sizes alone, so every model sees the same
    crops of the same clean images in the same order."""
    rng = np.random.default_rng([seed, 0x62656E6368])
    h, w = shape
    if crop > h or crop > w:
        raise BenchError(f"--crop {crop} is larger than the training images ({h}×{w}): lower --crop")
    plan = np.empty((steps, batch, 4), dtype=np.int64)
    plan[..., 0] = rng.integers(0, images, (steps, batch))
    plan[..., 1] = rng.integers(0, realizations, (steps, batch))
    plan[..., 2] = 2 * rng.integers(0, (h - crop) // 2 + 1, (steps, batch))
    plan[..., 3] = 2 * rng.integers(0, (w - crop) // 2 + 1, (steps, batch))
    return plan


def train_one(pairs, cleans_norm, layout, plan, crop, width, seed, device, lr, progress=None):
    """Trains one network on ``pairs`` in the order ``plan``; returns it (eval mode)."""
    torch = _torch()
    torch.manual_seed(seed)
    net = make_net(width).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    steps = len(plan)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(steps, 1), eta_min=lr * 0.02)
    black, white = layout["black"], float(layout["white"])
    # Everything normalised and packed once: (images, realizations, 4, H/2, W/2).
    noisy = torch.from_numpy(np.stack([np.stack([normalise(n, black, white) for n in row]) for row in pairs.noisy]))
    clean = torch.from_numpy(np.stack(cleans_norm))
    hc = crop // 2
    ar = torch.arange(hc)
    net.train()
    for s, rows in enumerate(plan):
        r = torch.from_numpy(rows)
        ys = (r[:, 2] // 2)[:, None] + ar  # (batch, hc)
        xs = (r[:, 3] // 2)[:, None] + ar
        iy, ix = ys[:, None, :, None], xs[:, None, None, :]
        ch = torch.arange(4)[None, :, None, None]
        j, k = r[:, 0][:, None, None, None], r[:, 1][:, None, None, None]
        x = noisy[j, k, ch, iy, ix].to(device)
        y = clean[j, ch, iy, ix].to(device)
        loss = torch.nn.functional.l1_loss(net(x), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if progress is not None:
            progress(s + 1, steps, loss.item())
    net.eval()
    return net


def eval_pairs(scenes: list[EvalScene], iso: int, layout) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every evaluation frame at ``iso`` with its scene's clean image, both packed and normalised
    (cropped to a multiple of 8): made once per ISO and scored by every network."""
    black, white = layout["black"], float(layout["white"])
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for s in scenes:
        h, w = (s.clean.shape[0] // 8) * 8, (s.clean.shape[1] // 8) * 8
        c = normalise(s.clean[:h, :w], black, white)
        out.extend((normalise(f[:h, :w], black, white), c) for f in s.frames.get(iso, []))
    if not out:
        raise BenchError(f"no evaluation frames at ISO {iso}")
    return out


def score_input(pairs: list[tuple[np.ndarray, np.ndarray]]) -> dict:
    """The noisy evaluation frames themselves scored against the clean images (no network)."""
    return score([n for n, _ in pairs], [c for _, c in pairs])


def evaluate(net, pairs: list[tuple[np.ndarray, np.ndarray]], device) -> dict:
    """``net``'s output on every evaluation pair (:func:`eval_pairs`), scored."""
    torch = _torch()
    preds = []
    with torch.no_grad():
        for noisy, _ in pairs:
            preds.append(net(torch.from_numpy(noisy[None]).to(device))[0].cpu().numpy())
    return score(preds, [c for _, c in pairs])


# ----------------------------------------------------------------------------------------------
# The run


def _config_key(cfg: dict) -> str:
    return hashlib.blake2b(json.dumps(cfg, sort_keys=True).encode(), digest_size=8).hexdigest()


def _fmt(m: dict, digits: int = 2) -> str:
    return f"{m['mean']:.{digits}f}±{m['std']:.{digits}f}"


def run(args: argparse.Namespace) -> dict:
    t0 = time.time()
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr, flush=True))
    if args.set:
        root = Path(args.set)
        args.eval = args.eval or root / "eval"
        if not args.train and not args.generate:
            args.train = root / "train" / "clean"
        if not args.captures and (root / "train" / "captures").is_dir():
            args.captures = root / "train" / "captures"
    if not args.pack:
        raise BenchError("--pack is needed: the calibrated pack whose noise is benchmarked")
    if not args.eval:
        raise BenchError("--eval DIR is needed (or --set DIR): per scene a base-ISO burst and frames at target ISOs")
    pack = noisecal.Pack.load(args.pack)
    layout = pack.layout
    scenes = load_eval(Path(args.eval), pack)
    eval_isos = sorted({i for s in scenes for i in s.frames})
    try:
        isos = eval_isos if not args.isos else [int(i) for i in args.isos.split(",") if i.strip()]
    except ValueError:
        raise BenchError(f"--isos {args.isos!r}: give whole ISOs separated by commas, e.g. 400,1600") from None
    missing = [i for i in isos if i not in eval_isos]
    if missing:
        raise BenchError(f"--isos {missing}: the evaluation set has frames at ISOs {eval_isos} only")
    if args.train:
        names, cleans = load_clean(Path(args.train), pack)
    else:
        n = args.generate or 16
        h, w = (scenes[0].clean.shape[0] // 2) * 2, (scenes[0].clean.shape[1] // 2) * 2
        names, cleans = [f"gen{i:03}" for i in range(n)], generate_clean(n, h, w, layout, args.data_seed, args.mono, parse_levels(args.generate_levels, layout))
    captures = load_captures(Path(args.captures), names, pack) if args.captures else {}
    shapes = {c.shape for c in cleans}
    if len(shapes) != 1:
        raise BenchError(f"--train: clean images of different sizes {sorted(shapes)}: use one size (crops are drawn from each)")
    if args.realizations:
        realizations = args.realizations
    elif captures:
        realizations = min(len(v) for v in captures.values())
    else:
        realizations = 4
    packs = {args.pack: pack}  # a model naming the main pack's file does not load it again
    specs = [parse_model(m, args.plain_pack) for m in args.models.split(",") if m.strip()]
    for c in args.components or []:
        specs.append(ModelSpec(f"noisecal:{c}", "noisecal", c))
    for s in specs:
        if s.pack_path and s.pack_path not in packs:
            packs[s.pack_path] = noisecal.Pack.load(s.pack_path)
        if s.kind == "oracle" and not captures:
            raise BenchError(
                "model oracle trains on the sensor's own noise: give --captures (real captures of the training scenes, "
                "<clean stem>_*.dng; `noisecal simulate --bench DIR` writes them) or drop oracle from --models"
            )
    labels = [s.label for s in specs]
    if len(set(labels)) != len(labels):
        raise BenchError(f"--models: labels repeat in {labels}: name them LABEL=MODEL")
    jobs = [(s, iso) for s in specs for iso in isos]
    if args.renoise_from is not None:
        a, b = args.renoise_from, args.renoise_to
        if b is None or b not in eval_isos or not captures:
            raise BenchError(
                "noise on noise needs --renoise-to B at an ISO of the evaluation set and --captures holding real ISO-A "
                "captures of the training scenes"
            )
        for m in RENOISE_METHODS:
            jobs.append((ModelSpec(f"{m} {a}→{b}", "renoise", method=m, from_iso=a), b))
        if not any(s.kind == "oracle" for s in specs):
            jobs.append((ModelSpec(f"real {b}", "oracle"), b))
    cleans_norm = [normalise(c, layout["black"], layout["white"]) for c in cleans]
    seeds = list(range(args.seed, args.seed + args.seeds))
    torch = _torch()
    device = torch.device(args.device)
    if args.threads:
        torch.set_num_threads(args.threads)
    steps = args.steps
    n_nets = len(jobs) * len(seeds)
    if args.minutes:
        probe = batch_plan(0, 6, args.batch, len(cleans), realizations, cleans[0].shape, args.crop)
        dummy = Pairs([[c] * realizations for c in cleans])
        train_one(dummy, cleans_norm, layout, probe[:2], args.crop, args.width, 0, device, args.lr)  # warm-up
        t = time.time()
        train_one(dummy, cleans_norm, layout, probe, args.crop, args.width, 0, device, args.lr)
        per_step = (time.time() - t) / len(probe)
        fit = int(args.minutes * 60 * 0.85 / (n_nets * per_step))
        steps = max(20, min(steps, fit)) if args.steps_given else max(20, fit)
        say(f"--minutes {args.minutes}: {per_step * 1000:.1f} ms per step → {steps} steps per network ({n_nets} networks)")
    cfg = {
        # Every pack a model reads, by its file's bytes: a pack changed on disk is not resumed.
        "packs": {p: hashlib.blake2b(Path(p).read_bytes(), digest_size=8).hexdigest() for p in sorted(packs)},
        "eval": str(Path(args.eval).resolve()),
        "train": str(Path(args.train).resolve())
        if args.train
        else f"generated:{len(cleans)}" + (":mono" if args.mono else "") + (f":{args.generate_levels}" if args.generate_levels else ""),
        "steps": steps,
        "batch": args.batch,
        "crop": args.crop,
        "width": args.width,
        "lr": args.lr,
        "realizations": realizations,
        "data_seed": args.data_seed,
        "device": args.device,
    }
    key = _config_key(cfg)
    state = Path(args.state) if args.state else None
    if state:
        state.mkdir(parents=True, exist_ok=True)
    prepared: dict[int, list] = {}

    def eval_at(iso: int) -> list:
        if iso not in prepared:
            prepared[iso] = eval_pairs(scenes, iso, layout)
        return prepared[iso]

    results = []
    done = 0
    for spec, iso in jobs:
        pairs = None
        for seed in seeds:
            done += 1
            tag = f"[{done}/{n_nets}] {spec.label} ISO {iso} seed {seed}"
            fname = None
            if state:
                fname = state / f"{key}-{hashlib.blake2b(f'{spec}|{iso}|{seed}'.encode(), digest_size=6).hexdigest()}.json"
                if fname.exists():
                    results.append(json.loads(fname.read_text()))
                    say(f"{tag}: resumed from {fname.name}")
                    continue
            if pairs is None:
                pairs = make_pairs(spec, iso, cleans, realizations, pack, captures, args.data_seed, packs)
            plan = batch_plan(seed, steps, args.batch, len(cleans), realizations, cleans[0].shape, args.crop)
            ts = time.time()

            def progress(s, n, loss, tag=tag, ts=ts):
                tty = sys.stderr.isatty()
                if not args.quiet and (s == n or s % max(1, n // (20 if tty else 4)) == 0):
                    end = "\n" if s == n or not tty else "\r"
                    print(f"{tag}: step {s}/{n} loss {loss:.4f} {time.time() - ts:.0f} s", end=end, file=sys.stderr, flush=True)

            net = train_one(pairs, cleans_norm, layout, plan, args.crop, args.width, seed, device, args.lr, progress)
            r = {"model": spec.label, "kind": spec.kind, "iso": iso, "seed": seed, **evaluate(net, eval_at(iso), device)}
            r["train_seconds"] = time.time() - ts
            results.append(r)
            if fname:
                fname.write_text(json.dumps(r))
    inputs = {iso: score_input(eval_at(iso)) for iso in sorted({iso for _, iso in jobs})}
    out: dict[str, Any] = {
        "config": cfg,
        "input": inputs,
        "isos": isos,
        "calibrated_isos": pack.calibrated_isos,
        "seeds": seeds,
        "networks": results,
        "summary": summary(results),
        "wall_seconds": time.time() - t0,
    }
    out["controls"] = controls(out["summary"])
    return out


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
    data — and by ``wrong_margin_db`` > 0.3 dB on the means)?"""
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
            others = {k: r for k, r in at.items() if k != wrong[0]}
            c["wrong_worst"] = all(mean[w["model"]] < r["psnr"]["mean"] for r in others.values())
            c["wrong_margin_db"] = (min(r["psnr"]["mean"] for r in others.values()) - mean[w["model"]]) if others else None
            ws = w.get("psnr_per_seed", {})
            paired = all(
                seed in r.get("psnr_per_seed", {}) and r["psnr_per_seed"][seed] > v
                for r in others.values()
                for seed, v in ws.items()
            )
            c["wrong_clear"] = bool(others) and bool(ws) and paired and c["wrong_margin_db"] > 0.3
        out[iso] = c
    return out


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
        inp = out.get("input", {}).get(iso)
        if inp:
            bs = "  ".join(f"{inp['bands'][b]['psnr']:>12.2f}" if b in inp["bands"] else f"{'':>12}" for b in bands)
            lines.append(f"{'(noisy input)':<22}{iso:>6}  {inp['psnr']:>12.2f}  {inp['ssim']:>14.4f}  {'':>12}  {bs}")
        lines.append("")
    for iso, c in out["controls"].items():
        parts = []
        if "oracle_best" in c:
            verdict = "yes" if c["oracle_best"] else ("within the seed spread" if c["oracle_within_spread"] else "NO")
            parts.append(f"oracle best: {verdict} (best − oracle {c['oracle_gap_db']:.2f} dB)")
        if "wrong_worst" in c:
            verdict = "yes, clearly" if c["wrong_clear"] else ("yes, but not clearly" if c["wrong_worst"] else "NO")
            parts.append(f"wrong worst: {verdict} (by {c['wrong_margin_db']:.2f} dB)")
        if parts:
            lines.append(f"controls at ISO {iso}: " + "; ".join(parts))
    n = len(out["networks"])
    lines.append(
        f"{n} networks, {out['config']['steps']} steps each (batch {out['config']['batch']}, crop {out['config']['crop']}, "
        f"width {out['config']['width']}), seeds {out['seeds']}, {out['wall_seconds'] / 60:.1f} min"
    )
    lines.append("PSNR/SSIM: mean±std over training seeds; bands: PSNR of the pooled error by clean level (dark < 2 % of range)")
    return "\n".join(lines)


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
    p.add_argument("--captures", type=Path, help="real captures of the training scenes (<clean stem>_*.dng): oracle, noise on noise")
    p.add_argument("--set", type=Path, help="a folder laid out as `noisecal simulate --bench` writes it")
    p.add_argument("--models", default=DEFAULT_MODELS, help=f"comma-separated [LABEL=]MODEL[:COMPONENTS][@PACK]; MODEL in {', '.join(BASE_MODELS)} [default: %(default)s]")
    p.add_argument("--components", action="append", help="add a noisecal row with these components (e.g. pixel), repeatable")
    p.add_argument("--plain-pack", help="the plain per-bin pack for the `plain` model (noisecal calibrate --plain)")
    p.add_argument("--isos", help="target ISOs to benchmark (comma-separated) [default: all in --eval]")
    p.add_argument("--renoise-from", type=int, help="noise on noise: train on real ISO-A captures re-noised to --renoise-to")
    p.add_argument("--renoise-to", type=int)
    p.add_argument("--steps", type=int, default=1500, help="training steps per network [default: %(default)s]")
    p.add_argument("--minutes", type=float, help="time budget for all networks: sets the steps per network (≤ --steps when given)")
    p.add_argument("--seeds", type=int, default=2, help="training seeds per model and ISO [default: %(default)s]")
    p.add_argument("--seed", type=int, default=0, help="first training seed [default: %(default)s]")
    p.add_argument("--data-seed", type=int, default=1, help="seed of the synthetic noise and generated scenes [default: %(default)s]")
    p.add_argument("--realizations", type=int, help="noisy images per clean image and ISO [default: as many as --captures has, else 4]")
    p.add_argument("--batch", type=int, default=16, help="crops per step [default: %(default)s]")
    p.add_argument("--crop", type=int, default=48, help="training crop side in raw pixels, a multiple of 8 [default: %(default)s]")
    p.add_argument("--width", type=int, default=16, help="UNet width (channels at the first scale) [default: %(default)s]")
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


if __name__ == "__main__":
    sys.exit(main())
