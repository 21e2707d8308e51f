"""The noise models: what produces each model's training pairs (a pack's synthesis, the
baselines, the wrong-model control, the oracle's real captures, noise on noise), all with the
same seeds (common random numbers)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import noisecal

from .errors import BenchError
from .scaled_hg import ScaledHg

BASE_MODELS = ("noisecal", "hg", "pg", "noiseprofile", "plain", "wrong", "loud", "oracle")
RENOISE_METHODS = ("bridge", "quantile", "denoised", "naive")
DEFAULT_MODELS = "oracle,noisecal,hg,pg,wrong"
# The HG controls and their factor on HG's variance (scaled_hg.py).
CONTROL_FACTORS = {"wrong": 0.5, "loud": 2.0}


@dataclass
class ModelSpec:
    label: str
    kind: str  # one of BASE_MODELS, or "renoise"
    components: str | None = None
    pack_path: str | None = None
    method: str | None = None  # renoise method
    from_iso: int | None = None
    # Noise on noise: the clean estimate that picks the bins (estimate.ESTIMATES). Out of the repr,
    # which keys --state files: the run adds it to the key when set, so earlier runs' files stay valid.
    estimate: str | None = field(default=None, repr=False)
    # A control's factor on HG's variance when given (``loud:4``); None: CONTROL_FACTORS'. Out of the
    # repr as ``estimate``: the run adds it to the --state key when set.
    factor: float | None = field(default=None, repr=False)

    def control_factor(self) -> float:
        """The factor on HG's variance of a ``wrong`` or ``loud`` row."""
        return self.factor if self.factor is not None else CONTROL_FACTORS[self.kind]


def parse_model(text: str, plain_pack: str | None = None) -> ModelSpec:
    """``[LABEL=]MODEL[:COMPONENTS][@PACK]``: e.g. ``hg``, ``noisecal:pixel``,
    ``interp=noisecal@held-out-isos.pack``, ``plain@plain.pack``; for the HG controls
    ``[LABEL=]wrong|loud[:FACTOR]``, the factor on HG's variance (e.g. ``loud4=loud:4``)."""
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
    if comps and kind == "oracle":
        raise BenchError(f"--models {text!r}: components apply to pack models, not {kind}")
    factor = None
    if comps and kind in CONTROL_FACTORS:
        try:
            factor = float(comps)
        except ValueError:
            factor = -1.0
        if not (factor > 0 and np.isfinite(factor)):
            raise BenchError(
                f"--models {text!r}: components apply to pack models, not {kind}; after {kind}: give its factor on HG's "
                f"variance, a number above 0 (e.g. {'wrong:0.25' if kind == 'wrong' else 'loud:4'})"
            )
        if (kind == "wrong") != (factor < 1):
            raise BenchError(f"--models {text!r}: the {kind} control's factor must be {'below' if kind == 'wrong' else 'above'} 1")
        comps = ""
    return ModelSpec(label.strip() or text.strip(), kind, comps.strip() or None, pack_path, factor=factor)


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
    estimates=None,
) -> Pairs:
    """The model's noisy training images for ``cleans`` at ``iso`` (the same seeds for every
    model: common random numbers). ``estimates`` (noise on noise): the clean estimate of each
    source capture, ``estimates[j][k]`` (float32 DN), or ``None`` for the core's built-in one."""
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
                row = []
                for k, f in enumerate(frames[:realizations]):
                    s = synth_seed(data_seed, j, k, iso)
                    if estimates is None or spec.method == "naive":
                        row.append(pack.renoise(f, need_iso, iso, s, method=spec.method))
                    else:
                        row.append(pack.renoise(f, need_iso, iso, s, method=spec.method, estimate=estimates[j][k]))
                out.append(row)
        return Pairs(out)
    p = packs[spec.pack_path] if spec.pack_path else pack
    model = {"plain": "noisecal", "wrong": "hg", "loud": "hg"}.get(spec.kind, spec.kind)
    parametric = model in PARAMETRIC
    # The controls: HG's noise at ½ (wrong) or 2 (loud) times its variance at every level, drawn
    # whole (scaled_hg.py: scaling HG's whole-DN noise left sub-DN noise as it was).
    scaled = ScaledHg(p, iso, spec.control_factor()) if spec.kind in CONTROL_FACTORS else None
    out = []
    for j, c in enumerate(cleans):
        row = []
        # A parametric baseline is zero-mean about the level it is given: it is handed the clean
        # image at the target ISO's brightness (clean_at="target": its noise drawn at the
        # reference level), so its noisy images are as bright as the pack's and the real ones.
        at = at_target_brightness(c, p, iso) if parametric else c
        for k in range(realizations):
            s = synth_seed(data_seed, j, k, iso)
            try:
                if scaled is not None:
                    n = scaled.draw(at, s)
                elif parametric:
                    n = p.synth(at, iso, s, model=model, components=spec.components, clean_at="target")
                else:
                    n = p.synth(c, iso, s, model=model, components=spec.components)
            except noisecal.NoisecalError as e:
                raise BenchError(f"model {spec.label} at ISO {iso}: {e}") from e
            row.append(n)
        out.append(row)
    return Pairs(out)


