"""The benchmark with its network replaced by a linear denoiser fitted in closed form: a ranking of
the noise models with the training converged and no seed luck.

    python tests/bench/linear_probe.py sim|set002 [the script's and noisecal-bench's options]

``sim`` runs tests/bench/sim_tiles.py, ``set002`` tests/bench/emva1288_ladder.py, each with
``noisecal.bench``'s ``train_one`` replaced (for this process only) by a least-squares fit: the
same input as the network with ``--highpass`` (the packed frame's 5×5 high-pass in units of the
real evaluation noise, so level-blind as the network is), features the 5×5 neighbourhood of that
high-pass per channel, the centre clipped to ±1 and through tanh(3·), the mean absolute high-pass
and a constant; the target the network's (clean − noisy in the same unit); 20 000 pixels drawn per
training image and realization (the training seed draws them; ``--steps`` is not used). The
model's pairs, targets, evaluation and scores are the benchmark's own (``make_pairs``,
``training_targets``, ``evaluate``), so the rows differ only by their training noise.

Why: a network of a few hundred steps is far from converged and its score moves 0.1–0.4 dB with
the training seed; a row trained on independent noise (the oracle's real captures) does not share
HG's and the pack's random numbers, so its paired differences are noisier than theirs. The fit
converges, so the order it gives is the order of the training noises on this evaluation set for
this (linear) denoiser class: docs/bench.md, "The oracle's clean image"."""

from __future__ import annotations

import sys

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

import noisecal.bench  # noqa: F401  (loads noisecal.bench.run, whose train_one main() replaces)
from noisecal.bench.layout import normalise

RADIUS = 2  # the 5×5 neighbourhood of the high-pass
DRAWN = 20_000  # pixels drawn per training image and realization


def features(x: np.ndarray, sigma: float) -> np.ndarray:
    """(4, h, w) normalised packed frame → (4·h·w, 29) features (module docstring)."""
    p = np.pad(x, ((0, 0), (2, 2), (2, 2)), mode="edge")
    hp = (x - sliding_window_view(p, (5, 5), axis=(1, 2)).mean(axis=(-1, -2))) / sigma
    q = np.pad(hp, ((0, 0), (RADIUS, RADIUS), (RADIUS, RADIUS)), mode="edge")
    n = 2 * RADIUS + 1
    f = sliding_window_view(q, (n, n), axis=(1, 2)).reshape(*hp.shape, n * n)
    c = hp[..., None]
    extra = [np.clip(c, -1, 1), np.tanh(3 * c), np.abs(f).mean(-1, keepdims=True), np.ones_like(c)]
    return np.concatenate([f, *extra], -1).reshape(-1, n * n + len(extra))


def train_linear(pairs, cleans_norm, layout, plan, crop, width, seed, device, lr, progress=None, input_scale=1.0, loss="mse", highpass_sigma=None):
    """``noisecal.bench.training.train_one``'s signature; returns a callable on a torch batch."""
    import torch

    if highpass_sigma is None:
        raise SystemExit("linear_probe.py: pass --highpass (the probe's input is the network's high-pass)")
    sigma = float(highpass_sigma)
    rng = np.random.default_rng(seed)
    black, white = layout["black"], float(layout["white"])
    xs, ys = [], []
    for j, row in enumerate(pairs.noisy):
        y = np.asarray(cleans_norm[j], np.float64)
        for noisy in row:
            x = normalise(noisy, black, white).astype(np.float64)
            f, t = features(x, sigma), ((y - x) / sigma).reshape(-1)
            pick = rng.choice(f.shape[0], min(DRAWN, f.shape[0]), replace=False)
            xs.append(f[pick])
            ys.append(t[pick])
    weights = np.linalg.lstsq(np.concatenate(xs), np.concatenate(ys), rcond=None)[0]

    def net(batch):
        x = batch[0].cpu().numpy().astype(np.float64)
        out = x + sigma * (features(x, sigma) @ weights).reshape(x.shape)
        return torch.from_numpy(out[None].astype(np.float32))

    return net


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("sim", "set002"):
        print("usage: linear_probe.py sim|set002 [options of sim_tiles.py or emva1288_ladder.py]", file=sys.stderr)
        return 2
    # noisecal.bench's __init__ binds the name ``run`` to the function: the module is in sys.modules.
    sys.modules["noisecal.bench.run"].train_one = train_linear  # type: ignore[attr-defined]
    if argv[0] == "sim":
        import sim_tiles as script
    else:
        import emva1288_ladder as script
    return script.main(argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
