"""``noisecal.rounded_gaussian_sd`` and ``noisecal.rounded_variance``: the core's rounded Gaussian
(the rule HG's tables are made with, ``derive/baselines/pmf.rs``), exposed for Python code that
draws HG-like noise (the benchmark's controls, ``noisecal.bench.scaled_hg``). Needs numpy alone."""

from __future__ import annotations

import math

import numpy as np
import pytest

import noisecal

# Known values, computed to 17 digits with mpmath (40 digits) by summing the cells of
# round(N(0, s²)) and solving for s: var(s) and s(var).
VARIANCE_AT_SD = {0.25: 0.045500269815884285, 0.5: 0.32541276258633084, 1.0: 1.083333322361118}
SD_FOR_VARIANCE = {0.05: 0.2551067147482711, 0.15: 0.34729517609519411, 0.5: 0.64586108656590661, 1.0: 0.95742713502913494}


def test_known_values():
    """Within 10⁻⁶ relative of the exact values (the core's erfc has a fractional error of
    1.2·10⁻⁷). A wrong implementation misses by far more: Sheppard's ``√(v − 1/12)`` gives 0 for
    0.05 DN² and 0.258 for 0.15 (0.74×); its nearest miss, 0.6455 for 0.5, is 0.99944× (560× the
    tolerance); ``√v`` gives 0.387 for 0.15 (1.11×)."""
    sd = np.array(list(VARIANCE_AT_SD))
    got = noisecal.rounded_variance(sd)
    assert got.dtype == np.float64 and got.shape == sd.shape
    np.testing.assert_allclose(got, list(VARIANCE_AT_SD.values()), rtol=1e-6)
    var = np.array(list(SD_FOR_VARIANCE))
    np.testing.assert_allclose(noisecal.rounded_gaussian_sd(var), list(SD_FOR_VARIANCE.values()), rtol=1e-6)
    # From 1.3 DN² up, Sheppard's correction, exactly.
    for v in (1.3, 2.0, 50.0):
        assert noisecal.rounded_gaussian_sd(v) == pytest.approx(math.sqrt(v - 1 / 12), rel=1e-15)
    assert noisecal.rounded_gaussian_sd(0.0) == 0.0


def test_shapes_lists_and_bad_values():
    """Any shape in, the same shape out; lists and integers are converted; a negative or
    non-finite value is an ``InputError`` naming the argument."""
    v = np.linspace(0.0, 3.0, 12).reshape(3, 4)
    s = noisecal.rounded_gaussian_sd(v)
    assert s.shape == (3, 4)
    np.testing.assert_allclose(noisecal.rounded_variance(s), v, rtol=1e-6, atol=1e-12)
    assert noisecal.rounded_gaussian_sd([1, 2]).shape == (2,)
    for bad in ([0.1, float("nan")], [-0.1], [float("inf")]):
        with pytest.raises(noisecal.InputError, match="var must be finite"):
            noisecal.rounded_gaussian_sd(bad)
    with pytest.raises(noisecal.InputError, match="sd must be finite"):
        noisecal.rounded_variance([-1.0])


def test_the_bench_controls_use_the_cores_rule():
    """``noisecal.bench.scaled_hg`` no longer carries its own copy: the functions are the core's."""
    from noisecal.bench import scaled_hg

    assert scaled_hg.rounded_gaussian_sd is noisecal.rounded_gaussian_sd
    assert scaled_hg.rounded_variance is noisecal.rounded_variance
