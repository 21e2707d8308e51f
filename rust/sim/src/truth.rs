//! The known truth of the structured noise components at one ISO: what a calibration
//! of row, column and frame-level noise should recover, and samplers of the true offset laws so
//! that a test can score a calibrated distribution against them (and measure the finite-sample
//! floor of that score by scoring two samples of the truth against each other).

use noisecal_core::POSITIONS;
use rand::Rng;

use crate::model::OffsetShape;
use crate::noise::normal;

/// The structured components of a simulated sensor at one ISO, in **output DN** (the digital
/// gain included), as [`crate::Simulator::capture`] adds them before rounding. From
/// [`crate::Simulator::structured_truth`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StructuredTruth {
    /// The ISO.
    pub iso: u32,
    /// Digital gain at this ISO (1 at or below the highest analog ISO).
    pub digital_gain: f64,
    /// RMS of the row offsets: one per row and frame, shared by the row's two CFA columns.
    pub row_sd_dn: f64,
    /// Law of the row offsets (unit variance before `row_sd_dn`).
    pub row_shape: OffsetShape,
    /// RMS of the per-frame column offsets (column noise; Gaussian).
    pub col_sd_dn: f64,
    /// RMS of the fixed column pattern.
    pub col_pattern_sd_dn: f64,
    /// RMS of the per-frame black-level error of each CFA position.
    pub frame_offset_sd_dn: [f64; POSITIONS],
    /// Law of the frame offsets: `sd · (√shared · s₀ + √(1 − shared) · s_p)` with `s₀` (common to
    /// the frame) and `s_p` (per position) independent unit-variance draws of this shape.
    pub frame_offset_shape: OffsetShape,
    /// Fraction of the frame-offset variance common to the four positions of a frame.
    pub frame_offset_shared: f64,
    /// RMS of the fixed per-pixel dark offsets (DSNU).
    pub dsnu_sd_dn: f64,
}

/// Unit-variance frame-offset draws of the four positions: a common draw, then one per position.
pub(crate) fn frame_offset_units<R: Rng + ?Sized>(shape: OffsetShape, shared: f64, rng: &mut R) -> [f64; POSITIONS] {
    let common = shape.sample_unit(rng);
    let (a, b) = (shared.sqrt(), (1.0 - shared).sqrt());
    std::array::from_fn(|_| a * common + b * shape.sample_unit(rng))
}

impl StructuredTruth {
    /// Whether every structured component is zero (a pixel-independent sensor).
    pub fn is_zero(&self) -> bool {
        self.row_sd_dn == 0.0
            && self.col_sd_dn == 0.0
            && self.col_pattern_sd_dn == 0.0
            && self.frame_offset_sd_dn.iter().all(|&v| v == 0.0)
            && self.dsnu_sd_dn == 0.0
    }

    /// One draw of the true row-offset law (output DN, before rounding).
    pub fn sample_row_offset<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        self.row_sd_dn * self.row_shape.sample_unit(rng)
    }

    /// `n` draws of the true row-offset law.
    pub fn sample_row_offsets<R: Rng + ?Sized>(&self, n: usize, rng: &mut R) -> Vec<f64> {
        (0..n).map(|_| self.sample_row_offset(rng)).collect()
    }

    /// One frame's black-level errors of the four CFA positions (output DN, before rounding),
    /// drawn from the true law (positions correlated by `frame_offset_shared`).
    pub fn sample_frame_offsets<R: Rng + ?Sized>(&self, rng: &mut R) -> [f64; POSITIONS] {
        let u = frame_offset_units(self.frame_offset_shape, self.frame_offset_shared, rng);
        std::array::from_fn(|p| self.frame_offset_sd_dn[p] * u[p])
    }

    /// `n` frames' black-level errors.
    pub fn sample_frame_offsets_n<R: Rng + ?Sized>(&self, n: usize, rng: &mut R) -> Vec<[f64; POSITIONS]> {
        (0..n).map(|_| self.sample_frame_offsets(rng)).collect()
    }

    /// One draw of the per-frame column offset (column noise only, not the fixed pattern).
    pub fn sample_column_offset<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        self.col_sd_dn * normal(rng)
    }

    /// The frame offsets at the ADC (DN, before digital gain), as capture draws them.
    pub(crate) fn sample_frame_offsets_adc<R: Rng + ?Sized>(&self, rng: &mut R) -> [f64; POSITIONS] {
        let u = frame_offset_units(self.frame_offset_shape, self.frame_offset_shared, rng);
        std::array::from_fn(|p| self.frame_offset_sd_dn[p] / self.digital_gain * u[p])
    }
}
