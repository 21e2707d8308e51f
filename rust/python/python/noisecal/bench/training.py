"""Training one network on a model's pairs: the data order every model shares (``batch_plan``)
and the seeded training loop (L1 or MSE, Adam, cosine decay)."""

from __future__ import annotations

import numpy as np

from .errors import BenchError
from .layout import normalise
from .network import _torch, make_net


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


LOSSES = ("l1", "mse")


def train_one(
    pairs, cleans_norm, layout, plan, crop, width, seed, device, lr, progress=None, input_scale=1.0, loss="l1", highpass_sigma=None
):
    """Trains one network on ``pairs`` in the order ``plan``; returns it (eval mode). ``loss``:
    ``l1`` or ``mse`` (the squared error PSNR scores); ``highpass_sigma``: :func:`make_net`'s."""
    if loss not in LOSSES:
        raise BenchError(f"loss {loss!r}: use one of {', '.join(LOSSES)}")
    torch = _torch()
    torch.manual_seed(seed)
    net = make_net(width, input_scale, highpass_sigma).to(device)
    loss_fn = torch.nn.functional.l1_loss if loss == "l1" else torch.nn.functional.mse_loss
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
        err = loss_fn(net(x), y)
        opt.zero_grad()
        err.backward()
        opt.step()
        sched.step()
        if progress is not None:
            progress(s + 1, steps, err.item())
    net.eval()
    return net
