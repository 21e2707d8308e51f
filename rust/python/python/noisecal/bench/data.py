"""Images from disk: the evaluation set (per scene a base-ISO burst or a given clean image, and
frames at target ISOs), clean training DNGs and real captures of them; the evaluation pairs,
packed and normalised once per ISO."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import noisecal

from .errors import BenchError
from .layout import normalise


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


def load_float_clean(train_dir: Path, names: list[str], cleans: list[np.ndarray]) -> list[np.ndarray] | None:
    """The clean training images before their rounding to whole DN, when the folder gives them:
    ``<stem>.npy`` beside every ``<stem>.dng`` (float DN, black included; the DNG is its rounding).
    ``None`` when no ``.npy`` is there. The real captures of a scene (``--captures``) are drawn
    about this image, not about the DNG's whole DN, as a real evaluation frame is about a burst's
    float mean: the rows trained on captures (the oracle, noise on noise) take it as their target
    (docs/bench.md, "the oracle's clean image")."""
    train_dir = Path(train_dir)
    given = [train_dir / f"{n}.npy" for n in names]
    have = [p.is_file() for p in given]
    if not any(have):
        return None
    if not all(have):
        missing = [p.name for p, h in zip(given, have) if not h]
        raise BenchError(
            f"--train {train_dir}: {len(missing)} clean image(s) have no .npy beside their DNG (e.g. {missing[0]}): "
            "give the float clean image of every training DNG or of none"
        )
    out = []
    for p, c in zip(given, cleans):
        try:
            f = np.load(p, allow_pickle=False)
        except (OSError, ValueError) as e:
            raise BenchError(f"--train: {p} is not a numpy array file ({e}): save it with np.save") from e
        if f.ndim != 2 or f.shape != c.shape or not np.issubdtype(f.dtype, np.number):
            raise BenchError(f"--train: {p} is {f.dtype} {f.shape}; its DNG is {c.shape}: give one number per pixel")
        if not np.isfinite(f).all():
            raise BenchError(f"--train: {p} holds NaN or infinite values")
        f = f.astype(np.float64)
        off = float(np.max(np.abs(f - c.astype(np.float64))))
        if off > 1.0:
            raise BenchError(
                f"--train: {p} is {off:.2f} DN from its DNG somewhere: the DNG must be the .npy rounded to whole DN"
            )
        out.append(f)
    return out


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
