"""noisecal: calibrated, non-parametric camera sensor noise for training data.

A *model pack* (made by the noisecal app on a phone, or by ``noisecal calibrate`` /
:func:`calibrate` from DNG bursts) holds, per ISO, CFA position and level, the measured noise
distribution of one camera. This package synthesizes that noise on clean raw images, re-noises
captures to a higher ISO and interpolates ISOs, from numpy arrays, with the same bytes as the
``noisecal`` command for the same inputs and seeds.

>>> import noisecal
>>> pack = noisecal.Pack.load("pixel6.pack")
>>> noisy = pack.synth(clean_u16, iso=1600, seed=7, cfa_origin=(y0, x0))

Errors: ``NoisecalError`` (a ``ValueError``) for every failure; its ``InputError`` for a wrong
argument (the message names it and the fix) and ``MismatchError`` for an image of another sensor
(``read_dng(path, pack=pack)``); a wrong dtype is a ``TypeError``. A ``Pack`` pickles (by its
bytes) and works in forked and spawned workers (DataLoader, multiprocessing, Ray).

Seeds: a batch ``(N, H, W)`` uses ``seed + i`` for image ``i``; a folder of files is seeded by
name, ``seed_for(file name, seed)``, the rule of ``noisecal synth`` on a folder and of
:mod:`noisecal.ray`.

HG's rounded Gaussian: ``rounded_gaussian_sd(var)`` is the SD whose ``round(N(0, s²))`` has the
integer variance ``var`` (DN², per element; the core's rule for HG's tables, exact below 1.3 DN²
where ``var − 1/12`` undershoots), ``rounded_variance(sd)`` its inverse.

Torch users: :mod:`noisecal.torch` (``NoiseSynth`` on any device). Ray Data users:
:mod:`noisecal.ray` (``RenoiseActor`` for ``Dataset.map_batches``). Does a pack train a better
denoiser than HG on your captures? :mod:`noisecal.bench` (``noisecal-bench``, needs torch).
"""

from ._noisecal import (
    InputError,
    MismatchError,
    NoisecalError,
    NoisecalWarning,
    Pack,
    __version__,
    calibrate,
    read_dng,
    rounded_gaussian_sd,
    rounded_variance,
    write_dng,
    write_raw_dng,
)
from .seeds import seed_for

__all__ = [
    "NoisecalError",
    "InputError",
    "MismatchError",
    "NoisecalWarning",
    "Pack",
    "calibrate",
    "read_dng",
    "write_dng",
    "write_raw_dng",
    "seed_for",
    "rounded_gaussian_sd",
    "rounded_variance",
    "__version__",
]


def _pack_from_bytes(data: bytes, pattern_cache_mb: int = 192) -> Pack:
    """Unpickles a :class:`Pack` (``Pack.__reduce__`` gives its bytes and its ``pattern_cache_mb``)."""
    pack = Pack.from_bytes(data)
    pack.set_pattern_cache_mb(pattern_cache_mb)
    return pack
