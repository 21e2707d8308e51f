//! Choosing the pooling, the shrinkage toward the law's Gaussian and the clip mode by held-out
//! likelihood (method.md, "Estimation" 4–6): for every fold, PMFs from the other folds scored on
//! the held-out fold's samples.

use crate::calibrate::estimate::marginal::MarginalFold;
use crate::calibrate::estimate::pool::FILL_MIN_SAMPLES;
use crate::calibrate::estimate::pool::{Acc, Data, laplace_mass, laplace_pmf, pool_bin};
use crate::calibrate::estimate::shrink::{gauss_on, gauss_pmf};
use crate::model::bin_levels::BinLevels;
use crate::model::histogram::NoiseHistogram;
use crate::model::pmf::Pmf;

/// Pooling thresholds `m` (samples) tried by the cross-validation. 0 is the plain per-bin
/// histogram.
pub const POOLING_CANDIDATES: [u64; 9] = [0, 16, 64, 256, 1024, 4096, 16_384, 65_536, 262_144];

/// A bin leaves its position's pooling for another candidate only when its own held-out samples
/// favour that candidate by more than this log-likelihood (a likelihood ratio of e⁴ ≈ 55).
pub const OVERRIDE_NATS: f64 = 4.0;

/// … and only with at least this many held-out samples of its own: a few samples of one pixel
/// share its clean image's error across frames and would vote as one.
pub const OVERRIDE_MIN_HELDOUT: u64 = 200;

/// The Laplace prior's mass at each value of a held-out histogram's support.
fn prior_on(held: &NoiseHistogram, mu: f64, var: f64) -> Vec<f64> {
    (0..held.counts.len())
        .map(|i| if held.counts[i] > 0 { laplace_mass(held.first + i as i32, mu, var) } else { 0.0 })
        .collect()
}

/// Log-likelihood of held-out counts under `(1 − ε)·pool + ε·Laplace(law)`, `ε = 1/(N + 1)`;
/// `prior` from [`prior_on`].
fn loglik(held: &NoiseHistogram, prior: &[f64], acc: &Acc, cum: u64) -> f64 {
    let eps = 1.0 / (cum as f64 + 1.0);
    let scale = if acc.total > 0.0 { (1.0 - eps) / acc.total } else { 0.0 };
    let mut ll = 0.0;
    for (i, &c) in held.counts.iter().enumerate() {
        if c == 0 {
            continue;
        }
        let p = scale * acc.at(held.first + i as i32) + eps * prior[i];
        ll += c as f64 * p.max(1e-300).ln();
    }
    ll
}

/// Adds to `out[a]` the log-likelihood of held-out counts under
/// `(1 − ε)·((1 − α)·pool + α·G) + ε·Laplace(law)` for every `α = shrinks[a]`, `ε = 1/(N + 1)`; `prior` from
/// [`prior_on`], `target` (`G`, the law's Gaussian) from [`gauss_on`]. The pool is read once per
/// held-out value; each weight costs one logarithm per value.
fn loglik_shrunk(
    held: &NoiseHistogram,
    prior: &[f64],
    target: &[f64],
    (acc, cum): (&Acc, u64),
    shrinks: &[f64],
    out: &mut [f64],
) {
    let eps = 1.0 / (cum as f64 + 1.0);
    // As [`loglik`] computes it, so that `α = 0` scores exactly as the pool alone.
    let scale = if acc.total > 0.0 { (1.0 - eps) / acc.total } else { 0.0 };
    for (i, &c) in held.counts.iter().enumerate() {
        if c == 0 {
            continue;
        }
        let pool = scale * acc.at(held.first + i as i32);
        let (g, floor) = ((1.0 - eps) * target[i], eps * prior[i]);
        for (o, &alpha) in out.iter_mut().zip(shrinks) {
            let p = ((1.0 - alpha) * pool + alpha * g) + floor;
            *o += c as f64 * p.max(1e-300).ln();
        }
    }
}

