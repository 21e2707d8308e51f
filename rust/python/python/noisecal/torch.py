"""Noise synthesis on any torch device from a pack's sampler tables (LED/PMRID-style pipelines).

``NoiseSynth(pack, iso)`` holds the tables of :meth:`noisecal.Pack.tables` as tensors; calling it
on a batch of clean raw tensors (DN, black included) draws the same distribution as the core: a
uniform 32-bit draw ``u`` picks ``first + i`` for the first ``i`` with ``cdf[i] > u``, found by one
``searchsorted`` over all tables laid end to end. The core's RNG streams are not reproduced (use
``Pack.synth`` for byte-identical output), nor its snapping onto a code lattice for sensors that
skip codes (``tables["lattice"]`` says where that applies); the output is clamped to the codes the
sensor writes. ``clean_at="target"`` takes clean images at the target ISO's brightness, as
``Pack.synth(..., clean_at="target")``: the tables' ``lut`` then picks each level's reference bin
and their ``shift`` (the gain shift taken out) is added, dithered onto the integers.

Components: ``NoiseSynth`` draws the pixel component alone (``Pack.synth(..., components="pixel")``).
It does not drop the others silently: when the pack has row, column, frame or fixed-pattern noise
at the ISO (``tables["structure"]``), the default ``components=None`` (every component, as
``Pack.synth``) is refused with a ``ValueError`` naming them; pass ``components="pixel"`` to accept
the pixel-independent model, or use ``Pack.synth`` for all of them.

Torch is optional: importing this module without it raises ImportError with the fix.
"""

from __future__ import annotations

try:
    import torch
except ImportError as e:  # pragma: no cover - exercised only without torch
    raise ImportError("noisecal.torch needs torch: pip install torch (or noisecal[torch])") from e

from . import Pack

_ONE = 1 << 32
_ROW = 1 << 33  # each table row's CDF lives in [0, 2^32]; rows are offset by 2^33 so all are sorted
_U16 = (1 << 16) - 1


def _check_components(components: str | None, tables: dict, iso: int) -> None:
    """Refuses components NoiseSynth does not draw (it draws the pixel component alone)."""
    if components is None:
        structure = list(tables.get("structure", []))
        if structure:
            raise ValueError(
                f"NoiseSynth draws the pixel component alone, but the pack adds {', '.join(structure)} noise at "
                f"ISO {iso} by default (Pack.synth): pass components=\"pixel\" to draw the pixel-independent model "
                "on the device, or use Pack.synth for every component"
            )
        return
    names = [c.strip().lower() for c in str(components).split(",") if c.strip()]
    others = [c for c in names if c != "pixel"]
    if others or not names:
        raise ValueError(
            f"components={components!r}: NoiseSynth draws the pixel component alone; pass components=\"pixel\", "
            "or use Pack.synth(..., components=...) for row, column, frame or fpn noise"
        )


