//! The variance law every parametric model shares, `σ² = a·(l − black) + b` per ISO and CFA
//! position (DN²), and its fit on a model's per-bin moments (method.md, "Baselines"). The
//! baselines synthesize from it ([`crate::derive::baselines`]); interpolation predicts read
//! noise and finds conversion-gain switches with it ([`crate::derive::gain_switch`]). Its fit near
//! black ([`dark_law`]) gives the slope a bin's levels follow there ([`crate::derive::fine_levels`]).

use crate::math::fit::nn_poly_fit;
use crate::model::layout::{Binning, POSITIONS};
use crate::model::pack::{IsoModel, NoiseProfile};

/// The variance law of one CFA position: `σ² = a·(l − black) + b` in DN² (`l − black` clamped
/// at 0). For PG, `a` is the gain in DN per electron and `b − 1/12` the read variance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseParams {
    pub a: f64,
    pub b: f64,
}

impl NoiseParams {
    /// Variance (DN²) at `level_above_black` (clamped at 0).
    pub fn variance(&self, level_above_black: f64) -> f64 {
        self.a * level_above_black.max(0.0) + self.b
    }

    /// Read variance referred to the input in electrons², `b / a²` (the shot slope `a` is the
    /// conversion gain in DN/e⁻). Infinite when `a` is 0.
    pub fn input_read_variance(&self) -> f64 {
        if self.a > 0.0 { self.b / (self.a * self.a) } else { f64::INFINITY }
    }
}

/// The statistics of one calibrated bin used by the fits.
#[derive(Debug, Clone, PartialEq)]
pub struct BinStat {
    pub bin: usize,
    /// Centre level of the bin above black (DN).
    pub level_above_black: f64,
    pub mean: f64,
    pub var: f64,
    pub samples: u64,
    pub filled: bool,
    /// Some of the bin's noise reaches 0 or white (its variance is shrunk by clipping).
    pub clipped: bool,
}

/// Per-bin statistics of one position of a model.
pub fn bin_stats(binning: &Binning, model: &IsoModel, pos: usize) -> Vec<BinStat> {
    let bw = binning.bin_width as f64;
    let black = binning.black[pos] as f64;
    let white = binning.white as f64;
    model.positions[pos]
        .bins
        .iter()
        .enumerate()
        .map(|(bin, bm)| {
            // The PMF's moments: for calibrated bins the estimator's (own samples, pooled where
            // held-out frames favoured it), which are steadier than a sparse bin's own moments.
            let (mean, var) = bm.moments();
            let lo_level = black + bin as f64 * bw;
            let hi_level = (lo_level + bw).min(white);
            let clipped = lo_level.round() + bm.quantile(0.001) < 0.5 || hi_level + bm.quantile(0.999) > white - 0.5;
            BinStat {
                bin,
                level_above_black: (bin as f64 + 0.5) * bw,
                mean,
                var,
                samples: bm.samples,
                filled: bm.filled(),
                clipped,
            }
        })
        .collect()
}

/// Fits `σ² = a·(l − black) + b` (non-negative `a`, `b`) to the per-bin variances of one
/// position. Bins whose PMF is clipped at 0 or white are left out; bins with samples of their own
/// are weighted by
/// `samples / σ⁴` (the inverse variance of a sample variance), bins without samples only when
/// fewer than two measured bins remain. Returns `None` when no bin is usable.
pub fn fit_params(binning: &Binning, model: &IsoModel, pos: usize) -> Option<NoiseParams> {
    let stats = bin_stats(binning, model, pos);
    let pick = |allow_filled: bool, allow_clipped: bool| -> Vec<&BinStat> {
        stats
            .iter()
            // A bin stands on data when it has samples of its own; a clipped bin whose PMF the
            // estimator replaced by the unclipped law is usable too (its PMF is not clipped).
            .filter(|s| (allow_filled || s.samples > 0) && (allow_clipped || !s.clipped))
            .filter(|s| s.samples > 0 || allow_filled)
            .collect()
    };
    let mut used = pick(false, false);
    if used.len() < 2 {
        used = pick(true, false);
    }
    if used.len() < 2 {
        used = pick(true, true);
    }
    if used.is_empty() {
        return None;
    }
    let x: Vec<f64> = used.iter().map(|s| s.level_above_black).collect();
    let y: Vec<f64> = used.iter().map(|s| s.var).collect();
    let w: Vec<f64> = used.iter().map(|s| s.samples.max(1) as f64 / s.var.max(1e-3).powi(2)).collect();
    let c = if used.len() >= 2 { nn_poly_fit(&x, &y, &w, 1) } else { vec![y[0], 0.0] };
    Some(NoiseParams { a: c[1], b: c[0] })
}

