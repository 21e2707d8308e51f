//! Pooling a bin with its neighbours, moved onto it by the noise law (method.md,
//! "Estimation" 4), and the Laplace prior every pool carries.

use crate::calibrate::estimate::clip::BinLevels;
use crate::calibrate::estimate::law::Law;
use crate::calibrate::estimate::{MIN_VAR, Stat};
use crate::model::histogram::NoiseHistogram;
use crate::model::pmf::Pmf;

/// Neighbours farther than this (bins) are pooled only to reach a bin's first samples.
pub const MAX_RADIUS: usize = 32;

/// Bins without samples of their own, far from data, pool at least this many samples.
pub const FILL_MIN_SAMPLES: u64 = 256;

/// A growing weighted PMF on the integer grid.
#[derive(Debug, Clone, Default)]
pub(super) struct Acc {
    pub(super) first: i32,
    pub(super) w: Vec<f64>,
    pub(super) total: f64,
}

impl Acc {
    pub(super) fn add(&mut self, p: &Pmf, weight: f64) {
        if p.p.is_empty() || weight <= 0.0 {
            return;
        }
        if self.w.is_empty() {
            self.first = p.first;
            self.w = vec![0.0; p.p.len()];
        }
        if p.first < self.first {
            let shift = (self.first - p.first) as usize;
            let mut v = vec![0.0; shift];
            v.extend_from_slice(&self.w);
            self.w = v;
            self.first = p.first;
        }
        let need = (p.last() - self.first + 1) as usize;
        if self.w.len() < need {
            self.w.resize(need, 0.0);
        }
        let off = (p.first - self.first) as usize;
        for (i, &x) in p.p.iter().enumerate() {
            self.w[off + i] += weight * x;
        }
        self.total += weight;
    }

    pub(super) fn at(&self, n: i32) -> f64 {
        let i = n as i64 - self.first as i64;
        if i < 0 || i as usize >= self.w.len() { 0.0 } else { self.w[i as usize] }
    }
}

/// The CDF of the Laplace law with mean `mu` and variance `var`.
fn laplace_cdf(mu: f64, var: f64) -> impl Fn(f64) -> f64 {
    let s = (var.max(MIN_VAR) / 2.0).sqrt();
    move |x: f64| {
        let z = (x - mu) / s;
        if z < 0.0 { 0.5 * z.exp() } else { 1.0 - 0.5 * (-z).exp() }
    }
}

/// Discretised Laplace law with mean `mu` and variance `var`: `P(n)`.
pub(super) fn laplace_mass(n: i32, mu: f64, var: f64) -> f64 {
    let cdf = laplace_cdf(mu, var);
    (cdf(n as f64 + 0.5) - cdf(n as f64 - 0.5)).max(0.0)
}

/// The Laplace prior as a PMF over ±12 standard deviations (the mass beyond is below 10⁻⁷),
/// cut at `±reach` ([`BinLevels::reach`]; the sensor's codes show only `|n| < reach`):
/// a damaged capture's law can be as wide as the range, and ±12 of its SDs were 280 000 cells a
/// bin.
pub(super) fn laplace_pmf(mu: f64, var: f64, reach: i32) -> Pmf {
    let sd = var.max(MIN_VAR).sqrt();
    let lo = ((mu - 12.0 * sd).floor() as i32 - 1).max(-reach);
    let hi = ((mu + 12.0 * sd).ceil() as i32 + 1).min(reach);
    // Each cell edge's CDF once (what `laplace_mass` gives cell by cell, with half the `exp`s).
    let cdf = laplace_cdf(mu, var);
    let mut below = cdf(lo as f64 - 0.5);
    let masses = (lo..=hi).map(|n| {
        let above = cdf(n as f64 + 0.5);
        let m = (above - below).max(0.0);
        below = above;
        m
    });
    Pmf::from_weights(lo, masses).unwrap_or(Pmf { first: mu.round() as i32, p: vec![1.0] })
}

/// Everything the pooling needs about one data set (all samples, or the training folds).
pub(super) struct Data<'a> {
    pub(super) stats: Vec<Stat>,
    pub(super) pmfs: Vec<Option<Pmf>>,
    pub(super) law: Law,
    pub(super) clipped: &'a [bool],
}

impl<'a> Data<'a> {
    pub(super) fn new(hists: &'a [NoiseHistogram], clipped: &'a [bool], levels: &BinLevels) -> Self {
        let stats: Vec<Stat> = hists.iter().map(Stat::of).collect();
        let pmfs = hists
            .iter()
            .map(|h| {
                let t = h.trimmed();
                Pmf::from_weights(t.first, t.counts.iter().map(|&c| c as f64))
            })
            .collect();
        let law = Law::fit(&stats, clipped, levels);
        Self { stats, pmfs, law, clipped }
    }

