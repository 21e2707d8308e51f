//! The default components at sub-DN noise on a real sensor (EMVA 1288 set 002, 8 bits, noise
//! about 0.3–0.7 DN, a fixed pattern of 0.12 DN RMS): at codes 4 and 7 each bin's samples come
//! from one exposure whose clean levels sit at one fraction of the code, so the bin's PMF is
//! at the lattice's floor `f(1 − f)` and no PMF on whole codes can have the pattern's dither
//! taken out of it. Synthesis draws the pattern's fraction with the pixel's noise (one rounding,
//! `synth/phase_tables.rs`). The pack is `tests/data/emva002/ladder.pack` (README beside it);
//! the real figures are those of the set's held-out frames, `frame − round(clean)`
//! (`tests/bench/emva1288_black.py`).

mod set002;

use noisecal_core::synth::sampler::IsoSampler;
use set002::{REAL_LESS_LEVEL_AT_BLACK, default_and_pixel, drawn_offsets, mean_var, own, set002};

/// Per code: the real variance and the real shares at −2 … +2 DN (`/tmp/i12/black.txt`,
/// held-out frames of set 002). Code 14's variance, 0.4342 DN², is a measurement that happens to
/// read as log₁₀ e.
#[allow(clippy::approx_constant)]
const REAL: [(u16, f64, [f64; 5]); 8] = [
    (3, 0.0921, [0.0000, 0.0661, 0.9066, 0.0273, 0.0000]),
    (4, 0.2601, [0.0000, 0.0026, 0.5026, 0.4924, 0.0025]),
    (5, 0.2224, [0.0005, 0.2743, 0.7111, 0.0140, 0.0000]),
    (7, 0.2925, [0.0001, 0.0182, 0.5575, 0.4176, 0.0067]),
    (8, 0.2965, [0.0053, 0.3678, 0.5977, 0.0291, 0.0000]),
    (11, 0.3684, [0.0035, 0.1816, 0.6513, 0.1604, 0.0032]),
    (14, 0.4342, [0.0009, 0.0634, 0.4955, 0.4102, 0.0297]),
    (15, 0.4639, [0.0280, 0.3559, 0.5252, 0.0889, 0.0018]),
];

/// Variance and shares at −2 … +2 DN of `noisy − code` over `seeds` flat images at `code`.
fn drawn(sampler: &IsoSampler, code: u16, seeds: u64) -> (f64, [f64; 5]) {
    let v = drawn_offsets(sampler, code, seeds);
    let n = v.len() as f64;
    let shares = std::array::from_fn(|k| v.iter().filter(|&&x| x == k as f64 - 2.0).count() as f64 / n);
    (mean_var(&v).1, shares)
}

/// Measured (2 seeds of 200 × 512; default / pixel-only variance, then the default's shares
/// at −1 / +2 DN; real in `REAL`), before → with the phase tables: code 3 0.1145 → 0.0982 /
/// 0.0857; code 4 0.3421 → 0.2682 / 0.2640, shares 0.027 / 0.020 → 0.0056 / 0.0036 (real
/// 0.0026 / 0.0025); code 7 0.3404 → 0.3213 / 0.3049; codes 8–15 unchanged; code 5 0.2627 →
/// 0.2657 / 0.2480 (position 1's bin 2 there sits at +0.30 DN in this pack, pooled onto its
/// neighbours' mean: drawn at its phase; a pack of today's calibration has it at −0.29 and code
/// 5 unchanged). What the default
/// adds to pixel-only is now at most the pattern's own variance (0.0145 DN²) plus sampling;
/// before, +0.029 / +0.078 / +0.036 DN² at codes 3 / 4 / 7. On the re-cut pack (README), with
/// bin 0 kept whole at black where the rescale cannot reach the law (`derive/fine_levels.rs`),
/// default / pixel-only: code 3 0.1079 / 0.0949, 4 0.2682 / 0.2640, 5 0.2479 / 0.2319, 7 0.3213 /
/// 0.3049, 8 0.3042 / 0.2892; `own` (what the real figures compare with) draws pixel-only's
/// tables on this pack (no row, column or frame offset): 0.975–1.043 of the real variance.
#[test]
fn sub_dn_codes_draw_the_pattern_with_the_pixel_noise() {
    let (pack, pattern) = set002();
    let (default, pixel) = default_and_pixel(&pack);
    let own = own(&pack);
    for (code, real, shares) in REAL {
        let (d, ds) = drawn(&default, code, 2);
        let (p, ps) = drawn(&pixel, code, 2);
        // Like with like (the real clean images carry the pattern): every component but the
        // pattern. On the pack of today's calibration 0.97–1.05 at every code; a sampler that
        // added the pattern again read up to 1.11 (code 5) and 1.17 (code 3).
        let (o, _) = drawn(&own, code, 2);
        assert!((0.93..1.08).contains(&(o / real)), "code {code}: own / real variance {:.3}", o / real);
        eprintln!(
            "code {code:2}: default {d:.4} ({:.3}×) pixel {p:.4} ({:.3}×) | shares −1/+2 real {:.4}/{:.4} default {:.4}/{:.4} pixel {:.4}/{:.4}",
            d / real,
            p / real,
            shares[1],
            shares[4],
            ds[1],
            ds[4],
            ps[1],
            ps[4]
        );
        // The variance of 200 000 draws of a PMF of 0.1–0.5 DN² has an SE of 0.0003–0.0015 DN²
        // (the two samplers share their streams, so the difference's is smaller): the bound
        // sits 0.01 DN² above the pattern, 0.02–0.06 below the old figures at codes 3, 4 and 7.
        assert!(
            d - p < pattern + 0.01,
            "code {code}: the default adds {:.4} DN² to pixel-only (pattern {pattern:.4}; the dither on top of \
             the lattice's floor: +0.029 / +0.078 / +0.036 at codes 3 / 4 / 7)",
            d - p
        );
    }
    // At black (code 3) the bin holds the pattern (`synth_fine_levels_structured.rs`): the default
    // draws pixel-only's variance, against the held-out `noisy − level` (the pattern kept) at the
    // 0 and 0.1 DN exposures 1.00 / 1.05; with the pattern added on top of the bin, 0.1080 DN²,
    // +0.0131 over pixel-only, 1.14 / 1.19.
    let (d3, _) = drawn(&default, 3, 2);
    let (p3, _) = drawn(&pixel, 3, 2);
    assert!((d3 - p3).abs() < 0.004, "code 3: the default adds {:.4} DN² to pixel-only (before: 0.0131)", d3 - p3);
    for real in REAL_LESS_LEVEL_AT_BLACK {
        assert!(
            (0.95..1.07).contains(&(d3 / real)),
            "code 3: default / real noisy − level {:.3} (before: 1.14–1.19)",
            d3 / real
        );
    }
    // Code 4's tails: the real shares at −1 / +2 DN are 0.0026 / 0.0025; the dither drew 0.027 /
    // 0.020, pixel-only draws 0.0037 / 0.0034.
    let (_, ds) = drawn(&default, 4, 2);
    assert!(ds[1] < 0.01 && ds[4] < 0.01, "code 4's shares at −1 / +2 DN: {:.4} / {:.4}", ds[1], ds[4]);
}