/// Log-likelihood of held-out counts of a clipped bin when the pool is unclipped noise and each
/// pixel's value is clamped to `[0, white]` (integer levels of the bin weighted equally).
fn loglik_clamped(held: &NoiseHistogram, acc: &Acc, cum: u64, prior: &Pmf, lo: i32, hi: i32, range: (i32, i32)) -> f64 {
    let (floor, white) = range;
    let eps = 1.0 / (cum as f64 + 1.0);
    let mut mix = Acc::default();
    if acc.total > 0.0 {
        let p = Pmf { first: acc.first, p: acc.w.iter().map(|w| w / acc.total).collect() };
        mix.add(&p, 1.0 - eps);
    }
    mix.add(prior, eps);
    // CDF over the mixture's support.
    let mut cdf = Vec::with_capacity(mix.w.len());
    let mut s = 0.0;
    for &x in &mix.w {
        s += x;
        cdf.push(s);
    }
    let total = s.max(1e-300);
    let cdf_at = |n: i32| -> f64 {
        // P(N ≤ n)
        let i = n as i64 - mix.first as i64;
        if i < 0 {
            0.0
        } else if i as usize >= cdf.len() {
            1.0
        } else {
            cdf[i as usize] / total
        }
    };
    let levels: Vec<i32> = {
        let count = (hi - lo + 1).max(1) as usize;
        let k = count.min(16);
        (0..k).map(|i| lo + ((i as f64 + 0.5) * count as f64 / k as f64).floor() as i32).collect()
    };
    let mut ll = 0.0;
    for (i, &c) in held.counts.iter().enumerate() {
        if c == 0 {
            continue;
        }
        let n = held.first + i as i32;
        let mut p = 0.0;
        for &l in &levels {
            let (bottom, top) = (floor - l, white - l);
            p += if n < bottom || n > top {
                0.0
            } else if n == bottom && n == top {
                1.0
            } else if n == bottom {
                cdf_at(n)
            } else if n == top {
                1.0 - cdf_at(n - 1)
            } else {
                mix.at(n) / total
            };
        }
        p /= levels.len() as f64;
        ll += c as f64 * p.max(1e-300).ln();
    }
    ll
}

pub(super) struct CvResult {
    /// Held-out log-likelihood per candidate (unclipped bins): pooling `c` with shrinkage `a` at
    /// `c · S + a`, `S` shrinkage weights.
    pub(super) ll: Vec<f64>,
    /// The same scored over all unclipped bins at once ([`MarginalFold`]).
    pub(super) marginal_ll: Vec<f64>,
    /// The same per bin, and each bin's held-out samples.
    pub(super) bin_ll: Vec<Vec<f64>>,
    pub(super) bin_heldout: Vec<u64>,
    pub(super) heldout: u64,
    /// Held-out log-likelihood of clipped bins, own mode and law mode.
    pub(super) clip_ll: Option<[f64; 2]>,
    pub(super) clip_samples: u64,
    /// The same per clipped bin (own mode; law mode per pooling candidate, unshrunk), zero
    /// elsewhere.
    pub(super) clip_bin_own: Vec<f64>,
    pub(super) clip_bin_law: Vec<Vec<f64>>,
}

