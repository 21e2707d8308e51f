"""The float clean training images (noisecal.bench.data.load_float_clean): the rows trained on real
captures (the oracle) are taught the clean image the captures were drawn about, not its rounding
to whole DN. Needs numpy alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import noisecal
from noisecal import bench as B

# An 8-bit sensor with sub-DN noise near black, as tests/bench/sim_tiles.py's (set 002's law).
WHITE, BLACK, A, VAR0 = 255, 2.87, 0.019, 0.01
LAYOUT = {"black": [BLACK] * 4, "white": WHITE}


def _noisy(clean: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    var = A * np.maximum(clean - BLACK, 0.0) + VAR0
    return np.clip(np.rint(clean + rng.standard_normal(clean.shape) * np.sqrt(var)), 0, WHITE).astype(np.uint16)


def _scene(rng: np.random.Generator, shape=(128, 128)) -> np.ndarray:
    """A float clean image in the dark band, 0–5 DN above black, with a sub-DN pixel pattern."""
    ramp = np.linspace(0.0, 5.0, shape[1])[None, :] * np.ones((shape[0], 1))
    return BLACK + ramp + 0.1 * rng.standard_normal(shape)


def _write(path: Path, px: np.ndarray) -> None:
    noisecal.write_raw_dng(path, px, cfa="RGGB", black=[BLACK] * 4, white=WHITE, iso=100, exposure_ns=1_000_000)


def _folder(tmp_path: Path, scenes: list[np.ndarray], npy: bool = True) -> Path:
    d = tmp_path / "train"
    d.mkdir()
    for j, s in enumerate(scenes):
        _write(d / f"s{j}.dng", np.rint(s).astype(np.uint16))
        if npy:
            np.save(d / f"s{j}.npy", s)
    return d


def _norm(x: np.ndarray) -> np.ndarray:
    return B.normalise(x, LAYOUT["black"], LAYOUT["white"]).astype(np.float64)


def test_the_oracles_pairs_carry_the_evaluations_noise(tmp_path):
    """Known truth: captures of float scenes 0–5 DN above black by the sensor. The oracle's
    training noise, capture − its target, must have the variance the evaluation pairs have
    (a held-out frame against the float clean image) within 5 % (about 10 standard errors at
    4 × 16 384 pixels), and be whole DN at under 1 % of pixels, as the evaluation's. The old
    target, the DNG's whole DN, gives 1.32× the evaluation's variance here and whole-DN noise at
    every pixel (the clean image's rounding put into the label); the synthetic rows keep the
    whole-DN image their noise is drawn about."""
    rng = np.random.default_rng(23)
    scenes = [_scene(rng) for _ in range(4)]
    d = _folder(tmp_path, scenes)
    names, cleans = B.load_clean(d, None)
    floats = B.load_float_clean(d, names, cleans)
    assert floats is not None and all(np.array_equal(f, s) for f, s in zip(floats, scenes))
    cleans_norm = [_norm(c) for c in cleans]
    floats_norm = [_norm(f) for f in floats]
    captures = [_norm(_noisy(s, rng)) for s in scenes]
    evaluation = np.concatenate([(_norm(_noisy(s, rng)) - _norm(s)).ravel() for s in scenes]).var()

    def pair_var(kind):
        targets = B.training_targets(kind, cleans_norm, floats_norm)
        return np.concatenate([(c - t).ravel() for c, t in zip(captures, targets)]).var()

    assert abs(pair_var("oracle") / evaluation - 1) < 0.05, pair_var("oracle") / evaluation
    # The pairs' noise in DN: about the float scene it is almost never whole DN, as the
    # evaluation's; against the DNG it is always whole DN.
    dn = np.concatenate([(c - t).ravel() for c, t in zip(captures, floats_norm)]) * (WHITE - BLACK)
    assert np.mean(np.abs(dn - np.rint(dn)) < 1e-3) < 0.01
    old = np.concatenate([(c - t).ravel() for c, t in zip(captures, cleans_norm)])
    assert abs(old.var() / evaluation - 1) > 0.15, old.var() / evaluation  # the test tells the two targets apart
    assert np.mean(np.abs(old * (WHITE - BLACK) - np.rint(old * (WHITE - BLACK))) < 1e-3) > 0.99
    for kind in ("noisecal", "hg", "wrong", "loud", "plain"):
        assert B.training_targets(kind, cleans_norm, floats_norm) is cleans_norm
    assert "renoise" in B.CAPTURED and B.training_targets("oracle", cleans_norm, None) is cleans_norm


def test_float_clean_images_are_all_or_none_and_must_match_their_dng(tmp_path):
    """No ``.npy``: ``None`` (every row trains on the DNGs, as before). Some but not all, a
    ``.npy`` of another size, or one more than 1 DN from its DNG (not its rounding): an error
    naming the file and the fix."""
    rng = np.random.default_rng(5)
    scenes = [_scene(rng, (32, 32)) for _ in range(2)]
    d = _folder(tmp_path, scenes, npy=False)
    names, cleans = B.load_clean(d, None)
    assert B.load_float_clean(d, names, cleans) is None
    np.save(d / "s0.npy", scenes[0])
    with pytest.raises(B.BenchError, match=r"s1\.npy.*every training DNG or of none"):
        B.load_float_clean(d, names, cleans)
    np.save(d / "s1.npy", scenes[1][:16])
    with pytest.raises(B.BenchError, match=r"s1\.npy is float64 \(16, 32\)"):
        B.load_float_clean(d, names, cleans)
    np.save(d / "s1.npy", scenes[1] + 3.0)
    with pytest.raises(B.BenchError, match=r"s1\.npy is 3\.\d\d DN from its DNG"):
        B.load_float_clean(d, names, cleans)
    np.save(d / "s1.npy", scenes[1])
    assert len(B.load_float_clean(d, names, cleans)) == 2
