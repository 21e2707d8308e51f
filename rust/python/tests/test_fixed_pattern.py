"""The fixed pattern (dark frames) through the Python package: a pack calibrated with a dark
step adds each sensor pixel's own dark offset, the same whatever the seed, and a crop given its
true origin gets the pattern of its true pixels (a crop told it sits at (0, 0) does not)."""

from __future__ import annotations

import numpy as np
import pytest

import noisecal

from conftest import run

ISO = 1600


@pytest.fixture(scope="module")
def dark_pack(tmp_path_factory: pytest.TempPathFactory, cli) -> noisecal.Pack:
    d = tmp_path_factory.mktemp("dark")
    run(cli, "simulate", "--dngs", d / "cal", "--width", "96", "--height", "64", "--frames", "6",
        "--isos", f"400,{ISO}", "--structured", "--dark", "8", "--seed", "5")
    return noisecal.calibrate(d / "cal")


def _pattern(pack: noisecal.Pack, clean: np.ndarray, origin: tuple[int, int], seeds: range, comps: str) -> np.ndarray:
    """Per-pixel mean of the synthetic noise over seeds (the part that repeats)."""
    acc = np.zeros(clean.shape)
    for s in seeds:
        acc += pack.synth(clean, ISO, s, cfa_origin=origin, components=comps).astype(np.float64) - clean
    return acc / len(seeds)


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def test_pattern_repeats_and_follows_the_crop(dark_pack: noisecal.Pack) -> None:
    black = int(round(dark_pack.layout["black"][0]))
    full = np.full((64, 96), black + 40, dtype=np.uint16)
    # The pattern repeats from seed to seed: two disjoint sets of seeds see the same pattern.
    a = _pattern(dark_pack, full, (0, 0), range(0, 48), "pixel,fpn")
    b = _pattern(dark_pack, full, (0, 0), range(48, 96), "pixel,fpn")
    assert _corr(a, b) > 0.25, _corr(a, b)
    # Without it nothing repeats.
    c = _pattern(dark_pack, full, (0, 0), range(0, 48), "pixel")
    d = _pattern(dark_pack, full, (0, 0), range(48, 96), "pixel")
    assert abs(_corr(c, d)) < 0.08, _corr(c, d)
    # A 32×48 crop at (10, 21) of the sensor: with its origin it gets those pixels' pattern.
    crop = full[10:42, 21:69].copy()
    e = _pattern(dark_pack, crop, (10, 21), range(96, 144), "pixel,fpn")
    assert _corr(e, a[10:42, 21:69]) > 0.25, _corr(e, a[10:42, 21:69])
    # Told it sits at (0, 0) (wrong pixels, and the wrong CFA phase), it does not.
    f = _pattern(dark_pack, crop, (0, 0), range(96, 144), "pixel,fpn")
    assert abs(_corr(f, a[10:42, 21:69])) < 0.08, _corr(f, a[10:42, 21:69])


def test_tables_name_the_components_they_leave_out(dark_pack: noisecal.Pack, pack: noisecal.Pack) -> None:
    # The dark step's pattern (and the simulated row/column offsets) are drawn by synth by default,
    # not by the pixel tables: the tables say so.
    structure = dark_pack.tables(ISO)["structure"]
    assert "fpn" in structure, structure
    assert set(structure) <= {"row", "column", "frame", "fpn"}
    assert dark_pack.tables(ISO, model="pg")["structure"] == []


def test_noise_synth_refuses_the_default_set_it_does_not_draw(dark_pack: noisecal.Pack) -> None:
    pytest.importorskip("torch", reason="torch is not installed (optional: pip install noisecal[torch])")
    from noisecal.torch import NoiseSynth

    structure = dark_pack.tables(ISO)["structure"]
    with pytest.raises(ValueError, match=r"NoiseSynth draws the pixel component alone, but the pack adds "
                                         + ", ".join(structure)):
        NoiseSynth(dark_pack, ISO)
    # Asked for the pixel component alone, it draws it.
    import torch

    out = NoiseSynth(dark_pack, ISO, components="pixel")(torch.full((8, 8), 200, dtype=torch.int32))
    assert out.shape == (8, 8)


def test_pattern_cache_setting_changes_no_byte(dark_pack: noisecal.Pack) -> None:
    # The fixed pattern a sampler keeps between calls (from a region's second request on) only
    # saves time: with none kept, a small limit or the default, repeated calls give the same bytes.
    import copy
    import pickle

    black = int(round(dark_pack.layout["black"][0]))
    clean = (black + 5 + np.arange(40 * 60).reshape(40, 60) % 300).astype(np.uint16)
    seeds = [1, 2, 1, 3]

    def runs(mb: int) -> list[np.ndarray]:
        p = copy.copy(dark_pack)
        p.set_pattern_cache_mb(mb)
        assert p.pattern_cache_mb == mb
        return [p.synth(clean, ISO, s, cfa_origin=(3, 1)) for s in seeds]

    none = runs(0)
    assert np.array_equal(none[0], none[2])
    assert not np.array_equal(none[0], dark_pack.synth(clean, ISO, 1, cfa_origin=(3, 1), components="pixel,row,column,frame"))
    for mb in (1, 192):
        assert all(np.array_equal(a, b) for a, b in zip(runs(mb), none)), mb
    # Copies and pickles (DataLoader workers) keep the setting.
    p = copy.copy(dark_pack)
    p.set_pattern_cache_mb(7)
    assert copy.copy(p).pattern_cache_mb == 7
    assert pickle.loads(pickle.dumps(p)).pattern_cache_mb == 7
    assert dark_pack.pattern_cache_mb == 192


def test_own_is_every_component_but_the_pattern(dark_pack: noisecal.Pack) -> None:
    # The rule for clean images from your own burst means (docs/method.md, *Fixed pattern*,
    # "Which components for which clean image"): components="own" is "pixel,row,column,frame",
    # byte for byte, and differs from the default, which adds the pattern the clean image carries.
    black = int(round(dark_pack.layout["black"][0]))
    clean = (black + 5 + np.arange(40 * 60).reshape(40, 60) % 300).astype(np.uint16)
    own = dark_pack.synth(clean, ISO, 4, components="own")
    assert np.array_equal(own, dark_pack.synth(clean, ISO, 4, components="pixel,row,column,frame"))
    assert np.array_equal(dark_pack.synth(clean, ISO, 4, components="own,fpn"), dark_pack.synth(clean, ISO, 4))
    assert not np.array_equal(own, dark_pack.synth(clean, ISO, 4))
    with pytest.raises(noisecal.NoisecalError, match="own"):
        dark_pack.synth(clean, ISO, 4, components="owned")
