//! The clip rule's thresholds and the fraction of a bin's samples that may have reached the
//! codes the sensor writes at either end (method.md, "Estimation" 1), and the clean levels each
//! bin covers.

use crate::model::histogram::NoiseHistogram;
use crate::model::layout::Binning;

/// A bin is clipped when more than this fraction of its samples may have reached 0 or white
/// (heavy tails make even 10⁻³ shrink a variance by a few per cent) …
pub const CLIP_FRACTION: f64 = 1e-4;

/// … or when its levels lie within this many standard deviations of 0 or white.
pub const CLIP_SIGMAS: f64 = 4.0;

/// The integer clean levels each bin of one position covers.
#[derive(Debug, Clone, PartialEq)]
pub struct BinLevels {
    /// Lowest and highest integer clean level of each bin.
    pub lo: Vec<i32>,
    pub hi: Vec<i32>,
    /// Centre level (DN) of each bin.
    pub center: Vec<f64>,
    /// The codes the sensor writes: clipped below at `floor`, above from `white` on (where its
    /// output starts to pile up, [`crate::calibrate::codes::output_range`]).
    pub floor: i32,
    pub white: i32,
}

impl BinLevels {
    /// The largest noise value the sensor's codes can show: a sample and its clean level both lie
    /// in `[floor, white]`, so `|n| < reach`.
    pub fn reach(&self) -> i32 {
        (self.white - self.floor).max(1) + 1
    }

    pub fn new(binning: &Binning, pos: usize) -> Self {
        let n = binning.bins(pos);
        let black = binning.black[pos] as f64;
        let w = binning.bin_width as f64;
        let white = binning.white as i32;
        let mut lo = Vec::with_capacity(n);
        let mut hi = Vec::with_capacity(n);
        for b in 0..n {
            // Bin 0 also takes every level below black; those that occur lie within a bin
            // width of it.
            let l = if b == 0 { (black - w).floor().max(0.0) as i32 } else { (black + b as f64 * w).ceil() as i32 };
            let h = if b + 1 == n { white } else { ((black + (b + 1) as f64 * w).ceil() as i32 - 1).min(white) };
            lo.push(l.min(white));
            hi.push(h.max(l.min(white)));
        }
        let center = (0..n).map(|b| binning.center(pos, b) as f64).collect();
        Self { lo, hi, center, floor: 0, white }
    }

    /// The same bins for a sensor that writes only codes `range[0] ..= range[1]`.
    pub fn with_range(mut self, range: [u16; 2]) -> Self {
        self.floor = range[0] as i32;
        self.white = range[1] as i32;
        self
    }

    pub fn len(&self) -> usize {
        self.lo.len()
    }

    pub fn is_empty(&self) -> bool {
        self.lo.is_empty()
    }
}

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
