"""The pieces of the real-data benchmark (tests/bench/emva1288.py and emva1288_ladder.py, docs/bench.md "Real data"):
``noisecal.write_raw_dng`` (a DNG from arrays and settings alone), evaluation scenes that give
their clean image (``clean.npy``), grey and band-limited generated scenes, and the converter's PNG
reader, descriptor parser and derived clean images, each against a known truth."""

from __future__ import annotations

import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

import noisecal
from noisecal import bench as B

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tests" / "bench"))
import emva1288 as E  # noqa: E402  (a script under tests/bench, not a package)
import emva1288_ladder as L  # noqa: E402

BLACK = [14.75, 14.5, 15.25, 15.0]


def _write(path: Path, px: np.ndarray, iso: int, exposure_ns: int = 5_160_000, **kw) -> None:
    noisecal.write_raw_dng(path, px, cfa="RGGB", black=BLACK, white=4095, iso=iso, exposure_ns=exposure_ns, **kw)


def test_write_raw_dng_round_trips_pixels_and_settings(tmp_path: Path):
    rng = np.random.default_rng(1)
    px = rng.integers(0, 4096, (48, 64)).astype(np.uint16)
    _write(tmp_path / "a.dng", px, 200, 10_320_000, make="Basler", model="test")
    got, meta = noisecal.read_dng(tmp_path / "a.dng")
    assert np.array_equal(got, px)
    assert (meta["iso"], meta["exposure_ns"], meta["cfa"], meta["white"]) == (200, 10_320_000, "RGGB", 4095)
    assert np.allclose(meta["black"], BLACK) and (meta["make"], meta["model"]) == ("Basler", "test")
    noisecal.write_raw_dng(tmp_path / "b.dng", px, cfa="GBRG", black=[64.0], white=4095, iso=100, exposure_ns=1000)
    assert noisecal.read_dng(tmp_path / "b.dng")[1]["black"] == [64.0] * 4


@pytest.mark.parametrize(
    "kw, msg",
    [
        ({"cfa": "RGBW"}, 'cfa "RGBW": use RGGB'),
        ({"black": [1.0, 2.0]}, "black has 2 values: give one, or four"),
        ({"iso": 0}, "iso and exposure_ns must be above 0"),
        ({"black": [5000.0]}, "the DNG's layout"),
    ],
)
def test_write_raw_dng_refuses_bad_settings_by_name(tmp_path: Path, kw: dict, msg: str):
    args = {"cfa": "RGGB", "black": BLACK, "white": 4095, "iso": 100, "exposure_ns": 1000, **kw}
    with pytest.raises(noisecal.InputError, match=msg):
        noisecal.write_raw_dng(tmp_path / "x.dng", np.zeros((8, 8), np.uint16), **args)
    assert not (tmp_path / "x.dng").exists()


def test_scenes_may_give_their_clean_image(tmp_path: Path):
    rng = np.random.default_rng(2)
    clean = 100 + 50 * rng.random((32, 48))
    for name in ("a", "b"):
        (tmp_path / "eval" / name).mkdir(parents=True)
    np.save(tmp_path / "eval" / "a" / "clean.npy", clean)
    for i in range(2):
        _write(tmp_path / "eval" / "a" / f"f{i}.dng", np.rint(clean + rng.normal(0, 3, clean.shape)).astype(np.uint16), 200)
    for i in range(3):  # a burst scene beside it
        _write(tmp_path / "eval" / "b" / f"r{i}.dng", np.full((32, 48), 120 + i, np.uint16), 100)
    _write(tmp_path / "eval" / "b" / "t.dng", np.full((32, 48), 121, np.uint16), 200)
    a, b = B.load_eval(tmp_path / "eval", None)
    assert a.base_iso is None and np.array_equal(a.clean, clean) and len(a.frames[200]) == 2
    assert b.base_iso == 100 and np.allclose(b.clean, 121) and len(b.frames[200]) == 1
    np.save(tmp_path / "eval" / "a" / "clean.npy", clean[:8])
    with pytest.raises(B.BenchError, match=r"clean.npy is float64 \(8, 48\); the frames are \(32, 48\)"):
        B.load_eval(tmp_path / "eval", None)
    (tmp_path / "eval" / "a" / "clean.npy").write_bytes(b"not numpy")
    with pytest.raises(B.BenchError, match="is not a numpy array file"):
        B.load_eval(tmp_path / "eval", None)


