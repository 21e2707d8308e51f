"""The clean estimate noise on noise starts from (paper §4.2, §5.3): the level that picks each
pixel's bin in the bridge, quantile and denoised re-noise. As the paper does it, by default: a
denoiser trained on the pack's synthetic noise at the source ISO (the same network and budget as
every row), applied to the real source-ISO captures. Or the core's built-in filter, or the known
clean training images (a perfect denoiser: the methods' upper bound)."""

from __future__ import annotations

import numpy as np

from .errors import BenchError
from .layout import normalise, unpack_raw
from .network import _torch

ESTIMATES = ("denoiser", "filter", "clean")
DEFAULT_ESTIMATE = "denoiser"


def parse_estimates(text: str) -> list[str]:
    names = [e.strip().lower() for e in text.split(",") if e.strip()]
    bad = [e for e in names if e not in ESTIMATES]
    if bad or not names:
        raise BenchError(f"--renoise-estimate {bad or '(none)'}: use some of {', '.join(ESTIMATES)}")
    return list(dict.fromkeys(names))


def denoise(net, raw: np.ndarray, layout, device) -> np.ndarray:
    """``net`` applied to one raw capture: float32 DN (black included), the capture's shape. The
    packed image is padded by reflection to a multiple of 4 (the UNet's two scales) and cropped
    back."""
    torch = _torch()
    black, white = layout["black"], float(layout["white"])
    x = normalise(raw, black, white)
    h, w = x.shape[1:]
    ph, pw = (-h) % 4, (-w) % 4
    if ph or pw:
        x = np.pad(x, ((0, 0), (0, ph), (0, pw)), mode="reflect")
    with torch.no_grad():
        y = net(torch.from_numpy(np.ascontiguousarray(x))[None].to(device))[0].cpu().numpy()[:, :h, :w]
    b = np.asarray(black, dtype=np.float64).reshape(4, 1, 1)
    return unpack_raw(y.astype(np.float64) * (white - b) + b).astype(np.float32)


def estimates_for(kind: str, frames: list[list[np.ndarray]], cleans: list[np.ndarray], train_denoiser, layout, device):
    """Per training image ``j`` and capture ``k``, the clean estimate of ``frames[j][k]`` (float32
    DN), or ``None`` for ``filter`` (the core's own). ``train_denoiser()`` gives the source-ISO
    denoiser (trained once, on demand)."""
    if kind == "filter":
        return None
    if kind == "clean":
        return [[cleans[j].astype(np.float32)] * len(row) for j, row in enumerate(frames)]
    if kind == "denoiser":
        net = train_denoiser()
        return [[denoise(net, f, layout, device) for f in row] for row in frames]
    raise BenchError(f"unknown clean estimate {kind!r}: use {', '.join(ESTIMATES)}")
