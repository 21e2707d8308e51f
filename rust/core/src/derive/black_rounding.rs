//! The clean image's rounding at black: what a sample `v − round(m)` at black holds besides the
//! frame-to-frame noise, `m` a pixel's clean level (its dark burst's mean), as the pack's PMFs
//! count noise (method.md, *Synthesis*, "Within a bin near black").
//!
//! The sample is `e + r`, `e` the pixel's temporal noise and `r = m − round(m)` its clean
//! level's rounding, so its variance is `T + Var(r)`. Where the clean levels spread over many
//! codes (noise or a pattern of a DN or more) `r` is uniform over a code and `Var(r)` is 1/12,
//! which is all [`crate::derive::fine_levels::variance_at_black`] counted before. On a sensor
//! whose pattern and noise at black are well below a DN the clean levels sit near one place in
//! their code and `Var(r)` is far less: EMVA 1288 set 002 (8 bits, black 2.82–2.92, a 0.12 DN
//! pattern) has 0.01–0.02 DN² where 1/12 said 0.083, so `T + 1/12` read 0.20 DN² at black against
//! the 0.14 a dark frame less its rounded leave-one-out mean measures.
//!
//! Here `m = black + s + p + ε` per position: `black` the layout's black level, `s` the pattern's
//! shading (its grid cells' values), `p` its pixel-to-pixel part (its stored quantile function)
//! and `ε` the burst mean's own sampling noise, normal of variance `T/(n − 1)` (`n` dark frames;
//! the leave-one-out mean of the calibration's bin-0 samples). `r` depends on `m`'s place in its
//! code alone: the pattern's places are counted on [`CELLS`] cells of a code, convolved with `ε`
//! wrapped onto the code, and `Var(r)` read off. For a spread of a DN or more this is 1/12 to
//! within 10⁻⁶ (tested), so only sub-DN sensors see a change.

use crate::model::structure::FixedPattern;

/// Cells a code is counted on (1/512 DN each).
pub const CELLS: usize = 512;

/// Points of the pattern's pixel quantile function read (midpoints of equal shares).
const PATTERN_POINTS: usize = 512;

/// `Var(m − round(m))` at position `pos` over the clean levels `m` of `fpn`'s dark pixels around
/// `black` (module docs), DN².
pub fn rounding_at_black(fpn: &FixedPattern, pos: usize, black: f64) -> f64 {
    let shading: Vec<f64> = match fpn.shading[pos].as_slice() {
        [] => vec![0.0],
        g => g.iter().map(|&v| v as f64).collect(),
    };
    let pixels: Vec<f64> =
        (0..PATTERN_POINTS).map(|i| fpn.pixels[pos].at((i as f64 + 0.5) / PATTERN_POINTS as f64)).collect();
    let places = shading.iter().flat_map(|&s| pixels.iter().map(move |&p| black + s + p));
    let others = fpn.frames.saturating_sub(1).max(1) as f64;
    let t = fpn.temporal_var[pos];
    let sampling = if t.is_finite() && t > 0.0 { t / others } else { 0.0 };
    rounding_variance(places, sampling)
}

/// `Var(r)`, `r = m − round(m)`, for `m` each of `levels` (equally likely) plus a normal of
/// variance `sampling`.
pub fn rounding_variance(levels: impl IntoIterator<Item = f64>, sampling: f64) -> f64 {
    let mut h = vec![0.0f64; CELLS];
    let mut n = 0.0;
    for m in levels {
        if !m.is_finite() {
            continue;
        }
        let r = m - m.round();
        let c = (((r + 0.5) * CELLS as f64) as usize).min(CELLS - 1);
        h[c] += 1.0;
        n += 1.0;
    }
    if n == 0.0 {
        return 1.0 / 12.0;
    }
    let h = wrapped_normal(&h, sampling.max(0.0).sqrt());
    let total: f64 = h.iter().sum();
    let centre = |c: usize| (c as f64 + 0.5) / CELLS as f64 - 0.5;
    let mean = h.iter().enumerate().map(|(c, &w)| w * centre(c)).sum::<f64>() / total;
    // Each cell's mass spread evenly over it adds its width²/12.
    let second = h.iter().enumerate().map(|(c, &w)| w * centre(c).powi(2)).sum::<f64>() / total
        + 1.0 / (12.0 * (CELLS * CELLS) as f64);
    (second - mean * mean).max(0.0)
}