pub(super) fn cross_validate(
    folds: &[&[NoiseHistogram]],
    total: &[NoiseHistogram],
    clipped: &[bool],
    levels: &BinLevels,
    live: &[usize],
    shrinks: &[f64],
) -> CvResult {
    let nbins = levels.len();
    let (s, candidates) = (shrinks.len(), POOLING_CANDIDATES.len() * shrinks.len());
    let mut bin_ll = vec![vec![0.0; candidates]; nbins];
    let mut marginal_ll = vec![0.0; candidates];
    let mut bin_heldout = vec![0u64; nbins];
    let mut heldout = 0u64;
    // Clipped bins: scored per candidate in both modes, then read at the chosen pooling.
    let mut clip_own = 0.0;
    let mut clip_law = vec![0.0; POOLING_CANDIDATES.len()];
    let mut clip_samples = 0u64;
    let mut clip_scored = false;
    let mut clip_bin_own = vec![0.0; nbins];
    let mut clip_bin_law = vec![vec![0.0; POOLING_CANDIDATES.len()]; nbins];
    for &k in live {
        let train: Vec<NoiseHistogram> = total.iter().zip(folds[k].iter()).map(|(t, f)| subtract(t, f)).collect();
        let data = Data::new(&train, clipped, levels);
        let mut marginal = MarginalFold::new(POOLING_CANDIDATES.len());
        for b in 0..nbins {
            let held = &folds[k][b];
            let nh = held.total();
            if nh == 0 {
                continue;
            }
            let (mu, var) = (data.law.mean[b], data.law.var[b]);
            if clipped[b] {
                clip_samples += nh;
                bin_heldout[b] += nh;
                if data.stats[b].n > 0 {
                    let mut own = 0.0;
                    let prior = prior_on(held, mu, var);
                    pool_bin(&data, b, true, &[0], 0, |_, acc, cum| own = loglik(held, &prior, acc, cum));
                    clip_own += own;
                    clip_bin_own[b] += own;
                    clip_scored = true;
                } else {
                    clip_own = f64::NEG_INFINITY;
                    clip_bin_own[b] = f64::NEG_INFINITY;
                }
                let prior = laplace_pmf(mu, var, levels.reach());
                let bl = &mut clip_bin_law[b];
                pool_bin(&data, b, false, &POOLING_CANDIDATES, FILL_MIN_SAMPLES, |c, acc, cum| {
                    let ll = loglik_clamped(
                        held,
                        acc,
                        cum,
                        &prior,
                        levels.lo[b],
                        levels.hi[b],
                        (levels.floor, levels.white),
                    );
                    clip_law[c] += ll;
                    bl[c] += ll;
                });
                continue;
            }
            heldout += nh;
            bin_heldout[b] += nh;
            let prior = prior_on(held, mu, var);
            // Without a shrinkage to choose, neither the Gaussian nor the all-levels score is needed.
            let shrinking = s > 1;
            let target = if shrinking {
                let (gauss, laplace) = (gauss_pmf(mu, var, levels.reach()), laplace_pmf(mu, var, levels.reach()));
                marginal.add_held(held, &gauss, &laplace, 1.0 / (data.stats[b].n as f64 + 1.0));
                gauss_on(held, &gauss)
            } else {
                vec![0.0; held.counts.len()]
            };
            let bl = &mut bin_ll[b];
            pool_bin(&data, b, false, &POOLING_CANDIDATES, FILL_MIN_SAMPLES, |c, acc, cum| {
                loglik_shrunk(held, &prior, &target, (acc, cum), shrinks, &mut bl[c * s..(c + 1) * s]);
                if shrinking {
                    marginal.add_pool(c, (acc, cum), nh);
                }
            });
        }
        marginal.score(shrinks, &mut marginal_ll);
    }
    let ll: Vec<f64> = (0..candidates).map(|c| bin_ll.iter().map(|b| b[c]).sum()).collect();
    // The clipped bins' law mode is read at the chosen pooling.
    let best = argmax(&ll) / s;
    CvResult {
        ll,
        marginal_ll,
        bin_ll,
        bin_heldout,
        heldout,
        clip_ll: (clip_samples > 0 && clip_scored).then_some([clip_own, clip_law[best]]),
        clip_samples,
        clip_bin_own,
        clip_bin_law,
    }
}

/// `t − f` (counts), `f ⊆ t`.
fn subtract(t: &NoiseHistogram, f: &NoiseHistogram) -> NoiseHistogram {
    if f.total() == 0 {
        return t.clone();
    }
    let mut out = t.clone();
    for (i, &c) in f.counts.iter().enumerate() {
        if c == 0 {
            continue;
        }
        let n = f.first + i as i32;
        let j = (n - out.first) as usize;
        out.counts[j] = out.counts[j].saturating_sub(c);
    }
    out.trimmed()
}

/// The index of the largest value (the first on ties).
pub(super) fn argmax(v: &[f64]) -> usize {
    (0..v.len()).min_by(|&a, &b| v[b].total_cmp(&v[a]).then(a.cmp(&b))).unwrap_or(0)
}
