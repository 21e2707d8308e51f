"""The network every model trains: a compact UNet on packed 4-channel raw (torch, imported
only when a network is made: torch is an optional extra)."""

from __future__ import annotations

from .errors import BenchError


def _torch():
    try:
        import torch
    except ImportError as e:
        raise BenchError(
            "the benchmark trains networks with torch, which is not installed: pip install torch (or "
            "pip install 'noisecal[torch]')"
        ) from e
    return torch


def make_net(width: int, input_scale: float = 1.0):
    """A compact UNet on packed 4-channel raw (two scales, residual output). ``input_scale``: the
    layers see the input times this factor and their correction is divided by it, so a sensor whose
    noise is a small fraction of the range (dim frames, a deep bit depth) reaches the layers at a
    workable size; 1 leaves the network exactly as without it."""
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
            if input_scale != 1.0:
                return x + self.correction(x * input_scale) / input_scale
            return x + self.correction(x)

        def correction(self, x):
            a = self.e1(x)
            b = self.e2(self.pool(a))
            c = self.mid(self.pool(b))
            b = self.d2(torch.cat([self.u2(c), b], 1))
            a = self.d1(torch.cat([self.u1(b), a], 1))
            return self.out(a)

    return UNet()