def test_generated_grey_and_band_limited_scenes():
    layout = {"cfa": "RGGB", "black": BLACK, "white": 4095}
    def plane_means(imgs):
        return np.mean([B.pack_raw(g.astype(np.float64) - B.per_position(BLACK, g.shape)).mean((1, 2)) for g in imgs], 0)

    # Every CFA position sees the same grey scene (gain 1); in colour R and B are 0.6 and 0.75 of G.
    grey = plane_means(B.generate_clean(8, 64, 64, layout, seed=3, mono=True))
    assert np.allclose(grey / grey.mean(), 1, atol=0.04), grey
    colour = plane_means(B.generate_clean(8, 64, 64, layout, seed=3))
    assert 0.45 < colour[0] / colour[1] < 0.75 and 0.6 < colour[3] / colour[1] < 0.9, colour
    band = B.generate_clean(4, 64, 64, layout, seed=3, mono=True, levels=(1944.0, 1995.0))
    for g in band:
        above = g.astype(np.float64) - B.per_position(BLACK, g.shape)
        assert above.min() >= 1943.5 and above.max() <= 1995.5 and above.max() - above.min() > 45
    assert B.parse_levels(None, layout) is None and B.parse_levels("10,20", layout) == (10.0, 20.0)
    for bad in ("20,10", "x", "0,5000"):
        with pytest.raises(B.BenchError, match="--generate-levels"):
            B.parse_levels(bad, layout)


