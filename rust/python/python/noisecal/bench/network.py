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


def make_net(width: int, input_scale: float = 1.0, highpass_sigma: float | None = None):
    """A compact UNet on packed 4-channel raw (two scales, residual output). ``input_scale``: the
    layers see the input times this factor and their correction is divided by it, so a sensor whose
    noise is a small fraction of the range (dim frames, a deep bit depth) reaches the layers at a
    workable size; 1 leaves the network exactly as without it.

    Initialised for its activations (He et al. 2015: normal weights of variance 2 / ((1 + 0.2²) ·
    fan-in) for LeakyReLU(0.2), zero biases) and with a zero output layer, so it starts as the
    identity (no correction) and its ten layers keep their signal. torch's default (uniform, a
    third of that variance per layer) shrank the signal through the layers and started from a
    random correction: at the budgets the benchmark affords the networks then barely denoised
    (+0.1 dB over the noisy input at ISO 3200 on phone12, 300 steps; now +3.0 dB), so a model
    with too much noise, which pushes the network to smooth more, won (HG at twice its variance
    +0.25 dB above the sensor's own noise; now −0.93 dB): see docs/bench.md, "Why over-noise
    won".

    ``highpass_sigma`` σ (normalised units; None: off): the layers see the input's high-pass in
    units of σ, ``(x − m)/σ`` with ``m`` its 5×5 local mean (per channel, borders averaged over
    the pixels inside), and their correction is in units of σ: ``x + σ·correction((x − m)/σ)``.
    Where the noise is small against the signal and its edges (8-bit frames: 0.3–1.4 DN against
    edges of 3.5–100 DN), the layers otherwise see the levels, a hundred times the noise, and
    stay the identity (docs/bench.md, "Why nothing learnt on EMVA set 002"); it replaces
    ``input_scale``."""
    torch = _torch()
    if highpass_sigma is not None and (not highpass_sigma > 0 or input_scale != 1.0):
        raise BenchError(f"highpass_sigma {highpass_sigma}: give a positive noise scale, and no input_scale with it")
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
            self.local_mean = nn.AvgPool2d(5, stride=1, padding=2, count_include_pad=False)

        def forward(self, x):
            if highpass_sigma is not None:
                return x + highpass_sigma * self.correction((x - self.local_mean(x)) / highpass_sigma)
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

    net = UNet()
    for m in net.modules():
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
            nn.init.kaiming_normal_(m.weight, a=0.2, nonlinearity="leaky_relu")
            nn.init.zeros_(m.bias)
    nn.init.zeros_(net.out.weight)
    return net
