//! Shrinking a bin's pooled PMF toward the law's own Gaussian (method.md, "Estimation" 4): the
//! weights tried, the target PMF, and its mass on a held-out histogram's support.
//!
//! With few frames at a level nothing is left to pool, and the pool keeps the sampling noise of
//! its histogram (about `(K − 1)/(8N)` nats of JSD over `K` cells from `N` samples), which a
//! two-parameter Gaussian does not have. Mixing `(1 − α)·pool + α·Gaussian(law mean, law
//! variance)` trades that noise for the Gaussian's shape error; the cross-validation picks `α`
//! with the pooling, and `α = 0` is among the candidates, so a bin only moves toward the
//! Gaussian where held-out frames say it helps (heavy tails or a second gain keep `α ≈ 0`).

use crate::calibrate::estimate::stat::MIN_VAR;
use crate::math::special::erfc;
use crate::model::histogram::NoiseHistogram;
use crate::model::pmf::Pmf;

/// Weights `α` of the Gaussian tried by the cross-validation. 0 is the pool as it is; 1 is the
/// law's Gaussian alone (the heteroscedastic Gaussian model at that bin).
pub const SHRINK_CANDIDATES: [f64; 6] = [0.0, 0.25, 0.5, 0.75, 0.9, 1.0];

/// The continuous Gaussian's variance whose integer rounding has variance `var` (rounding adds
/// 1/12 DN²), never below a hundredth of a DN².
fn latent_sd(var: f64) -> f64 {
    (var.max(MIN_VAR) - 1.0 / 12.0).max(0.01).sqrt()
}

/// The law's Gaussian at a bin as a PMF over ±9 standard deviations (the mass beyond is below
/// 10⁻¹⁸), cut at `±reach` ([`crate::model::bin_levels::BinLevels::reach`]). Each cell edge's
/// tail mass is computed once (what `math::special::normal_mass` gives cell by cell, with half the `erfc`s),
/// from the nearer tail so that far cells keep their precision.
pub(super) fn gauss_pmf(mu: f64, var: f64, reach: i32) -> Pmf {
    let sd = latent_sd(var);
    let lo = ((mu - 9.0 * sd).floor() as i32 - 1).max(-reach);
    let hi = ((mu + 9.0 * sd).ceil() as i32 + 1).min(reach);
    // Mass beyond an edge on its own side of the mean.
    let tail = |n: f64| {
        let z = (n - mu) / sd;
        (z, 0.5 * erfc(z.abs() / std::f64::consts::SQRT_2))
    };
    let mut below = tail(lo as f64 - 0.5);
    let masses = (lo..=hi).map(|n| {
        let above = tail(n as f64 + 0.5);
        let m = match (below.0 >= 0.0, above.0 >= 0.0) {
            (true, true) => below.1 - above.1,
            (false, false) => above.1 - below.1,
            _ => 1.0 - below.1 - above.1,
        };
        below = above;
        m.max(0.0)
    });
    Pmf::from_weights(lo, masses).unwrap_or(Pmf { first: mu.round() as i32, p: vec![1.0] })
}

/// The mass of `p` (the law's Gaussian, [`gauss_pmf`]) at each value of a held-out histogram's
/// support (0 where it holds no samples).
pub(super) fn gauss_on(held: &NoiseHistogram, p: &Pmf) -> Vec<f64> {
    (0..held.counts.len())
        .map(|i| {
            let n = held.first + i as i32;
            if held.counts[i] > 0 && n >= p.first && n <= p.last() { p.p[(n - p.first) as usize] } else { 0.0 }
        })
        .collect()
}

#[cfg(test)]
mod gauss_tests {
    use super::*;

    /// The rounded Gaussian keeps the law's mean and variance (rounding's 1/12 included) and
    /// stays within the sensor's reach.
    #[test]
    fn gauss_pmf_has_the_law_moments() {
        for (mu, var) in [(0.0, 1.0), (3.7, 42.5), (-12.25, 900.0)] {
            let p = gauss_pmf(mu, var, 1 << 20);
            let (m, v) = p.moments();
            assert!((m - mu).abs() < 1e-3 * var.sqrt().max(1.0), "mu {mu}: {m}");
            assert!((v / var - 1.0).abs() < 2e-3, "var {var}: {v}");
        }
        let wide = gauss_pmf(100.0, 1.4e8, 1024);
        assert!(wide.first >= -1024 && wide.last() <= 1024, "{} ..= {}", wide.first, wide.last());
    }
}
