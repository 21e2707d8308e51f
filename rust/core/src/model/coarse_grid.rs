//! Coarse cells for wide PMFs (method.md, "Pack format"): a PMF smooth over `k` DN is kept as the
//! masses of cells `k` DN wide ([`cell_masses`]) and re-expanded to one weight per DN
//! ([`expand`]) by a deterministic, integer-only, mass-preserving linear interpolation: inside a
//! cell the density runs linearly between the mean densities of the cell and each neighbour, and
//! the cell's mass is split along that line exactly (cumulative floor, so the weights sum to the
//! cell's mass on every machine). Each cell keeps its mass, so the mean moves only by how the
//! line places mass inside a cell: it follows the density's slope, which undoes the grouping's
//! bias to second order (measured below 10⁻³ of the variance for `k` up to a quarter of the
//! standard deviation, tested here).
//!
//! The grid starts at the PMF's first cell; a last cell shorter than `k` is padded with empty
//! cells, so the expansion may reach up to `k − 1` DN beyond the PMF.
//!
//! Which bins are kept coarse, and how wide ([`choose_step`]), is decided at calibration on the
//! exact PMF: cells at most a quarter of its standard deviation wide ([`SD_PER_CELL`]), its mean
//! and variance kept as well as the per-DN stored form keeps them, give or take an eighth of their
//! sampling standard errors ([`moment_tolerance`]), and no single DN moved further from its weight
//! than sampling noise allows ([`MAX_CELL_DEVIANCE`]: a pile or a spike is not smeared). Measured on the demo's, the 14-bit phone's and random-family packs, the
//! held-out cross-entropy of the PMFs kept so is lower than the exact ones' (the exact PMF of a
//! wide bin carries its pool's sampling noise at 1 DN; see `rust/core/tests/pack_compact.rs`).
//! The pack file stores the step with the bin; the decision is not repeated at load.

use crate::model::precision::{MIN_SAMPLES, Precision, cut_tails, round_by_diffusion};

/// The cell widths a bin may be kept at besides 1 DN, widest last.
pub const GRID_STEPS: [usize; 7] = [2, 4, 8, 16, 32, 64, 128];

/// The masses of `w` in cells of `k` DN from its first cell (the last one padded with empty
/// cells).
pub fn cell_masses(w: &[u64], k: usize) -> Vec<u64> {
    w.chunks(k.max(1)).map(|c| c.iter().fold(0u64, |a, &x| a.saturating_add(x))).collect()
}

/// The masses of weights `w` over `first ..` in cells of `k` DN whose edges lie at `origin + j·k`
/// (the first cell the one holding `first`, the last padded with empty DN), and the first DN of
/// the first cell.
pub fn cell_masses_at(first: i32, w: &[u64], k: usize, origin: i32) -> (i32, Vec<u64>) {
    let k = k.max(1);
    let lead = (first as i64 - origin as i64).rem_euclid(k as i64) as usize;
    let mut masses = vec![0u64; (lead + w.len()).div_ceil(k)];
    for (i, &x) in w.iter().enumerate() {
        let m = &mut masses[(lead + i) / k];
        *m = m.saturating_add(x);
    }
    (first - lead as i32, masses)
}

/// One weight per DN from cell masses `k` DN wide: each cell's mass split along a line from the
/// density at its left edge (the mean of its own and its left neighbour's, 0 beyond the ends) to
/// the one at its right edge. The weights of each cell sum to its mass exactly.
pub fn expand(masses: &[u64], k: usize) -> Vec<u64> {
    let k = k.max(1);
    let mut out = Vec::with_capacity(masses.len() * k);
    // Only the shape is read from the neighbours, to 40 significant bits (so the products below
    // stay in 128 bits whatever the masses); the mass itself is split exactly.
    let top = masses.iter().copied().max().unwrap_or(0);
    let shift = (64 - top.leading_zeros()).saturating_sub(40);
    let at = |j: usize| masses.get(j).map_or(0u128, |&m| (m >> shift) as u128);
    for (j, &m) in masses.iter().enumerate() {
        let left = j.checked_sub(1).map_or(0, at) + at(j);
        let right = at(j) + at(j + 1);
        // Weight of DN i (0 ≤ i < k) along the line, × 2k: left·(2k − 2i − 1) + right·(2i + 1).
        let shape = |i: usize| {
            let (i, k) = (i as u128, k as u128);
            left * (2 * k - 2 * i - 1) + right * (2 * i + 1)
        };
        let total: u128 = (0..k).map(shape).sum();
        let (mut cum, mut given) = (0u128, 0u64);
        let whole = if total == 0 { k as u128 } else { total };
        for i in 0..k {
            cum += if total == 0 { 1 } else { shape(i) };
            let upto = quotient(m as u128 * cum, whole);
            out.push(upto - given);
            given = upto;
        }
    }
    out
}