class NoiseSynth(torch.nn.Module):
    """Adds a pack's noise at one ISO to clean raw tensors on the tensors' device.

    Move it with ``.to(device)`` like any module; the generator passed to ``forward`` must live on
    the same device. ``components``: ``None`` (default) asks for every component the pack has at
    ``iso`` and is refused when that is more than ``"pixel"``, the only one drawn here; ``"pixel"``
    draws the pixel-independent model."""

    def __init__(
        self,
        pack: Pack,
        iso: int,
        *,
        model: str = "noisecal",
        extrapolate: bool = False,
        clean_at: str = "reference",
        components: str | None = None,
    ):
        super().__init__()
        tables = pack.tables(iso, model=model, extrapolate=extrapolate, clean_at=clean_at)
        _check_components(components, tables, iso)
        self._load(tables)

    @classmethod
    def from_tables(cls, tables: dict) -> NoiseSynth:
        """A sampler over tables in the layout of :meth:`noisecal.Pack.tables` (e.g. saved ones)."""
        self = cls.__new__(cls)
        torch.nn.Module.__init__(self)
        # Tables are the pixel-independent model whatever the pack holds besides: taking them as
        # they are is asking for the pixel component.
        self._load(tables)
        return self

    def _load(self, t: dict) -> None:
        cdf = torch.as_tensor(t["cdf"]).to(torch.int64)  # (4, B, K), units of 2^-32, padded with 2^32
        positions, bins, k = cdf.shape
        rows = torch.arange(positions * bins, dtype=torch.int64).reshape(positions, bins, 1)
        self.register_buffer("flat", (cdf + rows * _ROW).reshape(-1))
        self.register_buffer("lut", torch.as_tensor(t["lut"]).to(torch.int64))
        self.register_buffer("first", torch.as_tensor(t["first"]).to(torch.int64).reshape(-1))
        rng = torch.as_tensor(t["range"]).to(torch.int64)
        self.register_buffer("lo", rng[:, 0].clone())
        self.register_buffer("hi", rng[:, 1].clone())
        self.bins, self.k, self.white = bins, k, int(t["white"])
        self.iso = int(t["iso"]) if "iso" in t else None
        # Tables saved before the clean_at option have no shift: the reference brightness.
        self.clean_at = str(t["clean_at"]) if "clean_at" in t else "reference"
        shift = t["shift"] if "shift" in t else None
        self.has_shift = self.clean_at == "target" and shift is not None
        if self.has_shift:
            self.register_buffer("shift", torch.as_tensor(shift).to(torch.float64))
        else:
            self.shift = None

    def uniform(self, shape: tuple[int, ...], generator: torch.Generator | None, device: torch.device) -> torch.Tensor:
        """Uniform 32-bit draws in ``[0, 2^32)`` (int64), the unit of the tables' CDFs."""
        return torch.randint(0, _ONE, shape, generator=generator, device=device, dtype=torch.int64)

    def forward(self, clean: torch.Tensor, cfa_origin=None, generator: torch.Generator | None = None) -> torch.Tensor:
        """``clean``: (H, W) or (N, H, W) levels in DN (integer, or float rounded to the nearest
        level and clamped to ``[0, white]`` as the core's float input is). ``cfa_origin``: (row,
        column) of each image's pixel (0, 0) on the sensor, one pair or an (N, 2) tensor (only the
        parity matters). Returns int32 DN."""
        single = clean.dim() == 2
        x = clean.unsqueeze(0) if single else clean
        if x.dim() != 3:
            raise ValueError(f"clean has {clean.dim()} dimensions: give one image (H, W) or a batch (N, H, W)")
        n, h, w = x.shape
        dev = x.device
        if cfa_origin is None:
            origin = torch.zeros((n, 2), dtype=torch.int64, device=dev)
        else:
            origin = torch.as_tensor(cfa_origin, dtype=torch.int64, device=dev).reshape(-1, 2).expand(n, 2)
        ys = torch.arange(h, device=dev).view(1, h, 1) + origin[:, 0].view(n, 1, 1)
        xs = torch.arange(w, device=dev).view(1, 1, w) + origin[:, 1].view(n, 1, 1)
        pos = (ys % 2) * 2 + (xs % 2)  # (n, h, w), the core's `position(row, column)`
        if x.is_floating_point():
            level = torch.round(x.double()).clamp(0, self.white).long()
        else:
            # The core takes uint16 levels; one above white keeps its level (clamped after the
            # noise is added) and draws from the top bin.
            level = x.long().clamp(0, _U16)
        row = pos * self.bins + self.lut[pos, level.clamp(max=self.white)]
        u = self.uniform((n, h, w), generator, dev)
        idx = torch.searchsorted(self.flat, u + row * _ROW, right=True)
        value = self.first[row] + (idx - row * self.k)
        if self.has_shift:
            # The gain shift taken out, dithered onto the integers: floor(shift + U[0, 1)).
            d = torch.rand((n, h, w), generator=generator, device=dev, dtype=torch.float64)
            value = value + torch.floor(self.shift[pos, level.clamp(max=self.white)] + d).long()
        out = torch.maximum(torch.minimum(level + value, self.hi[pos]), self.lo[pos]).to(torch.int32)
        return out[0] if single else out