/// The variance law near black of one position, `σ² = b + a·x` at `x` DN above black, fitted on
/// the variances of the first `count` usable bins (`vars[bin]`, `None` for a bin left out), each
/// read at its centre, with weights `1/σ⁴` (every bin's variance read to the same relative
/// precision). With `at_black` (a measured variance at black), `b` is that and only `a` is
/// fitted; else both, non-negative. `None` with fewer than two usable bins (one with
/// `at_black`).
pub fn dark_law(vars: &[Option<f64>], bin_width: f64, count: usize, at_black: Option<f64>) -> Option<DarkLaw> {
    let used: Vec<(f64, f64)> =
        vars.iter().enumerate().filter_map(|(b, v)| v.map(|v| ((b as f64 + 0.5) * bin_width, v))).take(count).collect();
    if used.len() < 2 - at_black.is_some() as usize {
        return None;
    }
    let w = |v: f64| 1.0 / (v * v);
    if let Some(b) = at_black {
        let num: f64 = used.iter().map(|&(x, v)| w(v) * x * (v - b)).sum();
        let den: f64 = used.iter().map(|&(x, v)| w(v) * x * x).sum();
        return Some(DarkLaw { intercept: b, slope: (num / den).max(0.0) });
    }
    let x: Vec<f64> = used.iter().map(|u| u.0).collect();
    let y: Vec<f64> = used.iter().map(|u| u.1).collect();
    let wt: Vec<f64> = y.iter().map(|&v| w(v)).collect();
    let c = nn_poly_fit(&x, &y, &wt, 1);
    Some(DarkLaw { intercept: c[0], slope: c[1] })
}

/// The variance law near black fitted by [`dark_law`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DarkLaw {
    /// Variance at black (DN²).
    pub intercept: f64,
    /// Variance per DN above black.
    pub slope: f64,
}

impl DarkLaw {
    /// Variance (DN²) at `x` DN above black.
    pub fn variance(&self, x: f64) -> f64 {
        self.intercept + self.slope * x.max(0.0)
    }
}

/// HG parameters of every position of a model (positions without usable bins get `a = 0` and
/// `b` = the mean variance of their bins).
pub fn fit_all(binning: &Binning, model: &IsoModel) -> [NoiseParams; POSITIONS] {
    std::array::from_fn(|pos| {
        fit_params(binning, model, pos).unwrap_or_else(|| {
            let st = bin_stats(binning, model, pos);
            let b = st.iter().map(|s| s.var).sum::<f64>() / st.len().max(1) as f64;
            NoiseParams { a: 0.0, b }
        })
    })
}

/// The NoiseProfile `[[S, O]; 4]` of a model as variance laws in DN.
pub fn profile_params(binning: &Binning, profile: &NoiseProfile) -> [NoiseParams; POSITIONS] {
    std::array::from_fn(|pos| {
        let range = (binning.white as f64 - binning.black[pos] as f64).max(1.0);
        NoiseParams { a: profile.scale(pos) * range, b: profile.offset(pos) * range * range }
    })
}
