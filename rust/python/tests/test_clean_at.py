"""The brightness convention of the clean image (`clean_at`), on a sensor whose gain is not ∝ ISO
(`random:6` of the simulated family, γ 0.873): a clean ramp at the target ISO's brightness gets
noise without mean shift with `clean_at="target"`, and the gain shift by default."""

from __future__ import annotations

import numpy as np
import pytest

import noisecal

from conftest import have, run


@pytest.fixture(scope="module")
def gamma_pack(tmp_path_factory: pytest.TempPathFactory, cli) -> noisecal.Pack:
    d = tmp_path_factory.mktemp("gamma")
    run(cli, "simulate", "--sensor", "random:6", "--dngs", d / "cal")
    return noisecal.calibrate(d / "cal")


def _ramp(pack: noisecal.Pack, iso: int) -> tuple[np.ndarray, float, float]:
    lay = pack.layout
    black = lay["black"][0]
    g = min(pack.gain_ratios(iso))
    top = 0.6 * g * (lay["white"] - black)
    x = np.arange(512)
    row = np.round(black + x * top / len(x)).astype(np.uint16)
    return np.tile(row, (128, 1)), black, top


def _bands(clean, noisy, black, top, gains, bands=4):
    """Per band of level above black: (centre, mean of noisy − clean, SE, mean gain shift)."""
    out = []
    lvl = clean.astype(np.float64) - black
    d = noisy.astype(np.float64) - clean
    g = np.empty(clean.shape[-2:])
    g[0::2, 0::2], g[0::2, 1::2], g[1::2, 0::2], g[1::2, 1::2] = gains
    b = np.minimum((lvl / top * bands).astype(int), bands - 1)
    for k in range(bands):
        m = np.broadcast_to(b == k, d.shape)
        dk = d[m]
        shift = np.broadcast_to((g - 1) * lvl, d.shape)[m].mean()
        out.append(((k + 0.5) * top / bands, dk.mean(), dk.std() / np.sqrt(dk.size), shift))
    return out


def test_gain_ratios_and_clean_at_target_has_no_mean_shift(gamma_pack):
    pack = gamma_pack
    iso = max(pack.calibrated_isos)
    gains = pack.gain_ratios(iso)
    assert len(gains) == 4 and all(0.5 < g < 0.95 for g in gains), gains
    assert max(gains) < min(pack.gain_ratios(min(pack.calibrated_isos)))  # γ < 1: darker with ISO
    clean, black, top = _ramp(pack, iso)
    batch = np.stack([clean] * 4)
    target = pack.synth(batch, iso, 11, components="pixel", clean_at="target")
    reference = pack.synth(batch, iso, 11, components="pixel")
    assert np.array_equal(reference, pack.synth(batch, iso, 11, components="pixel", clean_at="reference"))
    for (c, m, se, shift), (_, mr, ser, _) in zip(
        _bands(clean, target, black, top, gains), _bands(clean, reference, black, top, gains)
    ):
        assert abs(m) <= 3 * se + 0.25 + 0.002 * c, f"level {c:.0f}: clean_at=target mean shift {m:+.3f} DN"
        assert abs(mr - shift) <= 3 * ser + 0.5 + 0.01 * c, f"level {c:.0f}: default {mr:+.2f} vs gain shift {shift:+.2f}"
    # The brightest band: tens of DN darker by default, not with the option.
    assert shift < -10 and abs(m) < 0.1 * abs(shift)
    # A crop keeps its CFA phase, and the whole run the same bytes with all components too.
    crop = clean[1:65, 3:131]
    a = pack.synth(crop, iso, 2, cfa_origin=(1, 3), clean_at="target")
    assert np.array_equal(a, pack.synth(crop, iso, 2, cfa_origin=(1, 3), clean_at="target"))


def test_synth_float_and_tables_follow_clean_at(gamma_pack):
    pack = gamma_pack
    iso = max(pack.calibrated_isos)
    clean, black, top = _ramp(pack, iso)
    white = pack.layout["white"]
    x = ((clean.astype(np.float32) - black) / (white - black)).astype(np.float32)
    f = pack.synth_float(x, iso, 4, clean_at="target")
    u = pack.synth(clean, iso, 4, clean_at="target")
    assert np.allclose(f * (white - black) + black, u, atol=1e-3)
    t = pack.tables(iso, clean_at="target")
    assert t["clean_at"] == "target" and t["gain_ratio"] == pytest.approx(pack.gain_ratios(iso))
    r = pack.tables(iso)
    assert r["clean_at"] == "reference" and not r["shift"].any()
    # At the target brightness a level draws from its reference level's bin, gain shift taken out.
    lv = int(black + 400)
    g = t["gain_ratio"][0]
    ref_level = int(round(black + 400 / g))
    assert t["lut"][0, lv] == r["lut"][0, ref_level]
    assert t["shift"][0, lv] == pytest.approx(-(g - 1) * 400 / g, abs=1e-6)
    with pytest.raises(noisecal.NoisecalError, match="clean_at"):
        pack.synth(clean, iso, clean_at="brighter")


@pytest.mark.skipif(not have("torch"), reason="torch is not installed")
def test_torch_noise_synth_takes_clean_at(gamma_pack):
    import torch

    from noisecal.torch import NoiseSynth

    pack = gamma_pack
    iso = max(pack.calibrated_isos)
    clean, black, top = _ramp(pack, iso)
    gains = pack.gain_ratios(iso)
    synth = NoiseSynth(pack, iso, clean_at="target", components="pixel")
    gen = torch.Generator().manual_seed(3)
    out = synth(torch.as_tensor(np.stack([clean.astype(np.int32)] * 4)), generator=gen).numpy()
    for c, m, se, _ in _bands(clean, out, black, top, gains):
        assert abs(m) <= 3 * se + 0.25 + 0.002 * c, f"level {c:.0f}: torch clean_at=target mean shift {m:+.3f} DN"
