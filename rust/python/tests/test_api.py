"""The package's behaviour: properties, errors, CFA origin of crops, float32, batches, threads."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import noisecal


def test_properties(pack):
    assert pack.isos == [100, 800]
    lay = pack.layout
    assert lay["cfa"] == "RGGB" and lay["white"] == 1023 and lay["bits"] == 10
    assert lay["black"] == [64.0] * 4
    assert pack.bin_width >= 1
    assert isinstance(pack.warnings, list)
    assert noisecal.Pack.from_bytes(pack.to_bytes()).to_bytes() == pack.to_bytes()


def test_errors_are_noisecal_errors_with_the_cores_message(pack, tmp_path):
    clean = np.full((8, 8), 300, np.uint16)
    with pytest.raises(noisecal.NoisecalError, match=r"outside the pack's calibrated range.*\(extrapolate=True\)"):
        pack.synth(clean, 25600, 1)
    with pytest.raises(noisecal.NoisecalError, match="unknown model"):
        pack.synth(clean, 800, model="gauss")
    with pytest.raises(noisecal.NoisecalError, match="dimensions"):
        pack.synth(np.zeros((2, 2, 2, 2), np.uint16), 800)
    with pytest.raises(noisecal.NoisecalError, match="black_level has 3 values"):
        pack.synth(clean, 800, black_level=[1, 2, 3])
    with pytest.raises(noisecal.NoisecalError, match="must be above|only adds noise"):
        pack.renoise(clean, 800, 100)
    with pytest.raises(noisecal.NoisecalError, match="cannot read model pack"):
        noisecal.Pack.load(tmp_path / "missing.pack")
    bad = tmp_path / "bad.pack"
    bad.write_bytes(b"not a pack at all")
    with pytest.raises(noisecal.NoisecalError, match="not a usable model pack"):
        noisecal.Pack.load(bad)
    with pytest.raises(TypeError, match="clean must be a numpy array of uint16, got ndarray of dtype float64"):
        pack.synth(clean.astype(np.float64), 800)
    with pytest.raises(noisecal.NoisecalError, match="bin_width 0"):
        noisecal.calibrate(tmp_path, bin_width=0)


def test_crop_origin_gives_true_cfa_positions(pack):
    # Per-position black levels far apart make each CFA position land in a different bin (and so
    # a different noise variance) for the same clean value: a crop whose origin is ignored would
    # give its pixels the variance of the wrong position.
    black = [64.0, 364.0, 664.0, 964.0]
    clean = np.full((512, 512), 1000, np.uint16)
    ref = pack.synth(clean, 800, 1, black_level=black).astype(np.float64) - clean
    var_ref = np.array([ref[py::2, px::2].var() for py in (0, 1) for px in (0, 1)])
    assert var_ref.max() / var_ref.min() > 3, f"positions not distinguishable: {var_ref}"
    for origin in [(1, 1), (0, 1), (1, 0), (255, 1000)]:
        crop = clean[:256, :256]
        noise = pack.synth(crop, 800, 2, black_level=black, cfa_origin=origin).astype(np.float64) - crop
        for py in (0, 1):
            for px in (0, 1):
                true_pos = ((py + origin[0]) % 2) * 2 + (px + origin[1]) % 2
                v = noise[py::2, px::2].var()
                assert abs(v / var_ref[true_pos] - 1) < 0.12, (origin, py, px, v, var_ref)


def test_float32_is_normalised_by_black_and_white(pack):
    clean = np.full((64, 64), 600, np.uint16)
    f = (clean.astype(np.float32) - 64) / (1023 - 64)
    out = pack.synth_float(f, 800, 5)
    assert out.dtype == np.float32 and out.shape == f.shape
    dn = np.rint(out * (1023 - 64) + 64).astype(np.uint16)
    np.testing.assert_array_equal(dn, pack.synth(clean, 800, 5))
    batch = pack.synth_float(np.stack([f, f]), 800, 5)
    np.testing.assert_array_equal(batch[0], out)
    assert not np.array_equal(batch[0], batch[1]), "image i of a batch uses seed + i"


def test_strided_input_is_read_in_place(pack):
    base = np.full((64, 128), 500, np.uint16)
    view = base[:, ::2]
    assert not view.flags["C_CONTIGUOUS"]
    np.testing.assert_array_equal(pack.synth(view, 800, 3), pack.synth(np.ascontiguousarray(view), 800, 3))


def test_same_bytes_on_any_thread_count(session, tmp_path):
    code = (
        "import noisecal, numpy as np, sys;"
        f"p = noisecal.Pack.load({str(session['cli_pack'])!r});"
        "c = (np.arange(300*301) % 900 + 64).astype(np.uint16).reshape(300, 301);"
        "sys.stdout.buffer.write(p.synth(c, 500, 9).tobytes())"
    )
    outs = []
    for threads in ("1", "2", "5"):
        env = dict(os.environ, RAYON_NUM_THREADS=threads)
        outs.append(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, check=True).stdout)
    assert len(outs[0]) == 300 * 301 * 2
    assert outs[0] == outs[1] == outs[2]


def test_gil_is_released_while_the_core_works(pack):
    clean = np.full((3000, 3000), 500, np.uint16)
    ticks = 0
    done = threading.Event()

    def work():
        for _ in range(3):
            pack.synth(clean, 800, 1)
        done.set()

    t = threading.Thread(target=work)
    t0 = time.perf_counter()
    t.start()
    while not done.is_set():
        ticks += 1
        time.sleep(0.001)
    t.join()
    elapsed = time.perf_counter() - t0
    # With the GIL held for the whole synthesis the loop could not tick while it runs.
    assert ticks > 0.3 * elapsed / 0.0011, (ticks, elapsed)


def test_tables_reproduce_the_cores_distribution(pack):
    t = pack.tables(800)
    level = 700
    clean = np.full((400, 400), level, np.uint16)
    noise = pack.synth(clean, 800, 4, components="pixel").astype(np.int64) - level
    for p in range(4):
        b = t["lut"][p, level]
        cdf = t["cdf"][p, b].astype(np.float64) / 2**32
        pmf = np.diff(np.concatenate([[0.0], cdf]))
        values = t["first"][p, b] + np.arange(len(pmf))
        got = noise[p // 2::2, p % 2::2].ravel()
        mean = (pmf * values).sum()
        sd = np.sqrt((pmf * (values - mean) ** 2).sum())
        assert abs(got.mean() - mean) < 5 * sd / np.sqrt(got.size)
        assert abs(got.std() / sd - 1) < 0.03


def test_seed_for_is_stable():
    assert noisecal.seed_for("img_0001.dng") == noisecal.seed_for("img_0001.dng")
    assert noisecal.seed_for("img_0001.dng") != noisecal.seed_for("img_0002.dng")
    assert noisecal.seed_for("a", 1) != noisecal.seed_for("a", 2)
    assert 0 <= noisecal.seed_for(b"x") < 2**64
