"""Throughput benchmarks (pytest-benchmark): in-memory synthesis of a 12 MP frame through the
package, against a vectorised numpy implementation of the same table sampling. With
`--benchmark-enable`:

    python -m pytest tests/test_bench.py --benchmark-enable --benchmark-columns=mean,median,ops

`rust/python/benches/throughput.py` runs these together with the Rust criterion bench of the same
entry point (`rust/core/benches/synth.rs`) on the same pack file (`NOISECAL_BENCH_PACK`), ISO
(`NOISECAL_BENCH_ISO`, default 800) and clean image, and prints the Mpix/s table and the ratios.
Without the variable the pack is the test session's.

In the default run (benchmarks disabled) each runs once, which checks they work."""

from __future__ import annotations

import os

import numpy as np
import pytest

import noisecal

H, W = 3000, 4000  # 12 MP, as rust/core/benches/synth.rs
ISO = int(os.environ.get("NOISECAL_BENCH_ISO", "800"))
SEED = 1


@pytest.fixture(scope="module")
def bench_pack(request) -> noisecal.Pack:
    path = os.environ.get("NOISECAL_BENCH_PACK")
    return noisecal.Pack.load(path) if path else request.getfixturevalue("pack")


@pytest.fixture(scope="module")
def clean() -> np.ndarray:
    """A horizontal ramp `64 + x·936 // (W − 1)`, every row alike (the Rust bench's image)."""
    x = np.arange(W, dtype=np.int64)
    return np.ascontiguousarray(np.broadcast_to((64 + x * 936 // (W - 1)).astype(np.uint16), (H, W)))


class NumpySynth:
    """The core's sampling rule in vectorised numpy: a uniform 32-bit draw `u` at (position, bin of
    the clean level) gives `first + i` for the first `i` with `cdf[i] > u`, found by one
    searchsorted over all tables laid end to end (each row's CDF offset by 2^33 so the whole array
    is sorted); the result is clamped to the codes the sensor writes. The tables are prepared once,
    as the package's sampler is."""

    def __init__(self, tables: dict):
        cdf = tables["cdf"].astype(np.int64)
        self.positions, self.bins, self.k = cdf.shape
        rows = np.arange(self.positions * self.bins, dtype=np.int64).reshape(self.positions, self.bins, 1)
        self.flat = (cdf + rows * (1 << 33)).ravel()
        self.lut = tables["lut"].astype(np.int64)
        self.first = tables["first"].astype(np.int64).ravel()
        self.lo = tables["range"][:, 0].astype(np.int64)
        self.hi = tables["range"][:, 1].astype(np.int64)
        self.white = int(tables["white"])

    def __call__(self, clean: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        h, w = clean.shape
        pos = (np.arange(h)[:, None] % 2) * 2 + (np.arange(w)[None, :] % 2)
        level = np.minimum(clean, self.white).astype(np.int64)
        row = pos * self.bins + self.lut[pos, level]
        u = rng.integers(0, 1 << 32, size=clean.shape, dtype=np.int64)
        idx = np.searchsorted(self.flat, u + row * (1 << 33), side="right")
        value = self.first[row] + idx - row * self.k
        return np.clip(level + value, self.lo[pos], self.hi[pos]).astype(np.uint16)


def test_bench_package_synth(benchmark, bench_pack, clean):
    bench_pack.synth(clean, ISO, SEED)  # the sampler is built once per pack (as in the Rust bench)
    benchmark.extra_info["mpix"] = H * W / 1e6
    out = benchmark(bench_pack.synth, clean, ISO, SEED)
    assert out.shape == clean.shape and out.dtype == np.uint16


def test_bench_package_synth_pixel(benchmark, bench_pack, clean):
    """The pixel-independent model alone (`components="pixel"`): the yardstick of what the default
    components (row, column, frame offsets, fixed pattern) cost on top."""
    bench_pack.synth(clean, ISO, SEED, components="pixel")
    benchmark.extra_info["mpix"] = H * W / 1e6
    out = benchmark(bench_pack.synth, clean, ISO, SEED, components="pixel")
    assert out.shape == clean.shape and out.dtype == np.uint16


def test_bench_numpy_synth(benchmark, bench_pack, clean):
    synth = NumpySynth(bench_pack.tables(ISO))
    rng = np.random.default_rng(0)
    benchmark.extra_info["mpix"] = H * W / 1e6
    out = benchmark(synth, clean, rng)
    core = bench_pack.synth(clean, ISO, SEED)
    # Same distribution, not the same stream: compare moments on a column band.
    a = out[:, :200].astype(np.float64) - clean[:, :200]
    b = core[:, :200].astype(np.float64) - clean[:, :200]
    assert abs(a.mean() - b.mean()) < 0.05 + 0.02 * b.std()
    assert abs(a.var() / b.var() - 1) < 0.05
