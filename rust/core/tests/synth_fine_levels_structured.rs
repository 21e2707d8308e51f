//! The default components near black on a real sub-DN sensor (EMVA 1288 set 002, 8 bits, noise
//! at black about 0.3 DN, a fixed pattern of 0.12 DN, no significant row, column or frame
//! offsets): where the sampler draws the fine levels' tables (`derive/fine_levels.rs`), the
//! default must draw pixel-only's tables with the offsets taken out, so that at black it adds
//! about the pattern's own variance to what pixel-only draws. The pack is
//! `tests/data/emva002/ladder.pack` (source, licence and how it was made in its README); the
//! real variance at black is that of the set's held-out frames there.

mod set002;

use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::IsoSampler;
use set002::{REAL_LESS_LEVEL_AT_BLACK, default_and_pixel, drawn_offsets, mean_var, own, set002};

/// Black's code (black 2.83–2.92 DN by position: 0.13 DN above it).
const BLACK_CODE: u16 = 3;
/// Variance of `frame − round(clean)` at code 3 over the set's held-out frames (521 023 pixels;
/// `tests/bench/emva1288_black.py`, "real −round").
const REAL_AT_BLACK: f64 = 0.0921;

/// Variance and mean of `noisy − code` over `seeds` flat images at `code`.
fn drawn(sampler: &IsoSampler, code: u16, seeds: u64) -> (f64, f64) {
    let (mean, var) = mean_var(&drawn_offsets(sampler, code, seeds));
    (var, mean)
}

