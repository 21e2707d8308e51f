//! A histogram's sample count, mean and variance, and the smallest variance any PMF is given:
//! what the law, the pooling and the clip flags all read from a bin.

use crate::model::histogram::NoiseHistogram;

/// Smallest variance any PMF is given (DN²): the quantisation of a noiseless pixel.
pub(crate) const MIN_VAR: f64 = 1.0 / 12.0;

/// Sample count, mean and variance of a histogram.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Stat {
    pub(crate) n: u64,
    pub(crate) mean: f64,
    pub(crate) var: f64,
}

impl Stat {
    pub(crate) fn of(h: &NoiseHistogram) -> Self {
        let n = h.total();
        let (mean, var) = h.moments();
        Self { n, mean, var }
    }
}
