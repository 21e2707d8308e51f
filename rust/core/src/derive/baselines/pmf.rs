//! Integer-grid PMFs of the parametric models at one clean level: a rounded Gaussian, a
//! Poisson–Gaussian (exact Poisson sums up to λ = 1000), folded onto 0 and white.

use crate::math::special::{ln_gamma, normal_mass};
use crate::model::layout::Binning;
use crate::model::pmf::Pmf;

/// Levels of a bin whose PMFs are averaged into the bin's baseline PMF.
pub const LEVELS_PER_BIN: usize = 8;

/// Poisson means above this use the Gaussian limit in the PG PMF.
pub const PG_EXACT_MAX_LAMBDA: f64 = 1000.0;

/// Up to [`LEVELS_PER_BIN`] integer levels spread evenly over a bin (from the black level up).
pub fn bin_levels(binning: &Binning, pos: usize, bin: usize) -> Vec<i32> {
    let bw = binning.bin_width as f64;
    let black = binning.black[pos] as f64;
    let last_bin = binning.bins(pos) - 1;
    let start = (black + bin as f64 * bw).ceil() as i32;
    let end = if bin >= last_bin { binning.white as i32 } else { (black + (bin + 1) as f64 * bw).ceil() as i32 - 1 };
    if end < start {
        return vec![binning.center(pos, bin).round() as i32];
    }
    let count = (end - start + 1) as usize;
    let k = count.min(LEVELS_PER_BIN);
    (0..k).map(|i| start + (((i as f64 + 0.5) * count as f64 / k as f64).floor() as i32)).collect()
}

/// Mean of PMFs on their common grid.
pub(super) fn average(pmfs: &[Pmf]) -> Pmf {
    let Some(first) = pmfs.iter().map(|p| p.first).min() else {
        return Pmf { first: 0, p: vec![1.0] };
    };
    let last = pmfs.iter().map(|p| p.last()).max().unwrap_or(first);
    let mut acc = vec![0.0; (last - first + 1) as usize];
    for p in pmfs {
        let off = (p.first - first) as usize;
        for (i, &x) in p.p.iter().enumerate() {
            acc[off + i] += x;
        }
    }
    Pmf::from_weights(first, acc).unwrap_or(Pmf { first: 0, p: vec![1.0] })
}

/// Folds the mass of `level + n < 0` onto `n = −level` and of `level + n > white` onto
/// `n = white − level`.
pub(super) fn clip(p: &Pmf, level: i32, white: i32) -> Pmf {
    let lo = -level;
    let hi = white - level;
    if p.first >= lo && p.last() <= hi {
        return p.clone();
    }
    let first = p.first.max(lo).min(hi);
    let last = p.last().min(hi).max(lo);
    let mut out = vec![0.0; (last - first + 1).max(1) as usize];
    for (i, &x) in p.p.iter().enumerate() {
        let n = (p.first + i as i32).clamp(lo, hi).clamp(first, last);
        out[(n - first) as usize] += x;
    }
    Pmf::from_weights(first, out).unwrap_or(Pmf { first, p: vec![1.0] })
}

/// Above this integer variance (DN²) a rounded Gaussian about an integer has the variance
/// `s² + 1/12` to within 10⁻⁸ DN² (Sheppard's correction: the error falls as `exp(−2π²s²)`, and
/// `s ≥ 1.1` here), so [`rounded_gaussian_sd`] takes `√(var − 1/12)` there.
pub const SHEPPARD_FROM: f64 = 1.3;

/// Variance of `round(N(0, sd²))` on the integers (the cells' exact sum).
pub fn rounded_variance(sd: f64) -> f64 {
    let sd = sd.max(1e-12);
    let top = (8.0 * sd + 2.0).ceil() as i32;
    (1..=top).map(|k| 2.0 * (k * k) as f64 * normal_mass((k as f64 - 0.5) / sd, (k as f64 + 0.5) / sd)).sum()
}