/// `h` (masses on the cells of one code) convolved with a normal of SD `sd` wrapped onto the
/// code.
fn wrapped_normal(h: &[f64], sd: f64) -> Vec<f64> {
    let n = h.len();
    // Below a cell's width the convolution moves nothing the cells can hold.
    if sd * n as f64 <= 0.5 {
        return h.to_vec();
    }
    // The kernel at each circular offset of `d` cells: the normal's density at `d/n + k`, every
    // `k` within its reach (a kernel wider than a code is nearly flat: 9 wraps at SD 1.5 DN).
    let wraps = (6.0 * sd).ceil() as i64 + 1;
    let kernel: Vec<f64> = (0..n)
        .map(|d| {
            let x = d as f64 / n as f64;
            (-wraps..=wraps).map(|k| (-0.5 * ((x + k as f64) / sd).powi(2)).exp()).sum::<f64>()
        })
        .collect();
    let sum: f64 = kernel.iter().sum();
    let mut out = vec![0.0; n];
    for (i, &w) in h.iter().enumerate() {
        if w == 0.0 {
            continue;
        }
        for (j, o) in out.iter_mut().enumerate() {
            *o += w * kernel[(j + n - i) % n] / sum;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A standard normal's quantile at `u` (bisection on a midpoint-rule CDF: tests only).
    fn normal_levels(mu: f64, sd: f64, n: usize) -> Vec<f64> {
        // Equal-mass points of N(mu, sd²) from a fine grid's CDF.
        let grid: Vec<f64> = (0..20_000).map(|i| -8.0 + 16.0 * (i as f64 + 0.5) / 20_000.0).collect();
        let dens: Vec<f64> = grid.iter().map(|z| (-0.5 * z * z).exp()).collect();
        let total: f64 = dens.iter().sum();
        let mut out = Vec::with_capacity(n);
        let (mut acc, mut k) = (0.0, 0);
        for (z, d) in grid.iter().zip(&dens) {
            acc += d / total;
            while k < n && acc >= (k as f64 + 0.5) / n as f64 {
                out.push(mu + sd * z);
                k += 1;
            }
        }
        out
    }

    /// Monte Carlo of `Var(m − round(m))` over `levels` plus a normal of SD `sd` (a fixed
    /// generator: the known truth the cells must give).
    fn monte_carlo(levels: &[f64], sd: f64) -> f64 {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let normal = Normal::new(0.0, sd.max(1e-12)).expect("normal");
        let (mut s1, mut s2, mut n) = (0.0, 0.0, 0.0);
        for _ in 0..40 {
            for &m in levels {
                let x = m + if sd > 0.0 { normal.sample(&mut rng) } else { 0.0 };
                let r = x - x.round();
                s1 += r;
                s2 += r * r;
                n += 1.0;
            }
        }
        s2 / n - (s1 / n).powi(2)
    }

    /// Known truth: the rounding's variance of normal clean levels at several places in their
    /// code and spreads, against a Monte Carlo of the same (within 0.002 DN² or 2 %). A spread of
    /// 0.5 DN or more gives 1/12 to 10⁻⁴ (what `variance_at_black` counted everywhere); a 0.12 DN
    /// pattern 0.13 DN below a code's centre (set 002's black) about the pattern's own variance,
    /// 0.0145, a sixth of 1/12; clean levels on a half code, 0.25.
    #[test]
    fn the_rounding_of_normal_clean_levels() {
        for (mu, pattern, sampling) in [
            (2.87, 0.12, 0.0023),
            (6.3, 0.15, 0.006),
            (0.5, 0.0, 0.001),
            (4.0, 0.05, 0.0),
            (10.2, 0.6, 0.0),
            (3.3, 0.05, 0.3),
        ] {
            let levels = normal_levels(mu, pattern, 4096);
            let got = rounding_variance(levels.iter().copied(), sampling);
            let want = monte_carlo(&levels, sampling.sqrt());
            eprintln!("mean {mu}, pattern {pattern}, sampling {sampling}: {got:.5} (Monte Carlo {want:.5})");
            assert!((got - want).abs() < 0.002 + 0.02 * want, "mean {mu}, pattern {pattern}: {got} against {want}");
            if pattern.powi(2) + sampling >= 0.25 {
                assert!((got - 1.0 / 12.0).abs() < 1e-4, "a spread of 0.5 DN or more: {got}");
            }
        }
        let set002 = rounding_variance(normal_levels(2.87, 0.12, 4096), 0.0023);
        assert!((0.010..0.025).contains(&set002), "set 002's black: {set002}");
    }
}