    /// The same data with the clean image's selection undone in every unclipped bin: its mean
    /// less the shift, its variance plus what the error lost (`select[b]` = (shift, variance to
    /// add)), and the law refitted. Clipped bins keep theirs: their shape near the clip is tied
    /// to their own levels.
    pub(super) fn deselected(mut self, select: &[(f64, f64)], levels: &BinLevels) -> Self {
        let mut moved = false;
        for (b, &(d, add)) in select.iter().enumerate() {
            if (d.abs() < 0.01 && add.abs() < 0.01) || self.clipped[b] {
                continue;
            }
            if let Some(p) = self.pmfs[b].as_ref() {
                let s = self.stats[b];
                // The error cannot have hidden more spread than the samples show unless the
                // pixels did not vary at all (a saturated reference and target): leave those.
                if add > 0.5 * s.var {
                    continue;
                }
                let var = (s.var + add).max(MIN_VAR);
                self.pmfs[b] = Some(p.rescaled(s.mean - d, var));
                self.stats[b].mean -= d;
                self.stats[b].var = var;
                moved = true;
            }
        }
        if moved {
            self.law = Law::fit(&self.stats, self.clipped, levels);
        }
        self
    }

    /// Moves bin `j`'s PMF onto bin `b` by the law (identity for `j == b`).
    pub(super) fn moved(&self, j: usize, b: usize) -> Option<Pmf> {
        let p = self.pmfs[j].as_ref()?;
        if j == b {
            return Some(p.clone());
        }
        // Centred on the law's mean at `b` (a sparse neighbour's own mean is mostly sampling
        // noise, which would widen the pool), its spread scaled by the law's variance ratio.
        let s = self.stats[j];
        let target = self.law.mean[b];
        let ratio = self.law.var[b] / self.law.var[j].max(MIN_VAR);
        if (target - s.mean).abs() < 0.01 && (ratio - 1.0).abs() < 0.002 {
            return Some(p.clone());
        }
        Some(p.rescaled(target, (s.var * ratio).max(MIN_VAR)))
    }

    /// Rings of pooling partners of bin `b`, nearest first: unclipped bins with samples. A
    /// clipped bin in own mode pools only itself.
    pub(super) fn rings(&self, b: usize, own_only: bool) -> Vec<Vec<usize>> {
        let nb = self.stats.len();
        let usable = |j: usize| self.stats[j].n > 0 && !self.clipped[j];
        if own_only {
            return if self.stats[b].n > 0 { vec![vec![b]] } else { Vec::new() };
        }
        let mut rings = Vec::new();
        if usable(b) {
            rings.push(vec![b]);
        }
        for d in 1..nb {
            let mut ring = Vec::with_capacity(2);
            if b >= d && usable(b - d) {
                ring.push(b - d);
            }
            if b + d < nb && usable(b + d) {
                ring.push(b + d);
            }
            if !ring.is_empty() {
                rings.push(ring);
            }
            if b < d && b + d >= nb {
                break;
            }
        }
        rings
    }
}

/// Pools bin `b` ring by ring and calls `visit(k, pool, pool_samples)` once for each threshold
/// `thresholds[k]` (ascending), as soon as the pool holds that many samples (or when no more
/// partners are left). A bin without samples of its own pools at least `fill_min`.
pub(super) fn pool_bin(
    data: &Data<'_>,
    b: usize,
    own_only: bool,
    thresholds: &[u64],
    fill_min: u64,
    mut visit: impl FnMut(usize, &Acc, u64),
) {
    let own_empty = data.stats[b].n == 0;
    let need = |k: usize| if own_empty { thresholds[k].max(fill_min) } else { thresholds[k] };
    let mut acc = Acc::default();
    let mut cum = 0u64;
    let mut k = 0usize;
    for ring in data.rings(b, own_only) {
        let dist = ring.iter().map(|&j| j.abs_diff(b)).max().unwrap_or(0);
        // Far rings only to reach a first sample (and `fill_min` for an empty bin).
        let short = cum == 0 || (own_empty && cum < fill_min);
        if dist > MAX_RADIUS && !short {
            break;
        }
        for &j in &ring {
            if let Some(p) = data.moved(j, b) {
                let n = data.stats[j].n;
                acc.add(&p, n as f64);
                cum += n;
            }
        }
        while k < thresholds.len() && cum > 0 && cum >= need(k) {
            visit(k, &acc, cum);
            k += 1;
        }
        if k == thresholds.len() {
            return;
        }
    }
    while k < thresholds.len() {
        visit(k, &acc, cum);
        k += 1;
    }
}

#[cfg(test)]
mod laplace_tests {
    use super::*;

    /// The PMF's cells are `laplace_mass`'s, bit for bit, and its support stays within the
    /// sensor's reach however wide the law.
    #[test]
    fn laplace_pmf_is_the_cell_masses_within_reach() {
        for (mu, var) in [(0.0, 1.0), (3.7, 42.5), (-12.25, 900.0), (0.5, 1e-6)] {
            let p = laplace_pmf(mu, var, 1 << 20);
            for (i, &x) in p.p.iter().enumerate() {
                let n = p.first + i as i32;
                let t: f64 = (p.first..=p.last()).map(|k| laplace_mass(k, mu, var)).sum();
                assert_eq!(x.to_bits(), (laplace_mass(n, mu, var) / t).to_bits(), "mu {mu} var {var} n {n}");
            }
        }
        let wide = laplace_pmf(100.0, 1.4e8, 1024);
        assert!(wide.first >= -1024 && wide.last() <= 1024, "{} ..= {}", wide.first, wide.last());
    }
}
