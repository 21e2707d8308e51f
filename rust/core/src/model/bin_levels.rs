//! The integer clean levels each bin of one CFA position covers, and the codes the sensor
//! writes at either end: what the estimator and the clip rules reason about per bin.

use crate::model::layout::Binning;

/// The integer clean levels each bin of one position covers.
#[derive(Debug, Clone, PartialEq)]
pub struct BinLevels {
    /// Lowest and highest integer clean level of each bin.
    pub lo: Vec<i32>,
    pub hi: Vec<i32>,
    /// Centre level (DN) of each bin.
    pub center: Vec<f64>,
    /// The position's black level (DN): bin 0's levels below it occur only where the clean
    /// estimate falls below black ([`BinLevels::lowest_sure`]).
    pub black: f64,
    /// The codes the sensor writes: clipped below at `floor`, above from `white` on (where its
    /// output starts to pile up, the calibration's output range).
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
        Self { lo, hi, center, black, floor: 0, white }
    }

    /// The same bins for a sensor that writes only codes `range[0] ..= range[1]`.
    pub fn with_range(mut self, range: [u16; 2]) -> Self {
        self.floor = range[0] as i32;
        self.white = range[1] as i32;
        self
    }

    /// The lowest integer clean level of bin `b` that surely occurs: `lo` for every bin but
    /// bin 0, whose levels wholly below black (`l + 0.5 ≤ black`) are there only for clean
    /// estimates that fall below black (the low tail of the fixed pattern and of the estimate's
    /// own noise); its levels from black up occur wherever the bin has samples.
    pub fn lowest_sure(&self, b: usize) -> i32 {
        if b == 0 { self.lo[0].max((self.black - 0.5).floor() as i32 + 1).min(self.hi[0]) } else { self.lo[b] }
    }

    pub fn len(&self) -> usize {
        self.lo.len()
    }

    pub fn is_empty(&self) -> bool {
        self.lo.is_empty()
    }
}
