"""noisecal.bench, the denoiser benchmark: its data layout, metrics, models and (with torch) a small
run whose controls must come out in order (the oracle best within the seed spread, the wrong
model — HG with half the variance — clearly worst).

The small run is CI's check of the whole machinery (tests/run_all.sh runs this file in a venv
with torch); without torch those tests are skipped and the rest run."""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

import noisecal
from noisecal import bench as B

from conftest import _cli, have, run


# ---------------------------------------------------------------------------------------------
# Data layout


def test_pack_raw_puts_cfa_position_p_in_channel_p_and_unpacks_back():
    raw = np.arange(6 * 8, dtype=np.uint16).reshape(6, 8)
    p = B.pack_raw(raw)
    assert p.shape == (4, 3, 4)
    for row, col in [(0, 0), (1, 0), (0, 3), (5, 7), (4, 5)]:
        assert p[(row % 2) * 2 + col % 2, row // 2, col // 2] == raw[row, col]
    assert np.array_equal(B.unpack_raw(p), raw)
    with pytest.raises(B.BenchError, match="even height and width"):
        B.pack_raw(raw[:5])


def test_normalise_maps_each_positions_black_to_0_and_white_to_1():
    black = [60.0, 64.0, 66.0, 70.0]
    img = B.per_position(black, (4, 6))
    assert np.allclose(B.normalise(img, black, 1023), 0)
    assert np.allclose(B.normalise(np.full((4, 6), 1023.0), black, 1023), 1)
    mid = B.normalise(np.full((4, 6), 500.0), black, 1023)
    assert np.allclose(mid[2], (500 - 66) / (1023 - 66))


@pytest.mark.parametrize("cfa", ["RGGB", "GRBG", "GBRG", "BGGR"])
def test_mosaic_keeps_each_pixels_cfa_colour(cfa):
    rgb = np.stack([np.full((4, 4), v) for v in (1.0, 2.0, 3.0)], axis=-1)
    m = B.mosaic(rgb, cfa)
    want = {"R": 1.0, "G": 2.0, "B": 3.0}
    for p, c in enumerate(cfa):
        assert np.all(m[p // 2 :: 2, p % 2 :: 2] == want[c])
    with pytest.raises(B.BenchError, match="unknown CFA"):
        B.mosaic(rgb, "RGBW")


def test_generated_scenes_are_seeded_in_range_and_have_the_channel_gains():
    layout = {"cfa": "GRBG", "black": [64.0] * 4, "white": 1023}
    a = B.generate_clean(8, 64, 96, layout, seed=3)
    assert all(np.array_equal(x, y) for x, y in zip(a, B.generate_clean(8, 64, 96, layout, seed=3)))
    assert not np.array_equal(a[0], B.generate_clean(1, 64, 96, layout, seed=4)[0])
    s = np.stack(a).astype(np.float64)
    assert s.min() >= 64 and s.max() <= 1023 and a[0].dtype == np.uint16
    # GRBG: position 1 is red (gain 0.6), 2 blue (0.75), 0 and 3 green (1): over 8 scenes the
    # channel means above black keep that order, and the scenes span dark to bright.
    ch = B.pack_raw(s.mean(0) - 64).reshape(4, -1).mean(1)
    assert ch[1] < ch[2] < min(ch[0], ch[3])
    assert 0.4 < ch[1] / ch[0] < 0.8
    norm = (s - 64) / (1023 - 64)
    assert (norm < 0.02).mean() > 0.05 and (norm > 0.3).mean() > 0.005


def test_batch_plan_is_seeded_even_and_in_bounds():
    a = B.batch_plan(7, 50, 8, 5, 3, (64, 80), 32)
    assert np.array_equal(a, B.batch_plan(7, 50, 8, 5, 3, (64, 80), 32))
    assert not np.array_equal(a, B.batch_plan(8, 50, 8, 5, 3, (64, 80), 32))
    assert a.shape == (50, 8, 4)
    assert a[..., 0].max() == 4 and a[..., 1].max() == 2 and a[..., :2].min() == 0
    assert np.all(a[..., 2:] % 2 == 0)
    assert a[..., 2].max() <= 64 - 32 and a[..., 3].max() <= 80 - 32
    assert a[..., 3].max() == 48  # the last even offset is reachable
    with pytest.raises(B.BenchError, match="larger than the training images"):
        B.batch_plan(0, 1, 1, 1, 1, (16, 16), 32)


# ---------------------------------------------------------------------------------------------
# Metrics


def test_psnr_known_values():
    ref = np.zeros((4, 8, 8))
    assert B.psnr(ref + 0.1, ref) == pytest.approx(20.0)
    assert B.psnr(ref + 0.01, ref) == pytest.approx(40.0)
    assert B.psnr(ref + 0.5, ref, data_range=2.0) == pytest.approx(10 * math.log10(4 / 0.25))
    assert B.psnr(ref, ref) == math.inf


def _ssim_brute(x, y, data_range=1.0):
    """SSIM by its definition, window by window (the 11×11 Gaussian of σ 1.5), for a 2-D image."""
    k = np.exp(-0.5 * ((np.arange(11) - 5) / 1.5) ** 2)
    w = np.outer(k, k) / np.outer(k, k).sum()
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    out = np.empty((x.shape[0] - 10, x.shape[1] - 10))
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            a, b = x[i : i + 11, j : j + 11], y[i : i + 11, j : j + 11]
            ma, mb = (w * a).sum(), (w * b).sum()
            va, vb = (w * a * a).sum() - ma**2, (w * b * b).sum() - mb**2
            cov = (w * a * b).sum() - ma * mb
            out[i, j] = (2 * ma * mb + c1) * (2 * cov + c2) / ((ma**2 + mb**2 + c1) * (va + vb + c2))
    return out


def test_ssim_known_values_and_the_definition():
    rng = np.random.default_rng(1)
    x = rng.random((2, 24, 30))
    assert B.ssim(x, x) == pytest.approx(1.0)
    # Constant images a and b: no variance, SSIM = (2ab + C1) / (a² + b² + C1).
    a, b = 0.3, 0.5
    c1 = 0.01**2
    assert B.ssim(np.full((1, 16, 16), a), np.full((1, 16, 16), b)) == pytest.approx((2 * a * b + c1) / (a * a + b * b + c1))
    y = np.clip(x + rng.normal(0, 0.1, x.shape), 0, 1)
    m = B.ssim_map(y, x)
    assert m.shape == (2, 14, 20)
    for c in range(2):
        assert np.allclose(m[c], _ssim_brute(y[c], x[c]), atol=1e-10)
    assert 0.3 < B.ssim(y, x) < 0.95


def test_score_bands_pool_the_error_by_clean_level():
    clean = np.zeros((4, 20, 20))
    clean[:, :, :10] = 0.01  # dark
    clean[:, :, 10:] = 0.5  # bright
    pred = clean.copy()
    pred[:, :, :10] += 0.01  # dark error 0.01 → 40 dB
    pred[:, :, 10:] += 0.1  # bright error 0.1 → 20 dB
    s = B.score([pred], [clean])
    assert set(s["bands"]) == {"dark", "bright"}
    assert s["bands"]["dark"]["psnr"] == pytest.approx(40.0)
    assert s["bands"]["bright"]["psnr"] == pytest.approx(20.0)
    assert s["bands"]["dark"]["fraction"] == pytest.approx(0.5)
    assert s["psnr"] == pytest.approx(10 * math.log10(1 / ((0.01**2 + 0.1**2) / 2)))


def test_score_regions_split_flat_interiors_from_edge_bands():
    # Known truth: a step between columns 15 and 16 of each packed channel. Edge band: the
    # columns whose 5×5 window holds both sides (14 … 17: 4 of 32), flat the rest. Errors 0.01 in
    # the band and 0.001 elsewhere → edge 40 dB, flat 60 dB. A 3×3 window (2 columns), a window
    # over rows only (none) or errors pooled over both regions (~49 dB each) fail.
    clean = np.full((4, 32, 32), 0.2)
    clean[:, :, 16:] = 0.3
    m = B.region_masks(clean, 0.01)
    cols = np.flatnonzero(m["edge"][0].all(axis=0))
    assert cols.tolist() == [14, 15, 16, 17] and not m["edge"][:, :, :14].any() and (m["flat"] == ~m["edge"]).all()
    # Below the tolerance a variation is flat: a ramp of 0.001 a column, 0.004 over the window.
    ramp = 0.2 + 0.001 * np.arange(32)[None, None, :] * np.ones((4, 32, 1))
    assert B.region_masks(ramp, 0.005)["flat"].all() and not B.region_masks(ramp, 0.003)["flat"][:, :, 2:-2].any()
    pred = clean + np.where(m["edge"], 0.01, 0.001)
    s = B.score([pred], [clean], flat_tolerance=0.01)
    assert s["regions"]["edge"]["psnr"] == pytest.approx(40.0) and s["regions"]["flat"]["psnr"] == pytest.approx(60.0)
    assert s["regions"]["edge"]["fraction"] == pytest.approx(4 / 32)
    assert "regions" not in B.score([pred], [clean])  # only when asked: earlier JSON keeps its keys
    # Summary and table: the region rows, their gain over the input's regions, the shares.
    inp = B.score([clean + 0.01], [clean], 0.01)
    res = [{"model": "hg", "kind": "hg", "iso": 200, "seed": i, **s} for i in range(2)]
    rows = B.summary(res)
    assert rows[0]["regions"]["flat"]["mean"] == pytest.approx(60.0)
    text = B.region_table({"summary": rows, "input": {200: inp}})
    assert "+20.00" in text and "+0.00" in text and "flat 88 %, edge 12 %" in text
    assert B.region_table({"summary": [{k: v for k, v in rows[0].items() if k != "regions"}], "input": {}}) == ""


def test_summarise():
    s = B.summarise([1.0, 2.0, 4.0])
    assert s["mean"] == pytest.approx(7 / 3)
    assert s["std"] == pytest.approx(np.std([1, 2, 4], ddof=1))
    assert (s["min"], s["max"], s["n"]) == (1.0, 4.0, 3)
    assert B.summarise([5.0])["std"] == 0.0


def test_controls_need_a_clear_margin():
    def row(model, kind, *seeds):
        return {
            "model": model,
            "kind": kind,
            "iso": 800,
            "psnr": B.summarise(list(seeds)),
            "psnr_per_seed": {str(i): v for i, v in enumerate(seeds)},
        }

    good = B.controls([row("oracle", "oracle", 35.9, 36.1), row("hg", "hg", 36.0, 36.04), row("wrong", "wrong", 35.0, 35.1)])
    g = good[800]
    assert not g["oracle_best"] and g["oracle_within_spread"] and g["wrong_clear"] and g["wrong_worst"]
    # Worst on the mean, but one seed of HG below one of the wrong model's: not clear.
    mixed = B.controls([row("oracle", "oracle", 36.0, 36.0), row("hg", "hg", 35.0, 36.4), row("wrong", "wrong", 35.2, 35.3)])[800]
    assert mixed["wrong_worst"] and not mixed["wrong_clear"]
    # Every seed below HG, but by 0.05 dB (under MIN_GAP_DB): not clear either.
    close = B.controls([row("hg", "hg", 36.0, 36.0), row("wrong", "wrong", 35.95, 35.95)])[800]
    assert close["wrong_worst"] and not close["wrong_clear"]
    # An oracle 0.5 dB down is not best.
    down = B.controls([row("oracle", "oracle", 35.5, 35.5), row("hg", "hg", 36.0, 36.0), row("wrong", "wrong", 35.0, 35.0)])[800]
    assert down["wrong_clear"] and not down["oracle_within_spread"]
    # The loud control (2× HG's variance): clearly below HG (the paired test) when the evaluation
    # penalises over-smoothing; above it (a textureless set) it is flagged, and it is not a row
    # the wrong model must beat.
    ok = B.controls([row("hg", "hg", 36.0, 36.2), row("loud", "loud", 35.5, 35.75), row("wrong", "wrong", 35.0, 35.1)])[800]
    assert ok["loud_below_hg"] and ok["loud_margin_db"] == pytest.approx(0.475) and ok["wrong_clear"]
    flat = B.controls([row("hg", "hg", 36.0, 36.2), row("loud", "loud", 36.5, 36.1), row("wrong", "wrong", 35.0, 35.1)])[800]
    assert not flat["loud_below_hg"]
    low = B.controls([row("hg", "hg", 36.0, 36.2), row("loud", "loud", 34.0, 34.1), row("wrong", "wrong", 35.0, 35.1)])[800]
    assert low["wrong_clear"] and low["loud_below_hg"]


def test_gain_over_the_noisy_input_per_band():
    # Known rows: the gain is the row's PSNR minus the noisy input's, overall and per band, at the
    # row's ISO (the input keyed by int in a run, by str once read back from --json).
    rows = [
        {"model": "hg", "iso": 200, "psnr": {"mean": 55.5, "std": 0}, "bands": {"dark": {"mean": 62.0}, "shadow": {"mean": 53.0}}},
        {"model": "hg", "iso": 400, "psnr": {"mean": 50.0, "std": 0}, "bands": {"mid": {"mean": 44.0}}},
    ]
    inputs = {200: {"psnr": 55.25, "bands": {"dark": {"psnr": 60.5}, "shadow": {"psnr": 53.25}}}, 400: {"psnr": 49.0, "bands": {}}}
    for inp in (inputs, {str(k): v for k, v in inputs.items()}):
        g = {(r["model"], r["iso"]): r for r in B.gains({"summary": rows, "input": inp})}
        assert g[("hg", 200)]["psnr"] == pytest.approx(0.25)
        assert g[("hg", 200)]["bands"] == pytest.approx({"dark": 1.5, "shadow": -0.25})
        assert g[("hg", 400)]["psnr"] == pytest.approx(1.0) and g[("hg", 400)]["bands"] == {}
    text = B.gain_table({"summary": rows, "input": inputs})
    assert "+1.50" in text and "-0.25" in text


# ---------------------------------------------------------------------------------------------
# Models


def test_parse_model():
    m = B.parse_model("interp=noisecal:pixel@x.pack")
    assert (m.label, m.kind, m.components, m.pack_path) == ("interp", "noisecal", "pixel", "x.pack")
    assert B.parse_model("HG").kind == "hg" and B.parse_model("HG").label == "HG"
    assert B.parse_model("plain", plain_pack="p.pack").pack_path == "p.pack"
    with pytest.raises(B.BenchError, match="--plain-pack"):
        B.parse_model("plain")
    with pytest.raises(B.BenchError, match="unknown model 'gauss'"):
        B.parse_model("gauss")
    with pytest.raises(B.BenchError, match="components apply to pack models"):
        B.parse_model("wrong:pixel")


@pytest.fixture(scope="module")
def gain_switch_pack(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small phone12 session at ISOs 200, 800 and 3200: the sensor switches conversion gain at
    ISO 800, so ISO 400 lies in the switch (between 200 and 800) and ISO 1600 does not."""
    d = tmp_path_factory.mktemp("switch")
    run(_cli(), "simulate", "--preset", "phone12", "--dngs", d / "cal", "--isos", "200,800,3200", "--frames", "4",
        "--width", "96", "--height", "64", "--seed", "5")  # fmt: skip
    noisecal.calibrate(d / "cal").save(d / "switch.pack")
    return d / "switch.pack"


def test_interpolated_rows_are_noted_with_the_packs_gain_switch_warning(gain_switch_pack: Path):
    """Every pack row at an ISO its pack does not calibrate gets a note, and the one inside the
    conversion-gain switch carries the pack's warning (modelled from one side: a brightness error
    if it is the wrong one); parametric rows and calibrated ISOs get none. The notes reach the
    terminal table."""
    pack = noisecal.Pack.load(gain_switch_pack)
    other = str(gain_switch_pack)
    specs = [B.parse_model(m) for m in ("noisecal", "hg", "wrong", f"interp=noisecal@{other}")]
    notes = B.interpolation_notes(specs, [400, 800, 1600], pack, {other: pack})
    by = {}
    for n in notes:
        label, _, rest = n.partition(" at ISO ")
        by[(label, int(rest.split(":")[0]))] = n
    assert set(by) == {("noisecal", 400), ("noisecal", 1600), ("interp", 400), ("interp", 1600)}
    for label in ("noisecal", "interp"):
        assert "switches conversion gain" in by[(label, 400)] and "Calibrate ISO 400" in by[(label, 400)]
        assert "switches conversion gain" not in by[(label, 1600)]
    out = {
        "summary": [], "isos": [], "controls": {}, "networks": [], "seeds": [0], "wall_seconds": 60.0, "notes": notes,
        "config": {"steps": 1, "batch": 1, "crop": 16, "width": 4},
    }  # fmt: skip
    text = B.table(out)
    assert sum(line.startswith("note: ") for line in text.splitlines()) == 4
    assert "note: noisecal at ISO 400: interpolated by its pack; ISO 400 lies between ISO 200 and 800" in text


# ---------------------------------------------------------------------------------------------
# The evaluation set `noisecal simulate --bench` writes, and its loading


@pytest.fixture(scope="module")
def bench_set(tmp_path_factory: pytest.TempPathFactory, cli: Path) -> Path:
    d = tmp_path_factory.mktemp("bench") / "set"
    run(cli, "simulate", "--bench", d, "--scenes", "4", "--train-scenes", "8", "--train-frames", "2",
        "--width", "128", "--height", "128", "--isos", "1600", "--frames", "12", "--seed", "3")
    return d


def test_simulated_bench_set_layout(bench_set: Path, pack):
    scenes = B.load_eval(bench_set / "eval", pack)
    assert [s.name for s in scenes] == [f"scene{i:03}" for i in range(4)]
    assert {s.base_iso for s in scenes} == {50}
    assert all(list(s.frames) == [1600] and len(s.frames[1600]) == 1 for s in scenes)
    names, cleans = B.load_clean(bench_set / "train" / "clean", pack)
    assert names == [f"scene{i:03}" for i in range(8)]
    caps = B.load_captures(bench_set / "train" / "captures", names, pack)
    assert set(caps) == {(j, 1600) for j in range(8)} and all(len(v) == 2 for v in caps.values())
    # ISO × exposure kept: the ISO-1600 frame is the burst mean × the gain ratio (phone10: ≈ 1.02)
    # above black; and the scenes are not flat or charts: many levels, dark and bright.
    ratios = []
    for s in scenes:
        c = B.normalise(s.clean, [64] * 4, 1023)
        f = B.normalise(s.frames[1600][0], [64] * 4, 1023)
        ratios.append(f.mean() / c.mean())
        assert len(np.unique(np.rint(s.clean))) > 50  # even the −3 EV scene
    assert 0.98 < np.mean(ratios) < 1.06, ratios
    c0 = B.normalise(scenes[0].clean, [64] * 4, 1023)
    assert c0.max() > 0.6 and (c0 < 0.05).mean() > 0.1
    # The clean training image is the scene's noiseless mean: its captures scatter about it.
    cap = np.stack(caps[(0, 1600)]).astype(np.float64).mean(0)
    assert abs((cap - 64).mean() / (cleans[0].astype(np.float64) - 64).mean() - 1.02) < 0.04


def _band_variance_ratios(outs, refs, cleans, lay) -> dict:
    """Per band of the clean level (fraction of the range above black): the variance of
    ``outs − cleans`` over that of ``refs − cleans``, pooled over the images."""
    edges = [0.0, 0.02, 0.1, 0.4, 1.01]
    acc: dict = {}
    for o, r, c in zip(outs, refs, cleans):
        frac = B.pack_raw(c.astype(np.float64))
        b = np.asarray(lay["black"], np.float64).reshape(4, 1, 1)
        frac = (frac - b) / (lay["white"] - b)
        eo, er = (B.pack_raw(x.astype(np.float64) - c) for x in (o, r))
        for i in range(len(edges) - 1):
            m = (frac >= edges[i]) & (frac < edges[i + 1])
            a = acc.setdefault(i, [[], []])
            a[0].append(eo[m])
            a[1].append(er[m])
    out = {}
    for i, (eo, er) in acc.items():
        eo, er = np.concatenate(eo), np.concatenate(er)
        if eo.size >= 2000:
            out[i] = eo.var() / er.var()
    return out


def test_renoise_estimate_gives_the_target_isos_variance_on_textured_scenes(bench_set: Path, pack):
    """Noise on noise (ISO 100 → 800) on the textured training scenes: with the known clean image
    as its estimate, the bridge puts ISO 800's variance on every band of levels (against the pack's
    own ISO-800 synthesis of the same clean images); the built-in filter blurs across edges, so
    the darkest pixels, beside bright ones, get a brighter level's noise."""
    names, cleans = B.load_clean(bench_set / "train" / "clean", pack)
    cleans = cleans[:6]
    lay = pack.layout
    src = [pack.synth(c, 100, B.synth_seed(5, j, 0, 100)) for j, c in enumerate(cleans)]
    ref = [pack.synth(c, 800, B.synth_seed(5, j, 1, 800)) for j, c in enumerate(cleans)]
    est = B.estimates_for("clean", [[s] for s in src], cleans, None, lay, "cpu")
    assert all(np.array_equal(e[0], c.astype(np.float32)) for e, c in zip(est, cleans))
    assert B.estimates_for("filter", [[s] for s in src], cleans, None, lay, "cpu") is None
    seeds = [B.synth_seed(5, j, 0, 800) for j in range(len(cleans))]
    with_clean = [pack.renoise(s, 100, 800, k, estimate=e[0]) for s, e, k in zip(src, est, seeds)]
    with_filter = [pack.renoise(s, 100, 800, k) for s, k in zip(src, seeds)]
    r_clean = _band_variance_ratios(with_clean, ref, [c.astype(np.float64) for c in cleans], lay)
    r_filter = _band_variance_ratios(with_filter, ref, [c.astype(np.float64) for c in cleans], lay)
    print("bridge variance / ISO-800 synthesis by band, clean estimate:", r_clean, "filter:", r_filter)
    assert len(r_clean) >= 3, r_clean
    for band, r in r_clean.items():
        assert 0.9 < r < 1.1, (band, r_clean)
    # Measured: clean 0.99 / 1.02 / 1.00, filter 1.44 / 1.00 / 0.83 (phone10 dead leaves, 6 scenes).
    assert r_filter[0] > r_clean[0] + 0.2, (r_filter, r_clean)
    with pytest.raises(B.BenchError, match="--renoise-estimate \\['magic'\\]: use some of denoiser, filter, clean"):
        B.parse_estimates("denoiser,magic")
    assert B.parse_estimates("clean, filter,clean") == ["clean", "filter"]


def test_noiseprofile_model_runs_on_a_simulated_session_with_the_sensors_variance(bench_set: Path):
    """`simulate --noise-profile` sessions carry the sensor's true NoiseProfile, so the bench's
    `noiseprofile` model trains on them: its noise has the real captures' variance per band of
    levels (known truth: the simulated sensor's own frames of the same scenes)."""
    pack = noisecal.Pack.load(_ci_pack(bench_set))
    names, cleans = B.load_clean(bench_set / "train" / "clean", pack)
    caps = B.load_captures(bench_set / "train" / "captures", names, pack)
    pairs = B.make_pairs(B.parse_model("noiseprofile"), 1600, cleans, 2, pack, caps, 1, {})
    real = [caps[(j, 1600)][k] for j in range(len(cleans)) for k in range(2)]
    synth = [pairs.noisy[j][k] for j in range(len(cleans)) for k in range(2)]
    cl = [c.astype(np.float64) for c in cleans for _ in range(2)]
    # Each variance about its own band mean (the means: the test of the target brightness below).
    ratios = _band_variance_ratios(synth, real, cl, pack.layout)
    print("noiseprofile variance / real ISO-1600 variance by band:", ratios)
    assert len(ratios) >= 3, ratios
    for band, r in ratios.items():
        assert 0.85 < r < 1.15, (band, ratios)


def test_parametric_baselines_come_out_at_the_target_brightness_as_real_captures_do(bench_set: Path):
    """Known truth: the simulated sensor's own ISO-1600 captures of the training scenes, which are
    brighter than the (reference-ISO) clean images by the gain ratio. Every model's noisy images
    must carry that shift, the parametric baselines' too (they are zero-mean about the level they
    are handed, so they get the clean image at the target brightness): a baseline left at the
    reference brightness is off by the whole shift in the bright band, a network trained on it
    learns a brightness error besides the noise."""
    pack = noisecal.Pack.load(_ci_pack(bench_set))
    names, cleans = B.load_clean(bench_set / "train" / "clean", pack)
    caps = B.load_captures(bench_set / "train" / "captures", names, pack)
    lay = pack.layout
    black = B.per_position(lay["black"], cleans[0].shape)
    bright = [(c.astype(np.float64) - black) > 0.2 * (lay["white"] - black) for c in cleans]

    def bias(rows):
        d = [(rows[j][k].astype(np.float64) - cleans[j])[bright[j]] for j in range(len(cleans)) for k in range(2)]
        d = np.concatenate(d)
        return d.mean(), d.std() / math.sqrt(d.size)

    real, real_se = bias([caps[(j, 1600)] for j in range(len(cleans))])
    g = np.asarray(pack.gain_ratios(1600))
    pos = (np.arange(cleans[0].shape[0])[:, None] % 2) * 2 + np.arange(cleans[0].shape[1])[None, :] % 2
    shift = np.mean(np.concatenate([((g[pos] - 1) * (c - black))[m] for c, m in zip(cleans, bright)]))
    print(f"real ISO-1600 mean − clean in the bright band {real:.2f} ± {real_se:.2f} DN, gain shift {shift:.2f} DN")
    assert abs(real - shift) < 0.1 * abs(shift) + 4 * real_se  # the truth carries the pack's gain shift
    # And it is large against what the test resolves (measured: 5.5 DN, SE 0.56 on phone10), so a
    # baseline without it (mean − clean ≈ 0) fails the bound below by several standard errors.
    assert abs(shift) > 8 * real_se
    for model in ("noisecal", "hg", "pg", "noiseprofile", "wrong", "loud"):
        pairs = B.make_pairs(B.parse_model(model), 1600, cleans, 2, pack, caps, 1, {})
        m, se = bias(pairs.noisy)
        print(f"{model}: mean − clean {m:.2f} ± {se:.2f} DN")
        # Within a tenth of the shift (+ sampling): a baseline without the shift is off by all of it.
        assert abs(m - real) < 0.1 * abs(shift) + 4 * math.hypot(se, real_se), (model, m, real, shift)


def test_minutes_budget_counts_every_network_the_run_trains():
    """``--minutes``: the steps that fit all the networks, the noise-on-noise denoiser included
    (before, it was left out, so a run with it overran its budget by one network's time)."""
    spec = B.ModelSpec
    rows = [(spec("hg", "hg"), 1600), (spec("oracle", "oracle"), 1600)]
    bridge = [(spec("bridge 400→1600", "renoise", method="bridge", from_iso=400, estimate="denoiser"), 1600)]
    naive = [(spec("naive 400→1600", "renoise", method="naive", from_iso=400), 1600)]
    filt = [(spec("bridge[filter] 400→1600", "renoise", method="bridge", from_iso=400, estimate="filter"), 1600)]
    assert B.networks_trained(rows, 2) == 4
    assert B.networks_trained(rows + naive + filt, 2) == 8  # no denoiser to train
    assert B.networks_trained(rows + bridge + naive, 2) == 9  # 4 rows × 2 seeds + the denoiser
    # 10 min at 0.1 s a step: 85 % of 600 s over 9 networks = 566 steps; capped by --steps; ≥ 20.
    assert B.steps_for_minutes(10, 0.1, 9) == 566
    assert B.steps_for_minutes(10, 0.1, 8) == 637  # the denoiser left out: one network's time over
    assert B.steps_for_minutes(10, 0.1, 9, at_most=500) == 500
    assert B.steps_for_minutes(10, 0.1, 9, at_most=1000) == 566
    assert B.steps_for_minutes(0.01, 0.1, 9) == 20


def test_synth_seeds_follow_the_package_rule_and_never_repeat():
    # Every (training image, realization, ISO) of a large run gets its own seed, the package's
    # keyed rule (a linear mix such as j·4099 + k·131 + ISO repeats: (0, 1, 400) and (0, 0, 531)).
    isos = [50, 100, 200, 400, 531, 800, 1600, 3200, 6400]
    seeds = {B.synth_seed(7, j, k, iso) for j in range(300) for k in range(8) for iso in isos}
    assert len(seeds) == 300 * 8 * len(isos)
    assert B.synth_seed(7, 3, 1, 400) == noisecal.seed_for("train/3/1/400", 7)
    assert B.synth_seed(7, 3, 1, 400) != B.synth_seed(8, 3, 1, 400)
    assert all(0 <= s < 2**64 for s in seeds)


def test_eval_pairs_are_the_normalised_frames_and_clean_images(bench_set: Path, pack):
    scenes = B.load_eval(bench_set / "eval", pack)
    lay = pack.layout
    pairs = B.eval_pairs(scenes, 1600, lay)
    assert len(pairs) == sum(len(s.frames[1600]) for s in scenes)
    h, w = (scenes[0].clean.shape[0] // 8) * 8, (scenes[0].clean.shape[1] // 8) * 8
    noisy, clean = pairs[0]
    assert np.array_equal(noisy, B.normalise(scenes[0].frames[1600][0][:h, :w], lay["black"], lay["white"]))
    assert np.array_equal(clean, B.normalise(scenes[0].clean[:h, :w], lay["black"], lay["white"]))
    # The noisy input's score is the frames' own score against the clean images.
    want = B.score([n for n, _ in pairs], [c for _, c in pairs])
    assert B.score_input(pairs) == want and want["psnr"] < 60
    with pytest.raises(B.BenchError, match="no evaluation frames at ISO 800"):
        B.eval_pairs(scenes, 800, lay)


def test_bad_evaluation_sets_are_named(bench_set: Path, pack, tmp_path: Path):
    bad = tmp_path / "eval"
    shutil.copytree(bench_set / "eval", bad)
    for f in sorted((bad / "scene001").glob("ref_*.dng"))[1:]:
        f.unlink()
    with pytest.raises(B.BenchError, match="scene001 has 1 frame at its lowest ISO 50"):
        B.load_eval(bad, pack)
    with pytest.raises(B.BenchError, match="no scene sub-folders"):
        B.load_eval(bench_set / "train" / "clean", pack)
    with pytest.raises(B.BenchError, match="names no clean training image"):
        B.load_captures(bench_set / "train" / "captures", ["other"], pack)
    # Stems with "_" and stems that prefix others: the longest match wins.
    caps = tmp_path / "caps"
    caps.mkdir()
    src = sorted((bench_set / "train" / "captures").glob("scene000_*.dng"))[0]
    shutil.copy(src, caps / "a_b_iso1600_0.dng")
    shutil.copy(src, caps / "a_iso1600_0.dng")
    got = B.load_captures(caps, ["a", "a_b"], pack)
    assert sorted(got) == [(0, 1600), (1, 1600)]


def test_cli_errors_are_one_line_without_a_traceback(bench_set: Path, session: dict, capsys):
    rc = B.main(["--pack", str(session["cli_pack"]), "--set", str(bench_set), "--isos", "3200", "--steps", "1"])
    err = capsys.readouterr().err
    assert "--isos [3200]: the evaluation set has frames at ISOs [1600] only" in err
    assert rc == 2 and "Traceback" not in err
    rc = B.main(["--pack", str(session["cli_pack"]), "--set", str(bench_set), "--isos", "16OO"])
    assert rc == 2 and "--isos '16OO': give whole ISOs" in capsys.readouterr().err
    if not have("torch"):
        rc = B.main(["--pack", str(session["cli_pack"]), "--set", str(bench_set), "--models", "hg", "--steps", "1"])
        err = capsys.readouterr().err
        assert rc == 2 and "needs torch" not in err and "pip install torch" in err
    rc = B.main(["--pack", str(session["cli_pack"]), "--set", str(bench_set), "--models", "hg,plain"])
    assert rc == 2 and "--plain-pack" in capsys.readouterr().err
    rc = B.main(["--pack", str(session["cli_pack"]), "--set", str(bench_set), "--crop", "36"])
    assert rc == 2 and "--crop 36: use a multiple of 8" in capsys.readouterr().err
    for bad in ("0", "-2", "nan"):
        rc = B.main(["--pack", str(session["cli_pack"]), "--set", str(bench_set), "--input-scale", bad])
        assert rc == 2 and f"--input-scale {float(bad)}: give a positive number" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# With torch: determinism and the small run CI checks


@pytest.mark.torch
def test_input_scale_scales_what_the_layers_see_and_nothing_else():
    """``make_net(w, s)``: the same weights as ``make_net(w)`` under the same seed, and an output of
    ``x + correction(s·x)/s``, the unscaled network's correction taken at ``s·x`` and scaled back."""
    torch = pytest.importorskip("torch")
    torch.manual_seed(3)
    plain = B.make_net(8)
    torch.manual_seed(3)
    scaled = B.make_net(8, 8.0)
    sp, ss = plain.state_dict(), scaled.state_dict()
    assert all(torch.equal(sp[k], ss[k]) for k in sp)
    # Both start as the identity (a zero output layer) with zero biases, where the layers are
    # positively homogeneous and the scale cancels: as after training, give both the same
    # non-zero output layer and biases.
    gen = torch.Generator().manual_seed(2)
    with torch.no_grad():
        for name, t in sp.items():
            if name.endswith("bias") or name.startswith("out."):
                v = torch.randn(t.shape, generator=gen) * 0.1
                plain.state_dict()[name].copy_(v)
                scaled.state_dict()[name].copy_(v)
    x = torch.rand(2, 4, 16, 16, generator=torch.Generator().manual_seed(1)) * 0.05
    with torch.no_grad():
        want = x + (plain(8.0 * x) - 8.0 * x) / 8.0
        got = scaled(x)
        assert torch.allclose(got, want, atol=1e-6)
        assert not torch.allclose(got, plain(x), atol=1e-4)  # it does change what the layers see


@pytest.mark.torch
def test_highpass_layers_see_the_input_less_its_local_mean_in_noise_units():
    """``make_net(w, highpass_sigma=σ)``: ``x + σ·correction((x − m)/σ)``, ``m`` the 5×5 local mean.
    With a trained-looking (non-zero) output layer and zero biases, a flat input of any level comes
    back unchanged (the layers never see the level; a network fed ``x/σ`` instead moves it by
    σ·f(x/σ)), and a textured one equals the formula computed by hand."""
    torch = pytest.importorskip("torch")
    torch.manual_seed(3)
    net = B.make_net(8, highpass_sigma=0.004)
    torch.manual_seed(3)
    plain = B.make_net(8)
    gen = torch.Generator().manual_seed(2)
    with torch.no_grad():
        for m in (net, plain):
            m.out.weight.copy_(torch.randn(m.out.weight.shape, generator=torch.Generator().manual_seed(5)) * 0.1)
        for level in (0.0, 0.1, 0.37):
            flat = torch.full((1, 4, 16, 16), level)
            # Exact up to float rounding of the local mean (a network fed x/σ shifts a flat input).
            assert float((net(flat) - flat).abs().max()) < 1e-6
        x = 0.2 + 0.05 * torch.rand(2, 4, 16, 16, generator=gen)
        m = torch.nn.functional.avg_pool2d(x, 5, stride=1, padding=2, count_include_pad=False)
        want = x + 0.004 * (plain((x - m) / 0.004) - (x - m) / 0.004)
        assert torch.allclose(net(x), want, atol=1e-6)
        assert (net(x) - x).abs().max() > 1e-4  # the correction is not zero: the check above is not vacuous
    with pytest.raises(B.BenchError):
        B.make_net(8, 2.0, highpass_sigma=0.004)


@pytest.mark.torch
def test_the_network_starts_as_the_identity_with_layers_that_keep_their_signal():
    """He initialisation for LeakyReLU(0.2) and a zero output layer: an untrained network returns
    its input exactly, and a unit-variance input keeps a mean square of about 1 through the first
    block (torch's default initialisation shrank it about 6× per layer: 0.17 after one layer, 0.03
    after two, which left the networks of a short budget barely denoising)."""
    torch = pytest.importorskip("torch")
    torch.manual_seed(0)
    net = B.make_net(16)
    x = torch.rand(2, 4, 32, 32, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        assert torch.equal(net(x), x)
        z = torch.randn(8, 4, 32, 32, generator=torch.Generator().manual_seed(2))
        conv = net.e1[0]
        a = torch.nn.functional.leaky_relu(conv(z), 0.2)
        b = torch.nn.functional.leaky_relu(net.e1[2](a), 0.2)
        # He: var(w) = 2 / ((1 + 0.2²)·fan-in), so var(y) = 1.92·E[x²] and E[leaky(y)²] = 0.52·var(y) ≈ 1
        # after every layer (torch's default, var(w) = 1 / (3·fan-in): 0.17, then 0.03).
        for h in (a, b):
            ms = float((h**2).mean())
            assert 0.6 < ms < 1.6, ms


@pytest.mark.torch
def test_training_is_deterministic(bench_set: Path, pack):
    pytest.importorskip("torch")
    names, cleans = B.load_clean(bench_set / "train" / "clean", pack)
    lay = pack.layout
    cn = [B.normalise(c, lay["black"], lay["white"]) for c in cleans]
    pairs = B.make_pairs(B.parse_model("hg"), 800, cleans, 2, pack, {}, 1, {})
    again = B.make_pairs(B.parse_model("hg"), 800, cleans, 2, pack, {}, 1, {})
    assert all(np.array_equal(a, b) for ra, rb in zip(pairs.noisy, again.noisy) for a, b in zip(ra, rb))
    plan = B.batch_plan(0, 5, 4, len(cleans), 2, cleans[0].shape, 32)
    nets = [B.train_one(pairs, cn, lay, plan, 32, 8, 0, "cpu", 1e-3) for _ in range(2)]
    other = B.train_one(pairs, cn, lay, plan, 32, 8, 1, "cpu", 1e-3)
    sa, sb, so = (n.state_dict() for n in (*nets, other))
    assert all(np.array_equal(sa[k].numpy(), sb[k].numpy()) for k in sa)
    assert not all(np.array_equal(sa[k].numpy(), so[k].numpy()) for k in sa)


@pytest.mark.torch
def test_the_denoiser_estimate_maps_back_to_dn_at_any_even_size(pack):
    """The clean estimate of noise on noise: a network applied to a raw capture, in DN on the
    capture's grid. With a zero correction (the UNet's output layer zeroed) it gives the capture
    back exactly, also at sizes whose packed image the UNet's two scales must pad (not ÷ 4)."""
    torch = pytest.importorskip("torch")
    net = B.make_net(8)
    with torch.no_grad():
        net.out.weight.zero_()
        net.out.bias.zero_()
    net.eval()
    rng = np.random.default_rng(4)
    for shape in [(32, 48), (30, 22), (2, 6)]:
        raw = rng.integers(64, 1024, shape).astype(np.uint16)
        est = B.denoise(net, raw, pack.layout, "cpu")
        assert est.dtype == np.float32 and est.shape == shape
        np.testing.assert_allclose(est, raw.astype(np.float32), atol=1e-3)


@pytest.mark.torch
def test_small_run_controls_in_order(bench_set: Path, tmp_path: Path, capsys):
    """CI's small configuration: oracle, noisecal, HG, the wrong model and the loud one at ISO
    1600, 2 seeds of a few hundred steps on 32-pixel crops. Every network must beat the noisy input
    (the machinery trains), the wrong model must be clearly below HG and the loud model (HG at
    twice its variance) too (the paired test, bench/paired.py: too much noise must lose, the
    networks denoise enough that over-smoothing costs), and the oracle best within the seed
    spread; the resumed run must reproduce the table. Measured at 500 steps: wrong 0.54 dB below
    HG, paired t 9.89 against 6.31 (2 seeds); loud 0.74 dB, t 71.8."""
    pytest.importorskip("torch")
    t0 = time.time()
    steps = os.environ.get("NOISECAL_BENCH_CI_STEPS", "500")
    out = tmp_path / "r.json"
    args = ["--pack", str(_ci_pack(bench_set)), "--set", str(bench_set), "--models", "oracle,noisecal,hg,wrong,loud",
            "--steps", steps, "--seeds", "2", "--crop", "32", "--width", "16", "--batch", "16", "--lr", "0.003",
            "--state", str(tmp_path / "state"), "--json", str(out)]
    assert B.main(args) == 0, capsys.readouterr().err
    table = capsys.readouterr().out
    with capsys.disabled():
        print("\n" + table)
    r = json.loads(out.read_text())
    assert len(r["networks"]) == 10
    inp = r["input"]["1600"]["psnr"]
    for n in r["networks"]:
        assert n["psnr"] > inp + 0.5, (n["model"], n["seed"], n["psnr"], inp)
    c = r["controls"]["1600"]
    assert c["wrong_clear"], c
    assert c["loud_below_hg"], c
    assert c["oracle_within_spread"], c
    # Resumed: every network read back from --state, the same scores.
    assert B.main(args) == 0
    err = capsys.readouterr().err
    assert err.count("resumed from") == 10
    assert json.loads(out.read_text())["summary"] == r["summary"]
    with capsys.disabled():
        print(f"small run: {time.time() - t0:.0f} s")


def _ci_pack(bench_set: Path) -> Path:
    """A phone10 pack of the bench set's sensor (seed 3) at ISO 1600, calibrated once."""
    p = bench_set.parent / "cal.pack"
    if not p.exists():
        cal = bench_set.parent / "cal"
        run(_cli(), "simulate", "--dngs", cal, "--isos", "1600", "--frames", "8", "--width", "128", "--height", "96",
            "--seed", "3", "--noise-profile")
        noisecal.calibrate(cal).save(p)
        shutil.rmtree(cal)
    return p


# ---------------------------------------------------------------------------------------------
# Headroom: how much noise a filter removes (numpy)


def test_linear_headroom_is_the_box_mean_on_flat_fields():
    """Flat fields under white Gaussian noise: the best linear 5×5 residual filter is the box mean,
    10·log10(25) = 13.98 dB over the input (less a little at the replicated borders). A 3×3 window
    scores 9.54 dB, a filter fitted without the neighbours' differences (absolute levels) or on one
    channel's scale would miss the bound; the clean-guided filter on a flat field is the same box
    mean."""
    rng = np.random.default_rng(7)
    pairs = []
    for level in (0.1, 0.2, 0.3, 0.4):
        c = np.full((4, 96, 96), level, np.float32)
        pairs.append(((c + rng.normal(0, 0.01, c.shape)).astype(np.float32), c))
    lin = B.linear_gain(pairs)
    assert 13.4 < lin < 14.1, lin
    assert 9.0 < B.linear_gain(pairs, radius=1) < 9.7
    guided = B.guided_gain(pairs, 0.002)
    assert 13.4 < guided < 14.1, guided


def test_headroom_tells_edge_bound_noise_from_none():
    """Dense edges of high contrast under noise a 100th of it (EMVA set 002's regime, 8-bit, 0.3–1.4
    DN of noise against edges of tens of DN): no linear filter gains (< 0.1 dB: any smoothing loses
    more at the edges than it wins between them) where the clean-guided filter gains > 5 dB; a
    warning names it. The same scenes under noise as large as the edges' contrast: the linear
    filter gains > 1 dB and no warning. (A linear fit without a train/test split, or a guided
    filter that smooths across edges, scores above 0.1 dB in the first case.)"""
    rng = np.random.default_rng(3)
    pairs_low, pairs_high = [], []
    for i in range(4):
        grey = B.dead_leaves(128, 128, rng).mean(-1)
        grey = np.log(np.maximum(grey, 1e-3))
        c = B.pack_raw((0.4 * (grey - grey.min()) / (grey.max() - grey.min())).astype(np.float32))
        pairs_low.append(((c + rng.normal(0, 0.002, c.shape)).astype(np.float32), c))
        pairs_high.append(((c + rng.normal(0, 0.08, c.shape)).astype(np.float32), c))
    low = B.headroom(pairs_low, 0.5 / 252)
    assert low["linear_db"] < 0.1 and low["guided_db"] > 5, low
    high = B.headroom(pairs_high, 0.5 / 252)
    assert high["linear_db"] > 1.0, high
    warn = B.headroom_lines({"headroom": {200: low, 400: high}})
    assert len(warn) == 2 and "only an edge-aware filter" in warn[0] and "edge-aware" not in warn[1], warn