# The parametric baselines: zero-mean noise about the level they are given.
PARAMETRIC = ("hg", "pg", "noiseprofile")


def at_target_brightness(clean: np.ndarray, pack, iso: int) -> np.ndarray:
    """``clean`` (uint16 DN at the reference ISO's brightness, as the training images are) carried
    to the target ISO's brightness: ``black + g·(clean − black)`` with the pack's gain ratios ``g``
    per CFA position (``Pack.gain_ratios``), rounded and clamped to ``[0, white]``.

    Why: under the clean-at convention's default (``reference``, docs/method.md) a clean image at
    the reference brightness comes out at the target ISO's, the pack's PMFs carrying the gain
    shift ``(g − 1)·(l − black)`` as their mean, and so do real captures. The parametric baselines
    are zero-mean, so without this their networks would also be taught a brightness error (about
    3 % at ISO 1600 on phone12) that has nothing to do with their noise. Given the clean image at
    the target brightness with ``clean_at="target"``, a baseline draws its noise at the reference
    level and adds it to the target-brightness level: the same gain shift, the baseline's own
    noise."""
    g = np.asarray(pack.gain_ratios(iso), dtype=np.float64)
    lay = pack.layout
    black = np.asarray(lay["black"], dtype=np.float64)
    pos = cfa_positions(clean.shape)
    b = black[pos]
    out = b + g[pos] * (clean.astype(np.float64) - b)
    return np.rint(np.clip(out, 0, int(lay["white"]))).astype(np.uint16)


def cfa_positions(shape: tuple[int, ...]) -> np.ndarray:
    """(h, w): each pixel's CFA position, the core's ``position(row, column)`` = 2·(row % 2) + column % 2."""
    return (np.arange(shape[0])[:, None] % 2) * 2 + np.arange(shape[1])[None, :] % 2


def interpolation_notes(specs: list, isos: list, pack, packs: dict) -> list[str]:
    """One line per pack model (``noisecal``, ``plain``) and benchmarked ISO its pack does not
    calibrate: the row's noise is interpolated, and when the ISO lies where the sensor switches
    conversion gain the pack's warning goes with it. The core then models the ISO from one side of
    the switch, and a wrong side shows in the table as a brightness error (the other gain ratio)
    that costs the bright bands most (docs/bench.md, "interpolated ISOs")."""
    notes = []
    for s in specs:
        if s.kind not in ("noisecal", "plain"):
            continue
        p = packs[s.pack_path] if s.pack_path else pack
        for iso in isos:
            if iso in p.calibrated_isos:
                continue
            try:
                derived = p.interp([iso])
            except noisecal.NoisecalError:
                continue  # not interpolable: make_pairs refuses the row with the core's message
            new = [w for w in derived.warnings if w not in p.warnings]
            notes.append(f"{s.label} at ISO {iso}: interpolated by its pack" + "".join(f"; {w}" for w in new))
    return notes
