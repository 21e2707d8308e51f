//! The weight codes of pack versions 7 and 8 (method.md, "Pack format"): a stored weight's code
//! is its index among the values its bin's [`Precision`] holds, so a code's step is one stored
//! step whatever the precision. Part of both formats' bytes: a change here is a format change.

use crate::error::CodecError;
use crate::model::pack::{IsoModel, PositionModel};
use crate::model::precision::{DERIVED_BITS, Precision, bin_precision};

/// The precision a bin of this model and position is stored with.
pub(super) fn precision_of(m: &IsoModel, p: &PositionModel, samples: u64) -> Precision {
    precision_for(m.is_calibrated(), p.is_estimated(), samples)
}

/// The precision of a bin of `samples` in a calibrated (or derived) model, at an estimated (or
/// plain) position: what the file's fields imply, so it is not stored.
pub(super) fn precision_for(calibrated: bool, estimated: bool, samples: u64) -> Precision {
    if calibrated { bin_precision(estimated, samples) } else { Precision::fixed(DERIVED_BITS) }
}

/// The codes of one precision: the values it holds, numbered in increasing order (0 is 0).
/// `start[L]` is the code of the smallest held value of bit length `L` (`2^(L−1)`), and
/// `start[65]` the number of codes.
pub(super) struct WeightCode {
    precision: Precision,
    start: [u64; 66],
}

impl WeightCode {
    pub(super) fn new(precision: Precision) -> Self {
        let mut start = [0u64; 66];
        start[1] = 1;
        for len in 1..=64u32 {
            let kept = precision.bits(len).min(len);
            start[len as usize + 1] = start[len as usize] + (1u64 << (kept - 1));
        }
        Self { precision, start }
    }

    /// The code of `w`, or `None` when the precision does not hold it.
    pub(super) fn code(&self, w: u64) -> Option<u64> {
        if w == 0 {
            return Some(0);
        }
        let len = 64 - w.leading_zeros();
        let drop = len - self.precision.bits(len).min(len);
        (w & ((1u64 << drop) - 1) == 0).then(|| self.start[len as usize] + (w >> drop) - (1u64 << (len - 1 - drop)))
    }

    /// The codes of a bin's `weights` (of ISO `iso`), or the error that names a weight this
    /// precision does not hold (a pack not in its compacted form).
    pub(super) fn codes(&self, weights: &[u64], iso: u32) -> Result<Vec<u64>, CodecError> {
        weights.iter().map(|&w| self.code(w)).collect::<Option<_>>().ok_or_else(|| CodecError::Encode {
            what: "model pack",
            detail: format!(
                "ISO {iso} holds a weight with more significant bits than its bin keeps: store the pack's compacted form"
            ),
        })
    }

    /// The weight a code names, or `None` beyond the last.
    pub(super) fn weight(&self, c: u64) -> Option<u64> {
        if c == 0 {
            return Some(0);
        }
        let len = self.start.partition_point(|&s| s <= c) - 1;
        if len > 64 {
            return None;
        }
        let len = len as u32;
        let drop = len - self.precision.bits(len).min(len);
        Some(((c - self.start[len as usize]) + (1u64 << (len - 1 - drop))) << drop)
    }

    /// The code of the value this precision stores `w` as (0 stays 0).
    pub(super) fn code_near(&self, w: u64) -> u64 {
        if w == 0 { 0 } else { self.code(self.precision.round(w)).unwrap_or(0) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every held value's code names it back, codes of held values are consecutive in increasing
    /// order, and a value not held has no code; for fixed and sample-driven precisions.
    #[test]
    fn codes_number_the_held_values_in_order() {
        for precision in
            [Precision::fixed(7), Precision::fixed(9), Precision::for_samples(0), Precision::for_samples(1 << 20)]
        {
            let code = WeightCode::new(precision);
            let mut expect = 0u64;
            for w in 0..200_000u64 {
                match code.code(w) {
                    Some(c) => {
                        assert!(precision.holds(w), "{w} coded but not held");
                        assert_eq!(c, expect, "{precision:?}: {w}");
                        assert_eq!(code.weight(c), Some(w));
                        expect += 1;
                    }
                    None => assert!(!precision.holds(w), "{precision:?}: {w} held but has no code"),
                }
            }
            for w in [u64::MAX, 1 << 63, (1 << 40) + (1 << 35), 987_654_321] {
                let q = precision.round(w);
                assert_eq!(code.weight(code.code(q).expect("held")), Some(q));
            }
            assert_eq!(code.weight(code.start[65]), None, "past the last code");
        }
    }
}