/// `⌊n / d⌋` (`d > 0`, the quotient within u64), in u64 where both fit (a 64-bit division
/// where the u128 one is a call to the runtime's routine), exactly as the u128 division.
#[inline]
fn quotient(n: u128, d: u128) -> u64 {
    match (u64::try_from(n), u64::try_from(d)) {
        (Ok(n), Ok(d)) => n / d,
        _ => (n / d) as u64,
    }
}

/// Whether `w` is already a re-expansion at `k` (its length a multiple of `k` and [`expand`] of
/// its own cell masses gives it back), so keeping it at `k` loses nothing.
pub fn is_expansion(w: &[u64], k: usize) -> bool {
    k > 1 && w.len().is_multiple_of(k) && expand(&cell_masses(w, k), k) == w
}

/// Cells are at most the PMF's standard deviation over this wide (a smooth density changes
/// little over a quarter of its SD: the expansion keeps its variance to 10⁻³, tested below).
pub const SD_PER_CELL: f64 = 4.0;

/// The coarse stored form may move the mean and the variance by at most this share of their
/// sampling standard errors (`SD/√N`, `var·√(2/N)`, `N` the bin's samples, at least
/// [`MIN_SAMPLES`]) more than the per-DN stored form does: the share the precision gives a
/// weight's rounding error of its own sampling error ([`crate::model::precision`]).
pub const SE_SHARE: f64 = 1.0 / 8.0;

/// How far the coarse stored form of a bin of `samples` samples may move its mean (as a share of
/// its SD) and its variance (as a share of itself) beyond the per-DN stored form.
pub fn moment_tolerance(samples: u64) -> (f64, f64) {
    let n = samples.max(MIN_SAMPLES) as f64;
    (SE_SHARE / n.sqrt(), SE_SHARE * (2.0 / n).sqrt())
}

/// No DN may differ from its stored form by a Poisson deviance beyond this at the bin's own sample
/// count (at least [`DEVIANCE_MIN_SAMPLES`]): about 6 σ, beyond what noise gives over the 10⁴
/// cells of a wide PMF, where a pile of a tenth of the bin's samples at a clipped end deviates by
/// hundreds.
pub const MAX_CELL_DEVIANCE: f64 = 40.0;

/// The sample count the deviance is taken at for a bin with fewer of its own: the fewest the
/// estimator pools for a bin without samples of its own (its PMF is then a sum of single samples,
/// each a spike at this count; the precision's floor [`MIN_SAMPLES`] would read one sample's spike
/// as a pile).
pub const DEVIANCE_MIN_SAMPLES: u64 = 256;