/// The SD `s` of the Gaussian whose rounding about an integer level has the integer variance
/// `var` (DN²): `√(var − 1/12)` from [`SHEPPARD_FROM`] up, below it bisection on
/// [`rounded_variance`] (which rises from 0 with `s`). `var − 1/12` alone undershoots there: at
/// 0.15 DN² it gives `s` = 0.26, whose rounding has 0.054 DN² (0.36×), and below 1/12 no noise.
pub fn rounded_gaussian_sd(var: f64) -> f64 {
    if var.is_nan() || var <= 0.0 {
        return 0.0;
    }
    if var >= SHEPPARD_FROM {
        return (var - 1.0 / 12.0).sqrt();
    }
    let (mut lo, mut hi) = (0.0f64, SHEPPARD_FROM.sqrt() + 0.5);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if rounded_variance(mid) < var {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// `round(N(mu, sd²))` on the integer grid.
pub(super) fn gaussian_cells(mu: f64, sd: f64) -> Pmf {
    let mut acc = Vec::new();
    let first = add_gaussian_cells(&mut acc, None, mu, sd, 1.0);
    Pmf::from_weights(first, acc).unwrap_or(Pmf { first: mu.round() as i32, p: vec![1.0] })
}

/// Adds `weight · round(N(mu, sd²))` into `acc` (which starts at `first`, or is created when
/// `first` is `None`); grows as needed and returns the (possibly new) first value.
fn add_gaussian_cells(acc: &mut Vec<f64>, first: Option<i32>, mu: f64, sd: f64, weight: f64) -> i32 {
    let sd = sd.max(1e-6);
    let lo = (mu - 8.0 * sd - 1.0).floor() as i32;
    let hi = (mu + 8.0 * sd + 1.0).ceil() as i32;
    let mut first = first.unwrap_or(lo);
    if acc.is_empty() {
        first = lo;
        acc.resize((hi - lo + 1) as usize, 0.0);
    }
    if lo < first {
        let shift = (first - lo) as usize;
        let mut v = vec![0.0; shift];
        v.extend_from_slice(acc);
        *acc = v;
        first = lo;
    }
    let need = (hi - first + 1) as usize;
    if acc.len() < need {
        acc.resize(need, 0.0);
    }
    let mut prev = (lo as f64 - 0.5 - mu) / sd;
    for n in lo..=hi {
        let next = (n as f64 + 0.5 - mu) / sd;
        acc[(n - first) as usize] += weight * normal_mass(prev, next);
        prev = next;
    }
    first
}

/// Poisson–Gaussian noise (DN) around a level `above` DN over black: gain `gain` DN/e⁻,
/// continuous read variance `read_var`, rounded to integers (no clipping here).
pub(super) fn pg_cells(gain: f64, read_var: f64, above: f64) -> Pmf {
    let sd = read_var.sqrt().max(1e-3);
    if gain <= 0.0 || above <= 0.0 {
        return gaussian_cells(0.0, sd);
    }
    let lambda = above / gain;
    if lambda > PG_EXACT_MAX_LAMBDA {
        return gaussian_cells(0.0, (gain * above + read_var).sqrt());
    }
    let spread = 10.0 * lambda.sqrt() + 10.0;
    let k0 = (lambda - spread).floor().max(0.0) as i64;
    let k1 = (lambda + spread).ceil() as i64;
    let mut acc = Vec::new();
    let mut first: Option<i32> = None;
    for k in k0..=k1 {
        let lp = k as f64 * lambda.ln() - lambda - ln_gamma(k as f64 + 1.0);
        let pk = lp.exp();
        if pk < 1e-15 {
            continue;
        }
        first = Some(add_gaussian_cells(&mut acc, first, gain * (k as f64 - lambda), sd, pk));
    }
    Pmf::from_weights(first.unwrap_or(0), acc).unwrap_or(Pmf { first: 0, p: vec![1.0] })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pg_cells_moments() {
        // gain 2 DN/e, read var 4, 50 e⁻ → variance 2·100 + 4 + 1/12, mean 0, skew 1/√λ.
        let p = pg_cells(2.0, 4.0, 100.0);
        let (m, v) = p.moments();
        assert!(m.abs() < 1e-6, "{m}");
        assert!((v - (204.0 + 1.0 / 12.0)).abs() < 0.05, "{v}");
        // Large gain, no read noise: a lattice every 8 DN.
        let p = pg_cells(8.0, 0.0, 40.0);
        assert!(p.at(0) > 0.1 && p.at(4) < 1e-9 && p.at(8) > 0.1);
    }

    /// Known truth: the rounded Gaussian of `rounded_gaussian_sd(v)` has the integer variance `v`
    /// (its PMF's moments, to 10⁻⁶), from 0.02 DN² (almost all 0 DN) to 50 DN², and the SD is
    /// continuous where Sheppard's rule takes over. Sheppard's `√(v − 1/12)` everywhere (what HG's
    /// tables drew before) gives 0.054 for 0.15 (0.36×) and 0 for 0.05.
    #[test]
    fn rounded_gaussian_has_the_integer_variance_asked() {
        for v in [0.02, 0.05, 0.15, 0.22, 0.5, 1.0, 1.29, 1.3, 2.0, 50.0] {
            let s = rounded_gaussian_sd(v);
            let (m, got) = gaussian_cells(0.0, s).moments();
            assert!(m.abs() < 1e-9 && (got - v).abs() < 1e-6 * v.max(1.0), "{v}: {got}");
        }
        let (_, old) = gaussian_cells(0.0, (0.15f64 - 1.0 / 12.0).sqrt()).moments();
        assert!(old < 0.4 * 0.15, "{old}");
        let below = rounded_gaussian_sd(SHEPPARD_FROM - 1e-9);
        assert!((below - rounded_gaussian_sd(SHEPPARD_FROM)).abs() < 1e-7, "{below}");
        assert_eq!(rounded_gaussian_sd(0.0), 0.0);
    }
}