/// Measured (4 seeds of 200 × 512): default / pixel-only / real variance at black 0.1148 /
/// 0.0857 / 0.0921 DN² (1.25× / 0.93×); the default adds 0.029 DN² to pixel-only, the
/// pattern's own 0.0145 and 0.015 the deconvolution cannot take out of a PMF at the lattice's
/// floor. Made from the deconvolved bins instead (the wrong order: the law anchored at the
/// dark frames' `T + 1/12` less what the first bin read lost to its deconvolution, then held at
/// 1/6 DN²), the default drew 0.1503 (1.63×), 0.065 DN² over pixel-only, its table at
/// black wider (0.135 DN²) than pixel-only's (0.097) before any offset was added. With the
/// pattern drawn with the pixel noise at the lattice's floor (`synth/phase_tables.rs`) the
/// default draws 0.0983. On the re-cut pack with bin 0 kept whole at black (the rescale toward
/// the dark frames' 0.18–0.23 DN² narrowed it instead; a one-level bin, `derive/fine_levels.rs`): default /
/// pixel-only 0.1080 / 0.0949 (1.17× / 1.03×). With the pattern the bin holds taken out of the
/// phase tables' `Y` (`StructureSampler::black_phase_set`): 0.0951 / 0.0949 (1.03× / 1.03×).
#[test]
fn at_black_the_default_draws_pixel_only_less_the_offsets() {
    let (pack, pattern) = set002();
    let (default, pixel) = default_and_pixel(&pack);
    let (d, dm) = drawn(&default, BLACK_CODE, 4);
    let (p, pm) = drawn(&pixel, BLACK_CODE, 4);
    eprintln!(
        "at black: default {d:.4} ({:.2}×, mean {dm:+.3}), pixel-only {p:.4} ({:.2}×, mean {pm:+.3}), pattern {pattern:.4} DN²",
        d / REAL_AT_BLACK,
        p / REAL_AT_BLACK
    );
    // The sampling SE of a variance of 400 000 draws of a three-point PMF near 0.1 DN² is about
    // 0.0005 DN²: the bounds sit 0.02 DN² inside the wrong order's figures.
    assert!(
        d - p < pattern + 0.03,
        "the default adds {:.4} DN² to pixel-only at black (pattern {pattern:.4}; wrong order: 0.065)",
        d - p
    );
    assert!(d / REAL_AT_BLACK < 1.4, "default / real variance at black {:.3} (wrong order: 1.63)", d / REAL_AT_BLACK);
    // Black's bin holds the pattern: its samples (the 0.1 DN step's target frame) are measured
    // about their clean level rounded, which the 0.12 DN pattern does not move off code 3, so the
    // PMF is that of `round(black + pattern + noise)`, as the held-out `noisy − round(clean)` and
    // `noisy − level` are. The default draws it with that pattern taken out of its `Y` and the
    // pattern added at the pixel's phase (`StructureSampler::black_phase_set`): what pixel-only
    // draws, within sampling (the two share their streams). Adding the pattern on top of the bin
    // (the table drawn at the phase of the PMF as it is, before) read 0.1080 (1.17×), 0.0131 DN²
    // over pixel-only: both bounds fail there.
    assert!(
        (d - p).abs() < 0.004,
        "the default adds {:.4} DN² to pixel-only at black, where the bin holds the pattern already (before: 0.0131)",
        d - p
    );
    assert!(
        (0.95..1.08).contains(&(d / REAL_AT_BLACK)),
        "default / real variance at black {:.3} (the pattern added twice: 1.17)",
        d / REAL_AT_BLACK
    );
    // Like with like for the default: the held-out `noisy − level` (the pattern kept) at the 0 and
    // 0.1 DN exposures, 0.99 / 1.05 now; 1.14 / 1.19 with the pattern added twice.
    for real in REAL_LESS_LEVEL_AT_BLACK {
        assert!(
            (0.95..1.07).contains(&(d / real)),
            "default / real noisy − level at black {:.3} (real {real}; the pattern added twice: 1.14–1.19)",
            d / real
        );
    }
    assert!(
        (0.85..1.15).contains(&(p / REAL_AT_BLACK)),
        "pixel-only / real variance at black {:.3}",
        p / REAL_AT_BLACK
    );
    // Like with like: the real figure is `frame − round(clean)` with a clean image that carries
    // the sensor's pattern, so the sampler it is compared with is the one for such clean images,
    // every component but the pattern (`own`; this pack has no row, column or frame offset, so
    // it draws pixel-only's tables). The fine levels at black drew 0.0863 (0.94×) when bin 0's
    // PMF was rescaled toward the dark frames' 0.18–0.23 DN², which the piecewise-uniform rescale
    // cannot reach at sub-DN noise (it narrowed the bin); the bin's own histogram, kept, draws
    // 0.0956 (1.04×, the plain histogram's 1.04×; `tests/bench/emva1288_black.py`).
    let (o, _) = drawn(&own(&pack), BLACK_CODE, 4);
    eprintln!("at black: own {o:.4} ({:.3}×)", o / REAL_AT_BLACK);
    assert!(
        (0.97..1.1).contains(&(o / REAL_AT_BLACK)),
        "own / real variance at black {:.3} (rescaled: 0.94)",
        o / REAL_AT_BLACK
    );
}

/// The same at the target ISO's brightness (`CleanAt::Target`, `resolve::sampler_for`): the fine
/// levels there are made for the target's levels, and must be drawn as at the reference
/// brightness, pixel-only's tables with the offsets taken out, not made from the deconvolved
/// bins (which drew the wrong order's excess at black).
#[test]
fn at_black_the_default_draws_pixel_only_less_the_offsets_at_the_target_brightness() {
    use noisecal_core::resolve::{ModelKind, sampler_for};
    use noisecal_core::synth::CleanAt;
    let (pack, pattern) = set002();
    let model = pack.iso(pack.isos[0].iso).expect("its ISO");
    let at = |which| sampler_for(&pack, model, ModelKind::Noisecal, which, CleanAt::Target, false).expect("a sampler");
    let (default, pixel) = (at(Components::ALL), at(Components::PIXEL));
    let (d, dm) = drawn(&default, BLACK_CODE, 4);
    let (p, pm) = drawn(&pixel, BLACK_CODE, 4);
    eprintln!(
        "at black, target brightness (gain ratios {:?}): default {d:.4} (mean {dm:+.3}), pixel-only {p:.4} (mean {pm:+.3}), pattern {pattern:.4} DN²",
        model.gain_ratio
    );
    assert!(
        d - p < pattern + 0.03,
        "at the target brightness the default adds {:.4} DN² to pixel-only at black (pattern {pattern:.4})",
        d - p
    );
}