/// The widest of [`GRID_STEPS`] the exact PMF `w` of a bin of `samples` samples of its own,
/// stored at `precision`, may be kept at, or 1 (kept per DN): its stored form there
/// ([`store_coarse`]) must keep the mean and variance as well as the per-DN stored form does,
/// give or take [`moment_tolerance`], and move no DN by more than [`MAX_CELL_DEVIANCE`].
pub fn choose_step(w: &[u64], samples: u64, precision: Precision) -> usize {
    let t: f64 = w.iter().map(|&c| c as f64).sum();
    if t <= 0.0 {
        return 1;
    }
    let (mean, var) = moments(0, w);
    let sd = var.sqrt();
    let n = samples.max(DEVIANCE_MIN_SAMPLES) as f64;
    let (mut f1, mut w1) = (0i32, w.to_vec());
    crate::model::precision::store_bin(&mut f1, &mut w1, precision);
    let (m1, v1) = moments(f1, &w1);
    let (mean_slack, var_slack) = ((m1 - mean).abs(), (v1 - var).abs());
    let (mean_tol, var_tol) = moment_tolerance(samples);
    for &k in GRID_STEPS.iter().rev().filter(|&&k| k as f64 * SD_PER_CELL <= sd) {
        let (mut fx, mut x) = (0i32, w.to_vec());
        store_coarse(&mut fx, &mut x, k, precision);
        let (mx, vx) = moments(fx, &x);
        if (mx - mean).abs() > mean_tol * sd + mean_slack || (vx - var).abs() > var_tol * var + var_slack {
            continue;
        }
        let tx: f64 = x.iter().map(|&c| c as f64).sum();
        let at = |i: usize| i.checked_sub(fx as usize).and_then(|j| x.get(j)).copied().unwrap_or(0);
        let deviates = w.iter().enumerate().any(|(i, &c)| {
            let (c, l) = (n * c as f64 / t, n * (at(i).max(1)) as f64 / tx);
            let d = if c > 0.0 { 2.0 * (c * (c / l).ln() - (c - l)) } else { 2.0 * l };
            d > MAX_CELL_DEVIANCE
        });
        if !deviates {
            return k;
        }
    }
    1
}

/// Puts a bin's exact weights in their stored form at step `k > 1`: tails cut as a bin kept per
/// DN cuts them ([`cut_tails`]), the cell masses rounded to `precision` by error diffusion
/// ([`round_by_diffusion`]), re-expanded.
pub fn store_coarse(first: &mut i32, counts: &mut Vec<u64>, k: usize, precision: Precision) {
    cut_tails(first, counts);
    let mut masses = cell_masses(counts, k);
    round_by_diffusion(&mut masses, precision);
    *counts = expand(&masses, k);
}

/// The step a bin in its stored form is kept at: the widest at which its weights are a
/// re-expansion of masses `precision` holds, else 1.
pub fn stored_step(w: &[u64], precision: Precision) -> usize {
    GRID_STEPS
        .iter()
        .rev()
        .copied()
        .find(|&k| is_expansion(w, k) && cell_masses(w, k).iter().all(|&m| precision.holds(m)))
        .unwrap_or(1)
}

/// Whether `w` is already in a stored form: a re-expansion of held masses
/// ([`stored_step`] > 1), or every weight held by `precision` with no tail to cut (what
/// [`crate::model::precision::store_bin`] gives). Compacting such a bin again leaves it as it
/// is, whichever step its exact PMF would have been given: an exact PMF is almost never either.
pub fn is_stored(w: &[u64], precision: Precision) -> bool {
    stored_form(w, precision).is_some()
}

/// The step `w` is stored at when it is already in a stored form ([`is_stored`]): its
/// [`stored_step`] when that is a coarse one, 1 for a bin stored per DN; `None` otherwise.
pub fn stored_form(w: &[u64], precision: Precision) -> Option<usize> {
    let k = stored_step(w, precision);
    let per_dn = || {
        w.iter().all(|&c| precision.holds(c))
            && crate::model::precision::measurable_span(w, crate::model::precision::TAIL_BITS)
                .is_some_and(|(lo, hi)| lo == 0 && hi + 1 == w.len())
    };
    (k > 1 || per_dn()).then_some(k)
}

