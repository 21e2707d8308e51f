"""`Pack.renoise` builds its renoiser (the bridge's per-bin deconvolution, the sampling tables) once
per (source ISO, target ISO, method, extrapolate) and keeps it in the Pack: the same bytes as a
fresh build, from any thread, and in a child forked after the parent filled the cache.

With `--benchmark-enable` the last test times a renoise of a small crop, the case the cache is for
(the denoiser benchmark re-noises many 256² training captures with one ISO pair):

    python -m pytest tests/test_renoise_cache.py --benchmark-enable --benchmark-columns=mean,median"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import noisecal
from workers import in_forked_child

TIMEOUT = 120
METHODS = ("bridge", "quantile", "denoised", "naive")


def capture(pack: noisecal.Pack, seed: int, size: int = 64) -> np.ndarray:
    """A real-looking ISO-100 capture: a ramp with the pack's own ISO-100 noise on it."""
    x = np.arange(size)
    clean = (80 + (x[None, :] * 7 + x[:, None] * 3) % 700).astype(np.uint16)
    return pack.synth(clean, 100, seed)


def fresh(pack: noisecal.Pack) -> noisecal.Pack:
    """The same models in a Pack with nothing cached."""
    return noisecal.Pack.from_bytes(pack.to_bytes())


def test_cached_renoisers_give_the_bytes_of_fresh_ones(pack):
    """Every method, interleaved on one Pack (a cache keyed on less than the method and ISO pair
    would hand one method another's renoiser), equals each call on a Pack of its own."""
    p = fresh(pack)
    noisy = capture(pack, 1)
    for rnd in range(2):
        for i, m in enumerate(METHODS):
            got = p.renoise(noisy, 100, 800, 10 + i, method=m)
            want = fresh(pack).renoise(noisy, 100, 800, 10 + i, method=m)
            np.testing.assert_array_equal(got, want, err_msg=f"{m}, round {rnd}")
    # The methods do differ on these inputs, so the comparison above can fail.
    outs = [p.renoise(noisy, 100, 800, 3, method=m) for m in METHODS]
    assert all(not np.array_equal(outs[0], o) for o in outs[1:])
    # A refused pair is refused again (not cached as anything).
    for _ in range(2):
        with pytest.raises(noisecal.InputError, match="to_iso must be above from_iso"):
            p.renoise(noisy, 800, 100, 0)


def test_renoise_from_threads_on_a_cold_cache_matches_serial(pack):
    noisy = [capture(pack, s) for s in range(4)]
    jobs = [(k, m) for k in range(4) for m in METHODS] * 2
    serial = {(k, m): fresh(pack).renoise(noisy[k], 100, 800, k, method=m) for k, m in set(jobs)}
    p = fresh(pack)
    with ThreadPoolExecutor(8) as ex:
        outs = list(ex.map(lambda j: p.renoise(noisy[j[0]], 100, 800, j[0], method=j[1]), jobs))
    for j, o in zip(jobs, outs):
        np.testing.assert_array_equal(o, serial[j], err_msg=str(j))


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform")
def test_a_child_forked_after_the_parent_renoised_renoises_the_same_bytes(pack):
    p = fresh(pack)
    noisy = capture(pack, 2)
    want = {m: p.renoise(noisy, 100, 800, 7, method=m) for m in ("bridge", "naive")}  # cached in the parent

    def child() -> bool:  # a cached renoiser and one it builds itself
        ok = np.array_equal(p.renoise(noisy, 100, 800, 7, method="bridge"), want["bridge"])
        q = p.renoise(noisy, 100, 800, 7, method="quantile")
        return ok and np.array_equal(q, fresh(pack).renoise(noisy, 100, 800, 7, method="quantile"))

    got = in_forked_child(child, TIMEOUT)
    assert got != "hung", f"the forked child did not renoise within {TIMEOUT} s (hung)"
    assert got == "ok"


def test_bench_renoise_small_crop(benchmark, pack):
    """One 64² capture re-noised by the bridge, the cache warm (before the cache, every call built
    the bridge)."""
    p = fresh(pack)
    noisy = capture(pack, 3)
    p.renoise(noisy, 100, 800, 0)
    out = benchmark(p.renoise, noisy, 100, 800, 0)
    assert out.shape == noisy.shape and out.dtype == np.uint16
