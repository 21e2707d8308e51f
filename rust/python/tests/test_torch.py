"""noisecal.torch draws the core's distribution (runs when torch is installed).

The check: on one clean image (column bands of constant level, a crop at an odd CFA origin, and a
batch with another origin), NoiseSynth's samples and `Pack.synth`'s are binned per (CFA position,
clean level) into cells of about equal probability under the exact distribution the tables encode
(noise PMF shifted by the level and clamped to the sensor's codes), and compared by a two-sample
chi-square test of homogeneity; each is also tested against the exact distribution (goodness of
fit). Mutations that a wrong implementation would make (a value off by one, the neighbouring bin,
the wrong CFA origin, swapped positions, draws in the wrong unit) must fail the same check.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.torch

ISO = 800
# Levels in DN (black 64, white 1023): black, shadows, mid-tones, highlights, near white where the
# output clips, and one above white (the core keeps the level and draws from the top bin).
LEVELS = (64, 100, 300, 600, 900, 1010, 1100)
BAND = 128  # columns per level
ROWS = 768  # per position and level: ROWS / 2 × BAND / 2 = 24 576 samples
CELLS = 40  # chi-square cells of about equal probability
ALPHA = 1e-4  # family-wise false-alarm rate of one check (Bonferroni over its tests)


def clean_image() -> np.ndarray:
    return np.repeat(np.array(LEVELS, dtype=np.uint16), BAND)[None, :].repeat(ROWS, axis=0)


def chi2_sf(x: float, df: int) -> float:
    """Upper tail of the chi-square distribution (Wilson–Hilferty; ample for df ≥ 10)."""
    z = ((x / df) ** (1 / 3) - (1 - 2 / (9 * df))) / math.sqrt(2 / (9 * df))
    return 0.5 * math.erfc(z / math.sqrt(2))


def exact_pmf(t: dict, pos: int, level: int) -> np.ndarray:
    """P(output code) for a clean level at a position, from the tables alone."""
    white = int(t["white"])
    b = t["lut"][pos, min(level, white)]
    cdf = t["cdf"][pos, b].astype(np.float64) / 2.0**32
    pmf = np.diff(cdf, prepend=0.0)
    lo, hi = t["range"][pos]
    codes = np.clip(level + t["first"][pos, b] + np.arange(len(pmf)), lo, hi)
    out = np.zeros(white + 1)
    np.add.at(out, codes, pmf)
    return out


def cells(pmf: np.ndarray) -> np.ndarray:
    """Cell index per output code: consecutive codes merged to about 1/CELLS probability each."""
    edges = np.floor(np.cumsum(pmf) * CELLS * (1 - 1e-9)).astype(np.int64)
    _, idx = np.unique(np.minimum(edges, CELLS - 1), return_inverse=True)
    return idx


def groups(img: np.ndarray, origin: tuple[int, int]):
    """(position, level, samples) for each CFA position and level band of one output image."""
    for y in (0, 1):
        for x in (0, 1):
            pos = ((y + origin[0]) % 2) * 2 + (x + origin[1]) % 2
            for j, level in enumerate(LEVELS):
                band = img[y::2, j * BAND + x : (j + 1) * BAND : 2]
                yield pos, level, band.ravel()


def compare(tables: dict, ours: list, core: list, origins: list) -> dict:
    """Two-sample chi-square per (image, position, level) between `ours` and `core`, and
    goodness of fit of each against the exact table distribution. Returns the smallest p-values,
    the largest JSD between the two empirical histograms, and the number of tests."""
    p_two, p_ours, p_core, jsd, tests = 1.0, 1.0, 1.0, 0.0, 0
    for a_img, b_img, origin in zip(ours, core, origins):
        for (pos, level, a), (_, _, b) in zip(groups(a_img, origin), groups(b_img, origin)):
            pmf = exact_pmf(tables, pos, level)
            cell = cells(pmf)
            k = cell.max() + 1
            expect = np.bincount(cell, weights=pmf, minlength=k)
            ca = np.bincount(cell[a], minlength=k).astype(np.float64)
            cb = np.bincount(cell[b], minlength=k).astype(np.float64)
            # Codes the tables give no probability are impossible under the exact distribution.
            impossible_a = int(np.count_nonzero(pmf[a] == 0))
            impossible_b = int(np.count_nonzero(pmf[b] == 0))
            n = len(a)
            both = ca + cb
            keep = both > 0
            two = float(np.sum((ca[keep] - cb[keep]) ** 2 / both[keep]))
            p_two = min(p_two, chi2_sf(two, max(int(keep.sum()) - 1, 1)))
            for c, bad, which in ((ca, impossible_a, "ours"), (cb, impossible_b, "core")):
                gof = float(np.sum((c - n * expect) ** 2 / (n * expect)))
                p = 0.0 if bad else chi2_sf(gof, k - 1)
                if which == "ours":
                    p_ours = min(p_ours, p)
                else:
                    p_core = min(p_core, p)
            ha, hb = np.bincount(a, minlength=2048) / n, np.bincount(b, minlength=2048) / n
            m = (ha + hb) / 2
            kl = lambda h: float(np.sum(h[h > 0] * np.log(h[h > 0] / m[h > 0])))  # noqa: E731
            jsd = max(jsd, (kl(ha) + kl(hb)) / 2)
            tests += 1
    return {"p_two": p_two, "p_ours": p_ours, "p_core": p_core, "jsd": jsd, "tests": tests}


def passes(r: dict) -> bool:
    return min(r["p_two"], r["p_ours"]) > ALPHA / r["tests"]


@pytest.fixture(scope="module")
def setup(pack):
    from noisecal.torch import NoiseSynth

    tables = pack.tables(ISO)
    assert not tables["lattice"].any(), "the test pack snaps onto a lattice, which table samplers do not reproduce"
    clean = clean_image()
    # One crop at an odd row origin, and a batch of two images with different origins.
    origins = [(1, 0), (0, 1), (1, 1)]
    # LEVELS has one level above white on purpose: allowed explicitly (the core keeps the level).
    core = [pack.synth(clean, ISO, 3, cfa_origin=origins[0], components="pixel", out_of_range="allow")]
    core += [pack.synth(clean, ISO, 4 + i, cfa_origin=o, components="pixel", out_of_range="allow")
             for i, o in enumerate(origins[1:])]
    return NoiseSynth, tables, clean, origins, core


def draw(synth, clean: np.ndarray, origins: list, seed: int = 0, origin_of=lambda o: o) -> list:
    g = torch.Generator().manual_seed(seed)
    x = torch.from_numpy(clean.astype(np.int64))
    single = synth(x, cfa_origin=origin_of(origins[0]), generator=g).numpy()
    batch = synth(torch.stack([x, x]), cfa_origin=torch.tensor([origin_of(o) for o in origins[1:]]), generator=g).numpy()
    return [single, batch[0], batch[1]]


def test_table_sampler_matches_the_core(setup, pack):
    NoiseSynth, tables, clean, origins, core = setup
    synth = NoiseSynth(pack, ISO, components="pixel")
    r = compare(tables, draw(synth, clean, origins), core, origins)
    print(f"\nNoiseSynth vs Pack.synth: {r}")
    # The core's own samples fit the exported tables (the tables are the core's whole sampler):
    # when this fails, the core adds something the tables do not carry (a component drawn per
    # row, column or frame, a lattice), and NoiseSynth cannot match it from them.
    assert r["p_core"] > ALPHA / r["tests"], f"Pack.synth does not follow pack.tables({ISO}): {r}"
    assert passes(r), r
    assert r["jsd"] < 0.01, r
    # Float input is rounded, as the core's float path does.
    g = torch.Generator().manual_seed(1)
    f = synth(torch.from_numpy(clean[:, :BAND].astype(np.float32)) + 0.3, generator=g)
    assert f.dtype == torch.int32 and f.shape == (ROWS, BAND)


def _permute_positions(t: dict, perm: list[int]) -> dict:
    t = dict(t)
    for key in ("lut", "cdf", "first", "range"):
        t[key] = t[key][perm]
    return t


def _mutants(NoiseSynth, tables: dict):
    """(name, sampler, origin mapping) of plausible implementation mistakes."""
    shifted_up = dict(tables, first=tables["first"] + 1)
    shifted_down = dict(tables, first=tables["first"] - 1)
    nbins = tables["cdf"].shape[1]
    next_bin = dict(tables, lut=np.minimum(tables["lut"] + 1, nbins - 1))
    ident = lambda o: o  # noqa: E731

    class ThirtyOneBits(NoiseSynth):
        def uniform(self, shape, generator, device):  # draws in [0, 2^31): half the CDF's unit
            return torch.randint(0, 1 << 31, shape, generator=generator, device=device, dtype=torch.int64)

    class SixteenBitDraws(NoiseSynth):
        def uniform(self, shape, generator, device):  # 16-bit draws against CDFs in 2^-32 units
            return torch.randint(0, 1 << 16, shape, generator=generator, device=device, dtype=torch.int64)

    return [
        ("value off by one (+1)", NoiseSynth.from_tables(shifted_up), ident),
        ("value off by one (-1)", NoiseSynth.from_tables(shifted_down), ident),
        ("neighbouring level bin", NoiseSynth.from_tables(next_bin), ident),
        ("R and B swapped", NoiseSynth.from_tables(_permute_positions(tables, [3, 1, 2, 0])), ident),
        ("Gr and Gb swapped", NoiseSynth.from_tables(_permute_positions(tables, [0, 2, 1, 3])), ident),
        ("CFA origin ignored", NoiseSynth.from_tables(tables), lambda o: (0, 0)),
        ("CFA origin transposed", NoiseSynth.from_tables(tables), lambda o: (o[1], o[0])),
        ("31-bit draws", ThirtyOneBits.from_tables(tables), ident),
        ("16-bit draws", SixteenBitDraws.from_tables(tables), ident),
    ]


def test_mutations_fail_the_same_check(setup):
    NoiseSynth, tables, clean, origins, core = setup
    caught = {}
    for name, synth, origin_of in _mutants(NoiseSynth, tables):
        r = compare(tables, draw(synth, clean, origins, origin_of=origin_of), core, origins)
        caught[name] = r
        print(f"\n{name}: p_two {r['p_two']:.3g}, p_fit {r['p_ours']:.3g}, max JSD {r['jsd']:.4f}")
    missed = [n for n, r in caught.items() if passes(r)]
    assert not missed, f"mutations not caught: {missed}"
    # The comparison with the core alone (no knowledge of the exact tables) catches each of them.
    missed = [n for n, r in caught.items() if r["p_two"] > ALPHA / r["tests"]]
    assert not missed, f"mutations the two-sample test misses: {missed}"


def test_components_it_does_not_draw_are_refused(pack):
    from noisecal.torch import NoiseSynth

    # Asked for explicitly: refused whatever the pack holds (the default set: test_fixed_pattern.py).
    for bad in ("pixel,row", "all", "frame", "pixel,fpn", ""):
        with pytest.raises(ValueError, match=r"NoiseSynth draws the pixel component alone"):
            NoiseSynth(pack, ISO, components=bad)
    assert NoiseSynth(pack, ISO, components="pixel").iso == ISO
    # A baseline model is pixel-only: nothing to refuse.
    assert pack.tables(ISO, model="hg")["structure"] == []
    assert NoiseSynth(pack, ISO, model="hg").iso == ISO
