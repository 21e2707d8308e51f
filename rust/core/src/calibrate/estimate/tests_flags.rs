//! The clip flags against known truth near the floor: an 8-bit sensor with 1 DN bins and its
//! black level 2.87 DN above the floor (EMVA 1288 set 002's layout), samples drawn at the
//! levels each bin holds and clamped like the sensor, and the flag compared with the fraction
//! of samples that truly reached the floor.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::clip::clip_fraction;
use super::*;
use crate::model::layout::{Binning, CfaPattern, SensorLayout};

const BLACK: f32 = 2.87;
const WHITE: i32 = 255;
const SAMPLES: usize = 200_000;
/// Share of bin 0's pixels whose clean level lies 0.57 DN below black (level 2: the low tail of
/// the pattern); the rest sit 0.1 DN above it (level 3), like set 002's dimmest lit step.
const BELOW_BLACK: f64 = 0.1;

fn binning() -> Binning {
    let layout = SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [BLACK; 4], white: WHITE as u16 };
    Binning::new(&layout, 1)
}

fn levels() -> BinLevels {
    BinLevels::new(&binning(), 0)
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    // Box–Muller.
    let u: f64 = rng.random::<f64>().max(1e-300);
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

/// Per bin 0 ..= 8: the histogram of `code − round(clean)` with `code = clamp(round(clean + σ·z),
/// 0, white)`, and the fraction of its samples whose code was clamped at 0 (the truth).
fn bins_at(sigma: f64, seed: u64) -> (Vec<NoiseHistogram>, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let lv = levels();
    let binning = binning();
    let mut hists = vec![NoiseHistogram::default(); lv.len()];
    let mut truth = vec![0.0; lv.len()];
    for b in 0..=8usize {
        let mut floored = 0usize;
        for i in 0..SAMPLES {
            let clean = match b {
                0 if (i as f64) < BELOW_BLACK * SAMPLES as f64 => BLACK as f64 - 0.57,
                0 => BLACK as f64 + 0.1,
                _ => BLACK as f64 + b as f64 + 0.5,
            };
            let raw = (clean + sigma * gauss(&mut rng)).round();
            floored += usize::from(raw <= 0.0);
            let code = raw.clamp(0.0, WHITE as f64) as i32;
            let level = clean.round() as i32;
            assert_eq!(b, binning.bin(0, level as f32), "clean {clean} lies in bin {b}");
            hists[b].add(code - level);
        }
        truth[b] = floored as f64 / SAMPLES as f64;
    }
    (hists, truth)
}

#[test]
fn bin_zero_is_flagged_only_where_its_samples_reach_the_floor() {
    let lv = levels();
    assert_eq!((lv.lo[0], lv.lowest_sure(0), lv.hi[0]), (1, 3, 3), "bin 0: levels 1..=3, from black up 3");
    // σ 0.3 DN is set 002 at black (variance 0.09–0.10): no sample comes near the floor, but
    // 5 % fall at −1 DN, which the rule that counts every level down to black − width (level 1)
    // took for "may have reached the floor" (fraction 0.05 ≫ 10⁻⁴: flagged). σ 0.8 DN clamps
    // 10⁻³ of bin 0's samples, σ 1.5 DN 5 %: those must be flagged, and the bins above them
    // wherever their own truth is over the threshold.
    for (k, sigma) in [0.3, 0.45, 0.8, 1.5, 3.0].into_iter().enumerate() {
        let (hists, truth) = bins_at(sigma, 7 + k as u64);
        let flags = clip_flags(&hists, &lv);
        for b in 0..=8usize {
            // Sampling noise: judge only where the truth is clearly on one side of the threshold.
            let clear = truth[b] > 3.0 * CLIP_FRACTION || truth[b] < CLIP_FRACTION / 3.0;
            if clear {
                assert_eq!(
                    flags[b],
                    truth[b] > CLIP_FRACTION,
                    "σ {sigma}: bin {b} truly clamped {:.2e}, flagged {}",
                    truth[b],
                    flags[b]
                );
            }
        }
        if sigma == 0.3 {
            assert!(!flags[0], "σ 0.3: bin 0 holds no sample at the floor");
            // What the old rule scores on the same samples: flagged.
            let old = clip_fraction(&hists[0], lv.lo[0], lv.hi[0], lv.floor, lv.white);
            assert!(old > 10.0 * CLIP_FRACTION, "the old rule's fraction {old:.2e} would flag bin 0");
        }
        if sigma >= 0.8 {
            assert!(flags[0], "σ {sigma}: bin 0 clamps {:.2e} of its samples and must stay flagged", truth[0]);
        }
    }
}

#[test]
fn bins_above_black_keep_their_lowest_level() {
    let lv = levels();
    for b in 1..lv.len() {
        assert_eq!(lv.lowest_sure(b), lv.lo[b], "bin {b}");
    }
    // A black level on a whole code: bin 0's sure levels start at it.
    let layout = SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 4095 };
    let l16 = BinLevels::new(&Binning::new(&layout, 16), 0);
    assert_eq!((l16.lo[0], l16.lowest_sure(0), l16.hi[0]), (48, 64, 79));
    let l0 = BinLevels::new(&Binning::new(&SensorLayout { black: [0.0; 4], ..layout }, 16), 0);
    assert_eq!(l0.lowest_sure(0), 0);
}
