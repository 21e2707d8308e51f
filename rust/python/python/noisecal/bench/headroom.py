"""How much of the evaluation set's noise a denoiser can remove, and how (numpy, no network):
the gain of the best linear filter and of a filter that knows the clean image's flat regions.

A network starts as the identity and first learns what a linear filter can do; where the best
linear filter gains nothing (noise far below the edges' contrast: every smoothing loses more at
the edges than it wins in the flat regions), only an edge-aware filter removes noise, and a
network of a short budget may stay the identity (docs/bench.md, "Why nothing learnt on EMVA set
002"). The clean-guided filter says whether there is noise to remove at all."""

from __future__ import annotations

import math

import numpy as np

from .metrics import psnr


def _neighbour_differences(noisy: np.ndarray, radius: int) -> np.ndarray:
    """(C, H, W, K): for each pixel the K = (2r+1)² − 1 neighbours within ``radius`` less the
    pixel itself (edges replicated), per packed channel."""
    r = radius
    p = np.pad(np.asarray(noisy, np.float64), ((0, 0), (r, r), (r, r)), mode="edge")
    h, w = noisy.shape[1:]
    shifts = [(dy, dx) for dy in range(2 * r + 1) for dx in range(2 * r + 1) if (dy, dx) != (r, r)]
    return np.stack([p[:, dy : dy + h, dx : dx + w] - noisy for dy, dx in shifts], -1)


def _db(preds: list[np.ndarray], pairs: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """Mean PSNR gain of ``preds`` over the noisy inputs, as the scores average PSNR over images."""
    gains = [psnr(p, c) - psnr(n, c) for p, (n, c) in zip(preds, pairs)]
    finite = [g for g in gains if math.isfinite(g)]  # a noiseless input scores inf: nothing to gain there
    return float(np.mean(finite)) if finite else math.nan


def linear_gain(pairs: list[tuple[np.ndarray, np.ndarray]], radius: int = 2) -> float:
    """The PSNR gain in dB of the best linear residual filter, ``noisy + Σ_k w_k (noisy_k − noisy)``
    over the neighbours ``k`` within ``radius`` (one set of weights for every channel: it keeps a
    flat level), least squares against the clean images. Fitted on every other pair and scored on
    the rest (one pair: fitted and scored on it, which flatters it a little). On a flat field under
    white noise it is the box mean: 10·log10((2r+1)²) dB (13.98 at radius 2)."""
    fit, test = (pairs[::2], pairs[1::2]) if len(pairs) > 1 else (pairs, pairs)
    k = (2 * radius + 1) ** 2 - 1
    xtx, xty = np.zeros((k, k)), np.zeros(k)
    for n, c in fit:
        x = _neighbour_differences(n, radius).reshape(-1, k)
        y = (np.asarray(c, np.float64) - n).reshape(-1)
        xtx += x.T @ x
        xty += x.T @ y
    w = np.linalg.lstsq(xtx, xty, rcond=None)[0]
    preds = [n + (_neighbour_differences(n, radius) @ w) for n, _ in test]
    return _db(preds, test)


def guided_gain(pairs: list[tuple[np.ndarray, np.ndarray]], tolerance: float, radius: int = 2) -> float:
    """The PSNR gain in dB of a filter told where the clean image is flat: each pixel the mean of
    its neighbours within ``radius`` whose clean value is within ``tolerance`` (normalised units)
    of its own, each carried to the pixel's clean level (``noisy_k − clean_k + clean``). Not a
    denoiser (it reads the clean image): the noise there is to remove, for a filter that finds the
    edges."""
    r = radius
    preds = []
    for n, c in pairs:
        n64, c64 = np.asarray(n, np.float64), np.asarray(c, np.float64)
        h, w = n.shape[1:]
        pn = np.pad(n64, ((0, 0), (r, r), (r, r)), mode="edge")
        pc = np.pad(c64, ((0, 0), (r, r), (r, r)), mode="edge")
        acc, cnt = np.zeros_like(n64), np.zeros_like(n64)
        for dy in range(2 * r + 1):
            for dx in range(2 * r + 1):
                nk, ck = pn[:, dy : dy + h, dx : dx + w], pc[:, dy : dy + h, dx : dx + w]
                near = np.abs(ck - c64) <= tolerance
                acc += np.where(near, nk - ck + c64, 0.0)
                cnt += near
        preds.append(acc / cnt)  # the centre is always near itself: cnt ≥ 1
    return _db(preds, pairs)


def headroom(pairs: list[tuple[np.ndarray, np.ndarray]], tolerance: float) -> dict:
    """Both gains (dB) over the noisy input on one ISO's evaluation pairs."""
    lin, guided = linear_gain(pairs), guided_gain(pairs, tolerance)
    return {"linear_db": lin if math.isfinite(lin) else None, "guided_db": guided if math.isfinite(guided) else None}
