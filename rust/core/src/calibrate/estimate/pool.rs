//! Pooling a bin with its neighbours, moved onto it by the noise law (method.md,
//! "Estimation" 4), and the Laplace prior every pool carries.

use crate::calibrate::estimate::law::{LAW_MIN_BINS_MEAN, Law, local_linear};
use crate::calibrate::estimate::stat::{MIN_VAR, Stat};
use crate::model::bin_levels::BinLevels;
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
        self.add_cells(p.first, &p.p, weight);
    }

    /// Adds `weight ×` the cells `cells` starting at value `first`.
    pub(super) fn add_cells(&mut self, first: i32, cells: &[f64], weight: f64) {
        if cells.is_empty() || weight <= 0.0 {
            return;
        }
        if self.w.is_empty() {
            self.first = first;
            self.w = vec![0.0; cells.len()];
        }
        if first < self.first {
            let shift = (self.first - first) as usize;
            let mut v = vec![0.0; shift];
            v.extend_from_slice(&self.w);
            self.w = v;
            self.first = first;
        }
        let need = (first + cells.len() as i32 - self.first) as usize;
        if self.w.len() < need {
            self.w.resize(need, 0.0);
        }
        let off = (first - self.first) as usize;
        for (i, &x) in cells.iter().enumerate() {
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
/// How far (standard errors) a bin's mean may sit from the law's and still be put on it
/// ([`Data::means_on_law`]): a two-sided tail of 7·10⁻⁶, so that over the ~1000 bins of an ISO
/// a bin keeps a mean the law does not follow by chance in about one ISO of 150.
pub const MEAN_LIMIT_SE: f64 = 4.5;

/// … and an unclipped bin no further than this fraction of its noise SD: a bin further off holds structure
/// the law misses (on two sensors of the random family, a κ² inflated by such structure dragged
/// bins onto the law and the pack lost to the plain histogram, 0.0051 against 0.0022).
pub const MEAN_LIMIT_SD: f64 = 0.1;

/// A bin's PMF is moved onto the law's mean only if the move keeps its variance within this
/// share (the bin means on the law, method.md "Estimation" 7): at sub-DN noise the rescale can collapse a PMF over three codes
/// onto one (known truth: `tests_folds.rs`, variance 0.109 → 10⁻⁶).
pub const MOVE_VAR_TOLERANCE: f64 = 0.02;

/// Clipped bins with samples below the unclipped range that [`Data::means_on_law`] needs to fit
/// a reference mean for them.
const MIN_CLIPPED_BINS: usize = 5;

pub(super) struct Data<'a> {
    pub(super) stats: Vec<Stat>,
    pub(super) pmfs: Vec<Option<Pmf>>,
    pub(super) law: Law,
    pub(super) clipped: &'a [bool],
    /// Per bin, the mean its pool is centred on ([`Data::moved`]) and its prior takes: the law's,
    /// or the bin's own where its samples alone put it off the law's and it keeps its mean
    /// ([`Data::means_on_law`]).
    pub(super) centre: Vec<f64>,
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
        let centre = law.mean.clone();
        Self { stats, pmfs, law, clipped, centre }
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
            self.centre = self.law.mean.clone();
        }
        self
    }

    /// The same data with each bin's mean put on the law's where the two differ by no more
    /// than [`MEAN_LIMIT_SE`] standard errors of what a bin mean can show: its own samples'
    /// `var/n`, plus the spread that every bin's mean carries from the bursts that fed it (`κ²`,
    /// the same for every bin of the position). A burst's frames share their frame offsets,
    /// flicker and the reference burst's own offset, so a bin fed by one or two bursts is off
    /// by a few tenths of a DN however many samples it has, and the folds of the
    /// cross-validation (alternate frames of the same bursts) cannot see it. `κ²` is measured
    /// on the unclipped bins (`d`, a bin's distance to the law): the Paule–Mandel estimate,
    /// `Σ d²/(var/n + κ²) = k − 1`. No unclipped bin moves further than
    /// [`MEAN_LIMIT_SD`] of its noise SD. A clipped bin at the floor (its own histogram kept) is compared with the
    /// local-linear fit of the floor's clipped bins' means (up to 16 bins, at least
    /// [`MIN_CLIPPED_BINS`]), since the clamp moves a mean smoothly with the level (a normal law
    /// clamped at the floor missed the demo's ISO 3200 bins by 1–2 DN); clipped bins at the top
    /// keep their means. On the demo's
    /// 10-bit phone at ISO 100 the bins near black sat 0.1–0.3 DN off the law with 10⁵ samples
    /// each (20 SE), alternating in sign from bin to bin, so a ramp came out with steps. A bin
    /// further off than the limit keeps its own mean: a level where the sensor does something
    /// the law does not follow.
    pub(super) fn means_on_law(mut self, levels: &BinLevels) -> Self {
        // A clipped bin at the floor: the local-linear fit of the means of the clipped bins
        // below the unclipped range (the clamp moves a mean smoothly with the level). Clipped
        // bins at the top keep theirs: saturated pixels, and pixels whose reference saturated
        // while the target did not, mix there, and their neighbours are no reference (moving
        // them made the pack lose to the plain histogram by 3.3× on a 10-bit sensor whose full
        // well fills below white).
        let first_unclipped = (0..self.stats.len()).find(|&b| !self.clipped[b]);
        let floor_side = |b: usize| first_unclipped.is_some_and(|f| b < f);
        let bw = if levels.len() > 1 { (levels.center[1] - levels.center[0]).abs().max(1.0) } else { 1.0 };
        let floor_pts: Vec<(f64, f64, f64, f64)> = (0..self.stats.len())
            .filter(|&b| self.clipped[b] && floor_side(b) && self.stats[b].n >= 2)
            .map(|b| (levels.center[b], self.stats[b].n as f64, self.stats[b].mean, self.stats[b].var))
            .collect();
        let reference = |b: usize| -> f64 {
            if !self.clipped[b] {
                self.law.mean[b]
            } else if floor_pts.len() >= MIN_CLIPPED_BINS {
                local_linear(&floor_pts, levels.center[b], bw, LAW_MIN_BINS_MEAN.min(floor_pts.len())).0
            } else {
                self.stats[b].mean
            }
        };
        let dev: Vec<(usize, f64, f64)> = (0..self.stats.len())
            .filter(|&b| self.stats[b].n >= 2 && self.pmfs[b].is_some())
            .filter(|&b| !self.clipped[b] || floor_side(b))
            .map(|b| {
                let s = self.stats[b];
                (b, s.mean - reference(b), s.var / s.n as f64)
            })
            .collect();
        let unclipped: Vec<(f64, f64)> =
            dev.iter().filter(|&&(b, _, _)| !self.clipped[b]).map(|&(_, d, se2)| (d, se2)).collect();
        if unclipped.len() < 3 {
            return self;
        }
        // Paule–Mandel: κ² such that Σ d²/(var/n + κ²) = k − 1 over the k unclipped bins.
        let q = |k2: f64| unclipped.iter().map(|&(d, se2)| d * d / (se2 + k2).max(1e-300)).sum::<f64>();
        let target = (unclipped.len() - 1) as f64;
        let kappa2 = if q(0.0) <= target {
            0.0
        } else {
            let (mut lo, mut hi) = (0.0, unclipped.iter().map(|&(d, _)| d * d).fold(0.0, f64::max));
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if q(mid) > target { lo = mid } else { hi = mid }
            }
            hi
        };
        for &(b, d, se2) in &dev {
            // An unclipped bin whose own samples put its mean off the law's by more than
            // `MEAN_LIMIT_SE` of their own standard error keeps that mean in its pool as well
            // (unless moved onto the law below): at sub-DN noise a level's noise about its
            // rounded clean level has the mean of where the level falls in its code, and
            // neighbours a code apart differ by up to ±0.5 DN, which `κ²` (inflated by that very
            // alternation) cannot tell from burst offsets. Centred on the law's mean, a sparse
            // bin pooled with them took their mean (EMVA set 002, position 1, 2 DN above black:
            // +0.295 DN against its own 168 samples' −0.286).
            if !self.clipped[b] && d.abs() > MEAN_LIMIT_SE * se2.sqrt() {
                self.centre[b] = self.stats[b].mean;
            }
            if d.abs() > MEAN_LIMIT_SE * (se2 + kappa2).sqrt()
                || (!self.clipped[b] && d.abs() > MEAN_LIMIT_SD * self.stats[b].var.sqrt())
                || d.abs() < 1e-3
            {
                continue;
            }
            if let Some(p) = self.pmfs[b].as_ref() {
                let s = self.stats[b];
                let moved = rescaled_keeping_var(p, s.mean - d, s.var, false);
                // Below about 1/6 DN² the unit cells of the rescale are wider than the noise
                // (its Sheppard term leaves almost nothing to scale): a PMF over three codes
                // may come back as one. A move that cannot keep the variance is not made.
                let (_, got) = moved.moments();
                let kept = (got / s.var - 1.0).abs() < MOVE_VAR_TOLERANCE;
                if !kept {
                    continue;
                }
                self.pmfs[b] = Some(moved);
                self.stats[b].mean -= d;
                self.centre[b] = self.law.mean[b];
            }
        }
        self
    }

    /// Moves bin `j`'s PMF onto bin `b` by the law (identity for `j == b`).
    pub(super) fn moved(&self, j: usize, b: usize) -> Option<Pmf> {
        let p = self.pmfs[j].as_ref()?;
        if j == b {
            return Some(p.clone());
        }
        // Centred on `b`'s centre, the law's mean unless `b`'s own samples say otherwise (a
        // sparse neighbour's own mean is mostly sampling noise, which would widen the pool), its
        // spread scaled by the law's variance ratio.
        let s = self.stats[j];
        let target = self.centre[b];
        let ratio = self.law.var[b] / self.law.var[j].max(MIN_VAR);
        if (target - s.mean).abs() < 0.01 && (ratio - 1.0).abs() < 0.002 {
            return Some(p.clone());
        }
        let var = (s.var * ratio).max(MIN_VAR);
        // A bin keeping its own mean is often one at sub-DN noise, where a neighbour moved by
        // a fraction of a code comes back wider (σ 0.3 DN, +0.35 → −0.25 DN: 0.217 → 0.27 DN²
        // uncorrected): the move keeps the mean and variance as the moves onto the law do, and
        // a neighbour whose move cannot keep the variance within `MOVE_VAR_TOLERANCE` is not
        // pooled (σ 0.45 DN, +0.34 → −0.37 DN came back 0.34 against 0.30 DN²).
        if target != self.law.mean[b] {
            let moved = rescaled_keeping_var(p, target, var, true);
            let (_, got) = moved.moments();
            return ((got / var - 1.0).abs() < MOVE_VAR_TOLERANCE).then_some(moved);
        }
        Some(p.rescaled(target, var))
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

/// `p` moved to mean `mu` with variance `var`: a fractional move on the integers changes a narrow
/// PMF's variance a little (3 % at 3.5 DN², more at sub-DN noise), and a few corrections of the
/// target put it back where the cells allow. With `keep_mean` the mean is corrected the same way
/// (at sub-DN noise the cells moved a fraction of a code miss it by up to 0.05 DN).
fn rescaled_keeping_var(p: &Pmf, mu: f64, var: f64, keep_mean: bool) -> Pmf {
    let (mut target, mut at) = (var, mu);
    let mut moved = p.rescaled(at, target);
    for _ in 0..3 {
        let (m, got) = moved.moments();
        let mean_off = keep_mean && (m - mu).abs() >= 1e-3;
        if got.is_nan() || got <= 0.0 || ((got / var - 1.0).abs() < 1e-3 && !mean_off) {
            break;
        }
        target *= var / got;
        if keep_mean {
            at += mu - m;
        }
        moved = p.rescaled(at, target);
    }
    moved
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
