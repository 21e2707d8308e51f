//! The clip rule's thresholds and the fraction of a bin's samples that may have reached the
//! codes the sensor writes at either end (method.md, "Estimation" 1), and the clean levels each
//! bin covers.

use crate::model::histogram::NoiseHistogram;

/// A bin is clipped when more than this fraction of its samples may have reached 0 or white
/// (heavy tails make even 10⁻³ shrink a variance by a few per cent) …
pub const CLIP_FRACTION: f64 = 1e-4;

/// … or when its levels lie within this many standard deviations of 0 or white.
pub const CLIP_SIGMAS: f64 = 4.0;

/// Fraction of a histogram's samples (counts over `first ..`) that may have reached 0 or white
/// for some integer level `lo ..= hi` of the bin: `n ≥ white − hi` or `n ≤ −lo`.
pub fn clip_fraction_of(first: i32, counts: &[u64], lo: i32, hi: i32, white: i32) -> f64 {
    clip_fraction_in(first, counts, lo, hi, 0, white)
}

/// [`clip_fraction_of`] for a sensor clipping at `floor` and `white`.
pub fn clip_fraction_in(first: i32, counts: &[u64], lo: i32, hi: i32, floor: i32, white: i32) -> f64 {
    let total: u64 = counts.iter().sum();
    if total == 0 {
        return 0.0;
    }
    let top = white - hi;
    let bottom = floor - lo;
    let c: u64 = counts
        .iter()
        .enumerate()
        .filter(|(i, _)| {
            let n = first + *i as i32;
            n >= top || n <= bottom
        })
        .map(|(_, &k)| k)
        .sum();
    c as f64 / total as f64
}

pub(super) fn clip_fraction(h: &NoiseHistogram, lo: i32, hi: i32, floor: i32, white: i32) -> f64 {
    clip_fraction_in(h.first, &h.counts, lo, hi, floor, white)
}