def _png16(img: np.ndarray, filters: int = 0) -> bytes:
    raw = b"".join(bytes([filters]) + row.astype(">u2").tobytes() for row in img)

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    head = struct.pack(">IIBBBBB", img.shape[1], img.shape[0], 16, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", head) + chunk(b"tEXt", b"k\0v") + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def test_png_reader_and_descriptor():
    img = np.random.default_rng(4).integers(0, 4096, (6, 10)).astype(np.uint16)
    assert np.array_equal(E.read_png16(_png16(img), "x.png"), img)
    with pytest.raises(E.ConvertError, match=r"x.png: PNG row filters \[1\]; only filter 0"):
        E.read_png16(_png16(img, filters=1), "x.png")
    with pytest.raises(E.ConvertError, match="not a PNG"):
        E.read_png16(b"GIF89a", "x.png")
    blocks = E.read_descriptor("# c\nv 3.0\nn 12 640 480\nb 40000.0 120.0\ni images\\b_000_snap_001.png\ni images\\b_000_snap_002.png\nd 40000.0\ni images\\d_000_snap_001.png\n")
    assert [(b.kind, b.exposure_ns, b.images) for b in blocks] == [
        ("b", 40000, ["images/b_000_snap_001.png", "images/b_000_snap_002.png"]),
        ("d", 40000, ["images/d_000_snap_001.png"]),
    ]


def test_pair_clean_recovers_a_scaled_flat_field():
    # Known truth: a shaded flat field with fixed pattern, the burst at signal S, a pair at 0.37·S
    # on a black level 0.8 DN higher; the pair's clean image is recovered from noisy frames.
    rng = np.random.default_rng(5)
    h, w = 120, 160
    dark = 15 + rng.normal(0, 0.5, (h, w))
    flat = 2000 * (1 + 0.02 * rng.normal(size=(h, w))) * np.linspace(0.95, 1.05, w)[None]
    burst_clean = dark + flat + rng.normal(0, 24 / 5, (h, w))  # a 25-frame mean's noise
    truth = dark + 0.8 + 0.37 * flat
    pair = [truth + rng.normal(0, 15, (h, w)) for _ in range(2)]
    dpair = [dark + 0.8 + rng.normal(0, 3, (h, w)) for _ in range(2)]
    got = E.pair_clean(burst_clean, dark, pair, dpair)
    err = got - truth
    assert abs(err.mean()) < 0.1  # the scale and the black shift
    assert err.std() < 0.37 * 24 / 5 * 1.1  # no more than the burst mean's own noise, scaled
    assert np.corrcoef(got.ravel(), truth.ravel())[0, 1] > 0.99


def test_dithered_burst_has_the_clean_image_as_its_mean():
    # A derived clean image handed to the calibrator as a reference burst: noiseless integer
    # frames whose mean is the float clean image within 1/(2n) DN (plain rounding errs by up to ½).
    rng = np.random.default_rng(11)
    clean = 14.76 + rng.uniform(0, 400, (60, 80))
    for n in (4, 8):
        frames = E.dithered_burst(clean, n)
        assert len(frames) == n and all(f.dtype == np.uint16 for f in frames)
        err = np.mean(np.stack(frames).astype(np.float64), axis=0) - clean
        assert np.abs(err).max() <= 0.5 / n + 1e-9
        assert abs(err.mean()) < 0.01
        spread = np.ptp(np.stack(frames).astype(np.int64), axis=0)
        assert spread.max() <= 1  # no noise: neighbouring codes only
    assert np.abs(np.rint(clean) - clean).max() > 0.45  # the test would catch plain rounding


def _flat_frames(rng: np.random.Generator, h: int, w: int, k: int) -> list:
    """``k`` held-out flat frames (noisy frame, clean image, exposure ns) at levels 80 DN apart,
    noise SD 5 DN, each clean image with a sub-DN texture of its own."""
    held = []
    for i in range(k):
        clean = 15 + 80.0 * (i + 1) + rng.uniform(0, 1, (h, w))
        held.append((np.rint(clean + rng.normal(0, 5, (h, w))).astype(np.uint16), clean, 40000 * (i + 1)))
    return held


def test_real_noise_mosaics_use_every_real_pixel_once(tmp_path: Path):
    # k flat frames at k levels → k mosaics: at every pixel the k scenes show the k frames once
    # each (a Latin square), each with its own frame's clean image, in regions of about equal area.
    rng = np.random.default_rng(2)
    h, w, k = 64, 96, 4
    held = _flat_frames(rng, h, w, k)
    written = {}

    def write(path: Path, px: np.ndarray, iso: int, exposure_ns: int):
        written[path.parent.name] = px

    E.write_mosaics(tmp_path, held, write)
    assert sorted(written) == [f"mosaic_{m}" for m in range(k)]
    frames = np.stack([written[f"mosaic_{m}"] for m in range(k)]).astype(np.int64)
    cleans = np.stack([np.load(tmp_path / f"mosaic_{m}" / "clean.npy") for m in range(k)])
    src = np.stack([f for f, _, _ in held]).astype(np.int64)
    src_clean = np.stack([c for _, c, _ in held])
    # Which frame each scene shows at each pixel, told by its clean image (levels 80 DN apart).
    which = np.rint((cleans - 15 - 0.5) / 80.0).astype(np.int64) - 1
    assert (np.sort(which, axis=0) == np.arange(k)[:, None, None]).all()
    assert np.array_equal(frames, np.take_along_axis(src, which, 0))
    assert np.array_equal(cleans, np.take_along_axis(src_clean, which, 0))
    area = np.bincount(which[0].ravel(), minlength=k) / (h * w)
    assert area.min() > 0.15  # equal areas up to the quantile split of a 64×96 map
    labels = E.mosaic_labels((h, w), k, 7)
    edges = (np.diff(labels, axis=1) != 0).mean()
    assert 0.01 < edges < 0.5  # regions, not noise: a label map with edges, not a random field


def _png8(img: np.ndarray) -> bytes:
    raw = b"".join(b"\0" + row.astype(np.uint8).tobytes() for row in img)

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    head = struct.pack(">IIBBBBB", img.shape[1], img.shape[0], 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", head) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def test_png_reader_reads_set_002s_8_bit_frames():
    img = np.random.default_rng(6).integers(0, 256, (5, 9)).astype(np.uint16)
    got = L.read_png_grey(_png8(img), "x.png", depths=(8,))
    assert got.dtype == np.uint16 and np.array_equal(got, img)
    with pytest.raises(E.ConvertError, match="a 8-bit PNG of colour type 0, interlace 0: want 16-bit grey"):
        E.read_png16(_png8(img), "x.png")  # set 001's reader still refuses anything but 16 bits


def test_ladder_flat_shape_and_clean_images():
    # Known truth: a flat field's shape (PRNU and shading, mean 1) seen through noisy pairs at 40
    # levels from 0 to 200 DN; the shape pooled from them predicts a pair's clean image within a
    # small fraction of its noise, where one pair's own mean errs by the noise / √2.
    rng = np.random.default_rng(8)
    h, w = 64, 96
    shape = (1 + 0.01 * rng.normal(size=(h, w))) * np.linspace(0.97, 1.03, w)[None]
    shape /= shape.mean()
    dark = 3 + rng.normal(0, 0.2, (h, w))
    levels = np.linspace(0, 200, 40)
    signals = [np.mean([s * shape + rng.normal(0, 0.5 + 0.1 * np.sqrt(s), (h, w)) for _ in range(2)], axis=0) for s in levels]
    got = L.flat_shape([sig for s, sig in zip(levels, signals) if s > 5])
    assert abs(got.mean() - 1) < 1e-12
    err = 150 * (got - shape)  # the clean image's error at 150 DN
    noise = 0.5 + 0.1 * np.sqrt(150)
    assert err.std() < 0.2 * noise, err.std()
    one_pair = signals[30] / levels[30] * 150 - 150 * shape  # what one pair's own mean gives
    assert one_pair.std() > 0.5 * noise
    # Every pair in the dark and shadow bands, every 4th above, none past EVAL_MAX.
    lv = [i / 100 for i in range(0, 60, 2)]  # 0, 0.02, … 0.58 of the range
    pick = L.ladder(lv)
    assert [lv[i] for i in pick] == [0.0, 0.02, 0.04, 0.06, 0.08, 0.16, 0.24, 0.32, 0.40]


def test_tile_scenes_have_large_flat_regions_and_lens_blurred_edges():
    # Tile maps: exactly `tiles` cells of mean area h·w/tiles; far fewer edges than a dead-leaves
    # map of the same size (a map of tiny regions, or noise, fails the edge bound).
    rng = np.random.default_rng(11)
    h, w, tiles = 96, 128, 12
    lab = B.tile_labels(h, w, tiles, rng)
    assert sorted(np.unique(lab)) == list(range(tiles))
    edges = (np.diff(lab, axis=1) != 0).mean()
    leaves = (np.diff(E.mosaic_labels((h, w), 4, 7), axis=1) != 0).mean()
    assert edges < 0.5 * leaves and edges < 0.05, (edges, leaves)
    # The blur keeps a constant, and blurs a step into the sampled Gaussian's ramp: at x px from
    # the step, Φ(x/σ) of the height (an unnormalised or box kernel misses by > 0.05).
    assert np.allclose(B.gaussian_blur(np.full((20, 30), 7.5), 1.3), 7.5)
    step = np.zeros((20, 40))
    step[:, 20:] = 100.0
    got = B.gaussian_blur(step, 1.5)[10]
    from math import erf, sqrt

    for x in (-3, -1, 1, 3):
        want = 100 * 0.5 * (1 + erf((x + 0.5) / (1.5 * sqrt(2))))
        assert abs(got[20 + x] - want) < 1.5, (x, got[20 + x], want)
    assert np.array_equal(B.gaussian_blur(step, 0), step)
    # Generated tile scenes: levels inside the band, flat interiors (most 3×3 windows of a packed
    # plane, 6×6 raw px, constant before the rounding, so within 1 DN after it; dead-leaves
    # scenes score 0.03–0.12 here).
    layout = {"cfa": "RGGB", "black": BLACK, "white": 4095}
    imgs = B.generate_tiles(6, h, w, layout, seed=3, tiles=tiles, blur=1.0, levels=(10.0, 300.0))
    for g in imgs:
        above = g.astype(np.float64) - B.per_position(BLACK, g.shape)
        assert above.min() >= 9.5 and above.max() <= 300.5
        win = np.lib.stride_tricks.sliding_window_view(B.pack_raw(g.astype(np.float64)), (3, 3), axis=(1, 2))
        flat = (win.max((-1, -2)) - win.min((-1, -2)) <= 1.0).mean()  # per CFA plane: the rounding alone
        assert flat > 0.45, flat
    assert not np.array_equal(imgs[0], imgs[1])


def test_tiled_mosaics_keep_every_pixel_real_and_its_clean_value_its_frames(tmp_path: Path):
    # k flat frames at levels 80 DN apart → k tiled scenes. Every pixel is the real pixel of one
    # held-out frame with that frame's clean value; in interiors each frame shows once over the k
    # scenes (a Latin square); along edges the chosen level lies between the two sides' levels (a
    # blurred ramp), and the flat interiors are most of the image (the dead-leaves mosaics: few).
    rng = np.random.default_rng(3)
    h, w, k = 128, 160, 5
    held = _flat_frames(rng, h, w, k)
    written = {}

    def write(path: Path, px: np.ndarray, iso: int, exposure_ns: int):
        written[path.parent.name] = px

    E.write_tiles(tmp_path, held, write, tiles=8, blur=2.0, seed=5)
    assert sorted(written) == [f"tiles_{m:02}" for m in range(k)]
    frames = np.stack([written[f"tiles_{m:02}"] for m in range(k)]).astype(np.int64)
    cleans = np.stack([np.load(tmp_path / f"tiles_{m:02}" / "clean.npy") for m in range(k)])
    src = np.stack([f for f, _, _ in held]).astype(np.int64)
    src_clean = np.stack([c for _, c, _ in held])
    which = np.rint((cleans - 15 - 0.5) / 80.0).astype(np.int64) - 1
    assert which.min() >= 0 and which.max() < k
    assert np.array_equal(frames, np.take_along_axis(src, which, 0))
    assert np.array_equal(cleans, np.take_along_axis(src_clean, which, 0))
    cls = E.tile_plan((h, w), k, 8, 5)
    assert len(np.unique(cls)) == k  # every class has cells (8 cells dealt to 5 classes)
    win = np.lib.stride_tricks.sliding_window_view(np.pad(cls, 7, mode="edge"), (15, 15))
    interior = win.max((-1, -2)) == win.min((-1, -2))  # no other class within 7 px (3.5 σ)
    assert interior.mean() > 0.5, interior.mean()
    for m in range(k):
        assert np.array_equal(which[m][interior], ((cls + m) % k)[interior])
    assert (np.sort(which[:, interior], axis=0) == np.arange(k)[:, None]).all()
    for m in range(k):
        # The picked frame's level (here its index) lies between the lowest and highest level
        # within 7 px: a ramp, never a level from elsewhere.
        near = np.lib.stride_tricks.sliding_window_view(np.pad((cls + m) % k, 7, mode="edge"), (15, 15))
        assert ((which[m] >= near.min((-1, -2))) & (which[m] <= near.max((-1, -2)))).all()
    edge = ~interior
    assert (which[:, edge] != ((cls[None] + np.arange(k)[:, None, None]) % k)[:, edge]).any()  # edges are blurred
    leaves = E.mosaic_labels((h, w), k, 7)
    wl = np.lib.stride_tricks.sliding_window_view(np.pad(leaves, 7, mode="edge"), (15, 15))
    assert (wl.max((-1, -2)) == wl.min((-1, -2))).mean() < 0.5 * interior.mean()


def test_ladder_conversion_never_uses_a_frame_twice_across_calibration_and_evaluation(tmp_path: Path, monkeypatch):
    # A small set 002 on disk (8-bit PNGs, its descriptor): a dark burst and photon-transfer pairs
    # at 30 exposures, frame 0 of every pair written with even codes and frame 1 with odd ones.
    # The converter must calibrate on frame 0 only (every target DNG even) and evaluate on frame 1
    # only (every pixel of every mosaic and tiled scene odd), each evaluated pixel paired with its
    # own level's clean image (noisy − clean within the noise; the neighbouring level's clean
    # image, 3 DN away, would be 3 DN off). A converter that evaluated frame 0, or calibrated on
    # frame 1, fails the parity; one that paired a frame with another level's clean, the RMS.
    monkeypatch.setattr(L, "CAL_W", 48)
    monkeypatch.setattr(L, "EVAL_W", 32)
    rng = np.random.default_rng(9)
    h, w = 32, 64
    root = tmp_path / "repo" / L.SET
    (root / "images").mkdir(parents=True)
    shape = 1 + 0.005 * rng.normal(size=(h, w))
    lines = ["d 140"]

    def png(name: str, img: np.ndarray) -> None:
        (root / "images" / name).write_bytes(_png8(np.clip(img, 0, 255)))
        lines.append(f"i images\\{name}")

    for i in range(20):
        png(f"d_burst_{i:02}.png", np.rint(3 + rng.normal(0, 0.3, (h, w))))
    for t in range(30):
        s = 3.0 * t
        lines.append(f"b {40 * t} {s * 10:.1f}")
        for f in range(2):
            v = np.floor((3 + s * shape + rng.normal(0, 0.5 + 0.1 * np.sqrt(s), (h, w))) / 2) * 2 + f
            png(f"b_{t:03}_{f}.png", v)
        if t < 5:
            lines.append(f"d {40 * t}")
            for f in range(2):
                png(f"d_{t:03}_{f}.png", np.rint(3 + rng.normal(0, 0.3, (h, w))))
    (root / "EMVA1288_Data.txt").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    got = L.convert(E.Source(tmp_path / "repo", L.SET), out, lambda *a: None)
    assert len(got["levels"]) >= 8
    targets = sorted((out / "cal").glob("target_*.dng"))
    assert len(targets) == 30
    for p in targets:
        assert (noisecal.read_dng(p)[0] % 2 == 0).all(), p.name
    for kind in ("eval-mosaic", "eval-tiles"):
        scenes = sorted((out / kind).iterdir())
        assert len(scenes) == len(got["levels"])
        for d in scenes:
            px = noisecal.read_dng(d / "frame.dng")[0]
            clean = np.load(d / "clean.npy")
            assert (px % 2 == 1).all(), d
            # The odd codes add ½ DN on average and a parity step of up to 1: the rest is the noise.
            err = px - clean - 0.5
            assert np.sqrt(np.mean(err**2)) < 1.6, (d, np.sqrt(np.mean(err**2)))


def test_tile_training_scenes_take_the_evaluation_ladder_and_fixed_pattern():
    # Known truth: held-out flat fields at 6 levels whose clean images carry a white fixed pattern
    # of SD 0.2 + 0.01·level over a smooth shading. tile_training recovers the ladder and the
    # line (a fit on the raw SD, shading included, puts t1 above 0.2 here); generate_tiles with
    # them gives only ladder levels (before the texture) and the texture's SD at each level.
    rng = np.random.default_rng(12)
    h, w = 128, 160
    black = [3.0] * 4
    shading = 40 * np.linspace(-1, 1, w)[None] * np.ones((h, 1))
    held = []
    for lv in (0.0, 5.0, 20.0, 40.0, 70.0, 100.0):
        clean = 3.0 + lv + 0.01 * lv * shading + (0.2 + 0.01 * lv) * rng.standard_normal((h, w))
        held.append((np.zeros((h, w), np.uint16), clean, 1000))
    got = E.tile_training(held, black)
    assert np.allclose(got["ladder"], [0, 5, 20, 40, 70, 100], atol=0.05)
    t0, t1 = got["texture"]
    assert abs(t0 - 0.2) < 0.02 and abs(t1 - 0.01) < 0.001, got["texture"]
    layout = {"cfa": "RGGB", "black": black, "white": 255}
    ladder = [0.0, 20.0, 60.0, 100.0]
    flat = B.generate_tiles(4, h, w, layout, seed=4, tiles=6, blur=2.0, levels=(0.0, 100.0), ladder=ladder)
    for g in flat:
        assert set(np.unique(g.astype(np.float64) - 3.0)) <= set(ladder)
    assert len(set(np.unique(np.concatenate([g.ravel() for g in flat])))) == len(ladder)  # ramps only of ladder levels
    tex = B.generate_tiles(4, h, w, layout, seed=4, tiles=6, blur=2.0, levels=(0.0, 100.0), ladder=ladder, texture=(0.5, 0.02))
    for g, f in zip(tex[:1], flat[:1]):  # the first scene: the same map (the texture's draws come after it)
        d = g.astype(np.float64) - f
        for lv in ladder:
            sd = d[f == 3.0 + lv].std()
            assert abs(sd**2 - ((0.5 + 0.02 * lv) ** 2 + 1 / 12)) < 0.15 * (0.5 + 0.02 * lv) ** 2 + 0.02, (lv, sd)