/// Mean and variance of weights over `first ..`.
fn moments(first: i32, w: &[u64]) -> (f64, f64) {
    let (m, v) = crate::model::histogram::moments(0, w.iter().map(|&c| c as f64));
    (m + first as f64, v)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `quotient` is the u128 division on both sides of u64's range: numerators and divisors
    /// just below, at and above 2⁶⁴, and random ones of every width (a quotient taken on the
    /// numerator's low 64 bits alone, or on a truncated divisor, is off wherever they exceed
    /// u64; the test asserts such pairs were compared).
    #[test]
    fn quotient_is_the_u128_division() {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let big = 1u128 << 64;
        let mut wide = 0;
        let mut pairs: Vec<(u128, u128)> =
            vec![(big - 1, 1), (big - 1, big - 1), (big, 2), (big + 1, 3), (big * 5, big), (7, 8), (0, 1)];
        for _ in 0..100_000 {
            let (a, b) = (next() as u128, next() as u128);
            let n = (a << (next() % 64)) | b >> (next() % 64);
            let d = ((next() as u128) >> (next() % 64)).max(1);
            pairs.push((n, d));
        }
        for (n, d) in pairs {
            if n / d > u64::MAX as u128 {
                continue;
            }
            wide += usize::from(n >= big);
            assert_eq!(quotient(n, d) as u128, n / d, "{n} / {d}");
        }
        assert!(wide > 1000, "{wide}");
    }

    /// Weights of a continuous density over unit cells, × 2³⁰.
    fn discretised(n: usize, density: impl Fn(f64) -> f64) -> Vec<u64> {
        let raw: Vec<f64> = (0..n).map(|i| density(i as f64)).collect();
        let t: f64 = raw.iter().sum();
        raw.iter().map(|&x| (x / t * (1u64 << 30) as f64).round() as u64).collect()
    }

    /// Every cell keeps its mass exactly; a re-expansion is recognised as one; the mean moves
    /// by under 10⁻³ SD and the variance by under 10⁻³ (relative) for cells up to a quarter of
    /// the SD wide, on Gaussian, Laplacian and skewed (gamma-like) PMFs; uniform splitting
    /// (what a wrong expansion does) moves the variance by k²/12 of a cell, which fails this
    /// at a quarter of the SD.
    #[test]
    fn expansion_keeps_cell_masses_mean_and_variance() {
        for sd in [16.0f64, 40.0, 300.0] {
            let n = (24.0 * sd) as usize;
            let c = n as f64 / 2.0;
            let shapes: [Box<dyn Fn(f64) -> f64>; 3] = [
                Box::new(move |x: f64| (-(x - c).powi(2) / (2.0 * sd * sd)).exp()),
                Box::new(move |x: f64| (-(x - c).abs() * 2f64.sqrt() / sd).exp()),
                Box::new(move |x: f64| {
                    let y = (x - c + 2.0 * sd) / (sd / 2.0);
                    if y <= 0.0 { 0.0 } else { y.powi(3) * (-y).exp() }
                }),
            ];
            for (s, shape) in shapes.iter().enumerate() {
                let w = discretised(n, shape);
                let (me, ve) = moments(0, &w);
                for &k in GRID_STEPS.iter().filter(|&&k| k as f64 <= sd / 4.0) {
                    let masses = cell_masses(&w, k);
                    let x = expand(&masses, k);
                    assert_eq!(cell_masses(&x, k), masses, "sd {sd} shape {s} k {k}");
                    assert!(is_expansion(&x, k));
                    let (mx, vx) = moments(0, &x);
                    assert!((mx - me).abs() < 1e-3 * ve.sqrt(), "sd {sd} shape {s} k {k}: mean {me} → {mx}");
                    // The Laplacian's cusp is not smooth over a cell: it alone gets 3·10⁻³.
                    let bound = if s == 1 { 3e-3 } else { 1e-3 };
                    assert!((vx / ve - 1.0).abs() < bound, "sd {sd} shape {s} k {k}: variance {ve} → {vx}");
                    if k as f64 >= sd / 4.0 {
                        let uniform: Vec<u64> = masses.iter().flat_map(|&m| vec![m / k as u64; k]).collect();
                        assert!((moments(0, &uniform).1 / ve - 1.0).abs() > bound, "uniform splitting passes");
                    }
                }
            }
        }
    }

    /// Any masses, however large or sparse, expand without overflow to their exact sums.
    #[test]
    fn any_masses_expand_exactly() {
        let cases: [&[u64]; 6] = [
            &[0, 0, 0],
            &[1],
            &[u64::MAX, 1, u64::MAX],
            &[5, 0, 0, 7],
            &[u64::MAX >> 3, 3, 0, 1 << 50],
            &[1, 2, 3, 1 << 40, 17],
        ];
        for masses in cases {
            for k in [1usize, 2, 3, 8, 128] {
                let x = expand(masses, k);
                assert_eq!(x.len(), masses.len() * k);
                assert_eq!(cell_masses(&x, k), masses, "{masses:?} at {k}");
            }
        }
    }
}
