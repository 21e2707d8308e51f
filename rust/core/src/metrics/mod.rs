//! Fidelity metrics (method.md, "Measuring fidelity"; paper §5.1): Jensen–Shannon divergence on
//! integer noise histograms, KL divergence with add-one smoothing (Noise Flow style), and the
//! accumulators that turn (clean, capture) pairs into per-(position, level group) noise samples.
//!
//! Conventions, fixed here so every caller computes the same numbers:
//! - Logarithms are natural, so `0 ≤ JSD ≤ ln 2` ([`JSD_MAX`]).
//! - Noise is `capture − round(clean)` for real data and `synthesized − round(clean)` for
//!   synthetic data, on flat pixels only, with the same clean image for both.
//! - A **level group** is `group_bins` consecutive bins of the pack's binning (counted from the
//!   black level of each CFA position, so group `g` covers the clean levels of bins
//!   `g·group_bins .. (g+1)·group_bins`). [`DEFAULT_GROUP_BINS`] = 8 gives 30 groups on the
//!   paper's 10-bit sensor (32 DN each): coarse enough that a held-out capture fills each group
//!   it touches with thousands of samples, fine enough that a model that is right on average but
//!   wrong per level is caught by the conditional JSD.
//! - The **marginal** JSD of a position pools all its levels; the **conditional** JSD is the
//!   mean over level groups of the per-group JSD, weighted by the real sample count of the
//!   group. A group with real samples but no synthetic samples scores `ln 2`.
//! - The **overall** scores are the means of the per-position scores weighted by real sample
//!   counts (not a JSD of positions pooled together, which would hide a wrong position).
//! - The **finite-sample floor** is [`compare`] applied to two independent real sets of the
//!   same size ([`finite_sample_floor`]); no model can be expected to score below it. Measured
//!   on halves of the real data, it is carried to the sample sizes of the model comparison by
//!   [`floor_scale`] ([`Floor`]).
//! - A model with several synthetic sets (seeds) scores their mean ([`score_seeds`]).
//! - Spatial measures (row and column means, row-offset distribution, frame offsets, noise power
//!   spectra of flat crops) are in [`spatial`], the noise power spectra in [`nps`].

mod line_pixels;
pub mod nps;
pub mod spatial;
#[cfg(test)]
mod tests_line_pixels;

use ndarray::ArrayView2;

use crate::model::histogram::NoiseHistogram;
use crate::model::layout::{Binning, POSITIONS, position};
use crate::model::pmf::Pmf;

/// The largest possible JSD with natural logarithms.
pub const JSD_MAX: f64 = std::f64::consts::LN_2;

/// Bins of the pack per level group by default (see the module docs).
pub const DEFAULT_GROUP_BINS: usize = 8;

/// Jensen–Shannon divergence (natural log) of two distributions given on the **same** grid
/// (`p[i]` and `q[i]` are the same noise value; a shorter slice is padded with zeros). Weights
/// need not be normalised (counts are fine). Two empty (all-zero) inputs give 0; one empty and
/// one non-empty give `ln 2`. The result is clamped to `[0, ln 2]` against rounding.
pub fn jsd(p: &[f64], q: &[f64]) -> f64 {
    let sp: f64 = p.iter().filter(|x| **x > 0.0).sum();
    let sq: f64 = q.iter().filter(|x| **x > 0.0).sum();
    match (sp > 0.0, sq > 0.0) {
        (false, false) => return 0.0,
        (true, false) | (false, true) => return JSD_MAX,
        _ => {}
    }
    let n = p.len().max(q.len());
    let mut acc = 0.0f64;
    for i in 0..n {
        let a = p.get(i).copied().unwrap_or(0.0).max(0.0) / sp;
        let b = q.get(i).copied().unwrap_or(0.0).max(0.0) / sq;
        let m = 0.5 * (a + b);
        if a > 0.0 {
            acc += 0.5 * a * (a / m).ln();
        }
        if b > 0.0 {
            acc += 0.5 * b * (b / m).ln();
        }
    }
    acc.clamp(0.0, JSD_MAX)
}

/// Two weight vectors over `first, first + 1, …` aligned on their common grid: returns
/// `(first, a, b)` with `a` and `b` of equal length covering both supports.
pub fn align(a_first: i32, a: &[f64], b_first: i32, b: &[f64]) -> (i32, Vec<f64>, Vec<f64>) {
    let a_last = a_first as i64 + a.len() as i64 - 1;
    let b_last = b_first as i64 + b.len() as i64 - 1;
    let (first, last) = match (a.is_empty(), b.is_empty()) {
        (true, true) => return (0, Vec::new(), Vec::new()),
        (true, false) => (b_first as i64, b_last),
        (false, true) => (a_first as i64, a_last),
        (false, false) => ((a_first as i64).min(b_first as i64), a_last.max(b_last)),
    };
    let len = (last - first + 1).max(0) as usize;
    let place = |f: i32, w: &[f64]| {
        let mut v = vec![0.0; len];
        let off = (f as i64 - first) as usize;
        v[off..off + w.len()].copy_from_slice(w);
        v
    };
    (first as i32, place(a_first, a), place(b_first, b))
}

/// JSD of two PMFs (aligned on their integer grids).
pub fn jsd_pmf(p: &Pmf, q: &Pmf) -> f64 {
    let (_, a, b) = align(p.first, &p.p, q.first, &q.p);
    jsd(&a, &b)
}

/// JSD of two integer noise histograms (counts, aligned on their grids).
pub fn jsd_hist(a: &NoiseHistogram, b: &NoiseHistogram) -> f64 {
    let (_, x, y) = align(a.first, &counts_f64(a), b.first, &counts_f64(b));
    jsd(&x, &y)
}

fn counts_f64(h: &NoiseHistogram) -> Vec<f64> {
    h.counts.iter().map(|&c| c as f64).collect()
}

/// `KL(p ‖ q)` (natural log) with add-one smoothing, as Noise Flow reports it: both histograms
/// are put on the integer grid spanning the union of their supports, every count (zeros
/// included) is increased by one, each is normalised, and `Σ p ln(p/q)` is returned. `p` is the
/// real noise, `q` the synthetic. Finite for any input; 0 when both are empty.
pub fn kl_add_one(p: &NoiseHistogram, q: &NoiseHistogram) -> f64 {
    let (pt, qt) = (p.trimmed(), q.trimmed());
    let (_, a, b) = align(pt.first, &counts_f64(&pt), qt.first, &counts_f64(&qt));
    if a.is_empty() {
        return 0.0;
    }
    let sa: f64 = a.iter().map(|x| x + 1.0).sum();
    let sb: f64 = b.iter().map(|x| x + 1.0).sum();
    a.iter()
        .zip(&b)
        .map(|(&x, &y)| {
            let pa = (x + 1.0) / sa;
            let pb = (y + 1.0) / sb;
            pa * (pa / pb).ln()
        })
        .sum::<f64>()
        .max(0.0)
}

/// Integer noise samples per (CFA position, level group); see the module docs for groups.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseSamples {
    binning: Binning,
    group_bins: usize,
    groups: [Vec<NoiseHistogram>; POSITIONS],
}

impl NoiseSamples {
    /// An empty accumulator for a pack's binning (`pack.binning()`), with `group_bins` bins per
    /// level group (at least 1; [`DEFAULT_GROUP_BINS`] is the documented default).
    pub fn new(binning: &Binning, group_bins: usize) -> Self {
        let group_bins = group_bins.max(1);
        let groups = std::array::from_fn(|pos| vec![NoiseHistogram::default(); binning.bins(pos).div_ceil(group_bins)]);
        Self { binning: binning.clone(), group_bins, groups }
    }

    pub fn binning(&self) -> &Binning {
        &self.binning
    }

    pub fn group_bins(&self) -> usize {
        self.group_bins
    }

    /// Number of level groups at a position.
    pub fn groups(&self, pos: usize) -> usize {
        self.groups[pos].len()
    }

    /// Level group of a (rounded) clean level at a position.
    pub fn group_of(&self, pos: usize, clean_level: f32) -> usize {
        (self.binning.bin(pos, clean_level) / self.group_bins).min(self.groups[pos].len() - 1)
    }

    /// Clean levels `[lo, hi)` (DN) that a group covers at a position.
    pub fn group_levels(&self, pos: usize, group: usize) -> (f32, f32) {
        let w = self.binning.bin_width as f32 * self.group_bins as f32;
        let lo = self.binning.black[pos] + group as f32 * w;
        (lo, (lo + w).min(self.binning.white as f32 + 1.0))
    }

    /// The histogram of one group.
    pub fn group(&self, pos: usize, group: usize) -> &NoiseHistogram {
        &self.groups[pos][group]
    }

    /// Adds one noise sample `n` whose clean level is `clean_level` (rounded clean, DN).
    #[inline]
    pub fn add(&mut self, pos: usize, clean_level: f32, n: i32) {
        let g = self.group_of(pos, clean_level);
        self.groups[pos][g].add(n);
    }

    /// Adds the noise `noisy − round(clean)` of every pixel of one frame where `mask` is true
    /// (all pixels when `None`). CFA positions follow [`position`] (the pack's phase at (0, 0)).
    /// Returns the number of samples added, or an error naming the mismatched sizes.
    pub fn add_frame(
        &mut self,
        clean: ArrayView2<'_, f32>,
        noisy: ArrayView2<'_, u16>,
        mask: Option<ArrayView2<'_, bool>>,
    ) -> Result<u64, crate::error::ModelError> {
        if clean.dim() != noisy.dim() || mask.is_some_and(|m| m.dim() != clean.dim()) {
            return Err(crate::error::ModelError::Unsupported(format!(
                "noise samples: clean image is {:?}, noisy image {:?}, mask {:?}; they must have the same size (rows, cols)",
                clean.dim(),
                noisy.dim(),
                mask.map(|m| m.dim())
            )));
        }
        let mut added = 0u64;
        for ((y, x), &c) in clean.indexed_iter() {
            if let Some(m) = &mask
                && !m[(y, x)]
            {
                continue;
            }
            let base = c.round();
            let n = noisy[(y, x)] as i32 - base as i32;
            self.add(position(y, x), base, n);
            added += 1;
        }
        Ok(added)
    }

    /// Adds another accumulator's samples (same binning and grouping required).
    pub fn merge(&mut self, other: &NoiseSamples) -> Result<(), crate::error::ModelError> {
        if other.binning != self.binning || other.group_bins != self.group_bins {
            return Err(crate::error::ModelError::Unsupported(
                "noise samples: cannot merge accumulators with different binning or level groups; build both from the same pack".into(),
            ));
        }
        for pos in 0..POSITIONS {
            for (a, b) in self.groups[pos].iter_mut().zip(&other.groups[pos]) {
                a.merge(b);
            }
        }
        Ok(())
    }

    /// All levels of a position pooled.
    pub fn marginal(&self, pos: usize) -> NoiseHistogram {
        let mut h = NoiseHistogram::default();
        for g in &self.groups[pos] {
            h.merge(g);
        }
        h.trimmed()
    }

    /// Samples at a position.
    pub fn total(&self, pos: usize) -> u64 {
        self.groups[pos].iter().map(|g| g.total()).sum()
    }
}

/// The score of one level group of one position.
#[derive(Debug, Clone, PartialEq)]
pub struct GroupScore {
    pub pos: usize,
    pub group: usize,
    /// Clean levels `[lo, hi)` of the group (DN).
    pub levels: (f32, f32),
    pub real_samples: u64,
    pub synth_samples: u64,
    pub jsd: f64,
}

/// Marginal and conditional JSD of synthetic against real noise (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Scores {
    /// Marginal JSD per position (`None` where there are no real samples).
    pub marginal: [Option<f64>; POSITIONS],
    /// Conditional JSD per position (`None` where there are no real samples).
    pub conditional: [Option<f64>; POSITIONS],
    /// Real-sample-weighted mean of the per-position marginal JSDs (0 when nothing was seen).
    pub marginal_overall: f64,
    /// Real-sample-weighted mean of the per-position conditional JSDs.
    pub conditional_overall: f64,
    /// Real samples per position.
    pub samples: [u64; POSITIONS],
    /// Every group that had real samples.
    pub groups: Vec<GroupScore>,
}

/// Scores synthetic noise against real noise (same binning and grouping).
pub fn compare(real: &NoiseSamples, synth: &NoiseSamples) -> Scores {
    let mut marginal = [None; POSITIONS];
    let mut conditional = [None; POSITIONS];
    let mut samples = [0u64; POSITIONS];
    let mut groups = Vec::new();
    for pos in 0..POSITIONS {
        let n = real.total(pos);
        samples[pos] = n;
        if n == 0 {
            continue;
        }
        marginal[pos] = Some(jsd_hist(&real.marginal(pos), &synth.marginal(pos)));
        let mut acc = 0.0;
        for g in 0..real.groups(pos) {
            let r = real.group(pos, g);
            let nr = r.total();
            if nr == 0 {
                continue;
            }
            let s = synth.groups.get(pos).and_then(|v| v.get(g)).cloned().unwrap_or_default();
            let j = jsd_hist(r, &s);
            acc += j * nr as f64;
            groups.push(GroupScore {
                pos,
                group: g,
                levels: real.group_levels(pos, g),
                real_samples: nr,
                synth_samples: s.total(),
                jsd: j,
            });
        }
        conditional[pos] = Some(acc / n as f64);
    }
    let total: u64 = samples.iter().sum();
    let overall = |v: &[Option<f64>; POSITIONS]| {
        if total == 0 {
            return 0.0;
        }
        (0..POSITIONS).filter_map(|p| v[p].map(|x| x * samples[p] as f64)).sum::<f64>() / total as f64
    };
    Scores {
        marginal_overall: overall(&marginal),
        conditional_overall: overall(&conditional),
        marginal,
        conditional,
        samples,
        groups,
    }
}

/// The finite-sample floor: the scores of one real set against another, independent real set
/// of the same size (e.g. even and odd frames of a held-out burst). A model is as good as it can
/// be shown to be when its scores reach this floor.
pub fn finite_sample_floor(real_a: &NoiseSamples, real_b: &NoiseSamples) -> Scores {
    compare(real_a, real_b)
}

/// `KL(real ‖ synthetic)` with add-one smoothing ([`kl_add_one`]) of the marginal histograms per
/// position (`None` where there are no real samples), and their real-sample-weighted mean.
pub fn kl_per_position(real: &NoiseSamples, synth: &NoiseSamples) -> ([Option<f64>; POSITIONS], f64) {
    let mut kl = [None; POSITIONS];
    let mut acc = 0.0;
    let mut total = 0u64;
    for (p, slot) in kl.iter_mut().enumerate() {
        let n = real.total(p);
        if n == 0 {
            continue;
        }
        let v = kl_add_one(&real.marginal(p), &synth.marginal(p));
        *slot = Some(v);
        acc += v * n as f64;
        total += n;
    }
    (kl, if total > 0 { acc / total as f64 } else { 0.0 })
}

/// The mean JSD of one level group over synthetic sets.
#[derive(Debug, Clone, PartialEq)]
pub struct GroupMean {
    pub pos: usize,
    pub group: usize,
    /// Clean levels `[lo, hi)` of the group (DN).
    pub levels: (f32, f32),
    pub real_samples: u64,
    pub jsd: f64,
}

/// The scores of one model against real noise, averaged over its synthetic sets (one per seed):
/// per position, overall, per seed and per level group.
#[derive(Debug, Clone, PartialEq)]
pub struct SeedMean {
    pub marginal: [Option<f64>; POSITIONS],
    pub conditional: [Option<f64>; POSITIONS],
    /// KL with add-one smoothing ([`kl_per_position`]).
    pub kl: [Option<f64>; POSITIONS],
    pub marginal_overall: f64,
    pub conditional_overall: f64,
    pub kl_overall: f64,
    pub per_seed_marginal: Vec<f64>,
    pub per_seed_conditional: Vec<f64>,
    /// Every group with real samples, by position then group.
    pub groups: Vec<GroupMean>,
}

/// Scores every synthetic set against the same real noise ([`compare`], [`kl_per_position`]) and
/// averages them.
pub fn score_seeds(real: &NoiseSamples, synth: &[NoiseSamples]) -> SeedMean {
    let scores: Vec<Scores> = synth.iter().map(|s| compare(real, s)).collect();
    let kls: Vec<([Option<f64>; POSITIONS], f64)> = synth.iter().map(|s| kl_per_position(real, s)).collect();
    let mut groups: std::collections::BTreeMap<(usize, usize), GroupMean> = std::collections::BTreeMap::new();
    for sc in &scores {
        for g in &sc.groups {
            let row = groups.entry((g.pos, g.group)).or_insert(GroupMean {
                pos: g.pos,
                group: g.group,
                levels: g.levels,
                real_samples: g.real_samples,
                jsd: 0.0,
            });
            row.jsd += g.jsd / scores.len() as f64;
        }
    }
    let per_position = |v: Vec<[Option<f64>; POSITIONS]>| -> [Option<f64>; POSITIONS] {
        std::array::from_fn(|p| {
            let xs: Vec<f64> = v.iter().filter_map(|a| a[p]).collect();
            (!xs.is_empty()).then(|| xs.iter().sum::<f64>() / xs.len() as f64)
        })
    };
    let mean = |v: &[f64]| if v.is_empty() { 0.0 } else { v.iter().sum::<f64>() / v.len() as f64 };
    let per_seed_marginal: Vec<f64> = scores.iter().map(|s| s.marginal_overall).collect();
    let per_seed_conditional: Vec<f64> = scores.iter().map(|s| s.conditional_overall).collect();
    SeedMean {
        marginal: per_position(scores.iter().map(|s| s.marginal).collect()),
        conditional: per_position(scores.iter().map(|s| s.conditional).collect()),
        kl: per_position(kls.iter().map(|k| k.0).collect()),
        marginal_overall: mean(&per_seed_marginal),
        conditional_overall: mean(&per_seed_conditional),
        kl_overall: mean(&kls.iter().map(|k| k.1).collect::<Vec<_>>()),
        per_seed_marginal,
        per_seed_conditional,
        groups: groups.into_values().collect(),
    }
}

/// The factor that carries a floor measured on two halves of `samples_a` and `samples_b` real
/// samples to a model comparison of `compared` real against as many synthetic samples. A JSD
/// estimated from finite histograms is biased upwards roughly in proportion to `1/n₁ + 1/n₂`, so
/// the factor is `(1/N + 1/N) / (1/n_a + 1/n_b)` (≈ ½ for halves of the compared set, 1 for
/// two sets of the compared size).
pub fn floor_scale(samples_a: u64, samples_b: u64, compared: u64) -> f64 {
    (2.0 / compared as f64) / (1.0 / samples_a as f64 + 1.0 / samples_b as f64)
}

/// The finite-sample floor of a model comparison: one real set against another, independent
/// one ([`finite_sample_floor`], and KL), with the factor ([`floor_scale`]) that carries it to
/// the comparison's sample sizes. A model at the scaled floor is as close to the real noise as
/// the data can show.
#[derive(Debug, Clone, PartialEq)]
pub struct Floor {
    pub scores: Scores,
    pub kl: [Option<f64>; POSITIONS],
    pub kl_overall: f64,
    pub samples_a: u64,
    pub samples_b: u64,
    pub scale: f64,
}

impl Floor {
    /// The floor of `real_a` against `real_b`, for a comparison of `compared` real samples
    /// against as many synthetic ones. `None` when either set or the comparison is empty.
    pub fn measure(real_a: &NoiseSamples, real_b: &NoiseSamples, compared: u64) -> Option<Floor> {
        let samples_a: u64 = (0..POSITIONS).map(|p| real_a.total(p)).sum();
        let samples_b: u64 = (0..POSITIONS).map(|p| real_b.total(p)).sum();
        if samples_a == 0 || samples_b == 0 || compared == 0 {
            return None;
        }
        let scores = finite_sample_floor(real_a, real_b);
        let (kl, kl_overall) = kl_per_position(real_a, real_b);
        Some(Floor { scores, kl, kl_overall, samples_a, samples_b, scale: floor_scale(samples_a, samples_b, compared) })
    }

    /// The marginal JSD floor at the comparison's sample sizes.
    pub fn marginal_scaled(&self) -> f64 {
        self.scores.marginal_overall * self.scale
    }

    /// The conditional JSD floor at the comparison's sample sizes.
    pub fn conditional_scaled(&self) -> f64 {
        self.scores.conditional_overall * self.scale
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(binning: &Binning, n: usize, spread: i32) -> NoiseSamples {
        let mut s = NoiseSamples::new(binning, DEFAULT_GROUP_BINS);
        for i in 0..n {
            s.add(i % POSITIONS, 200.0, (i as i32 * 7919) % (2 * spread + 1) - spread);
        }
        s
    }

    #[test]
    fn the_floor_is_scaled_to_the_compared_sample_sizes() {
        // Halves of a comparison: about half; two sets of the compared size: exactly one.
        assert_eq!(floor_scale(500, 500, 1000), 0.5);
        for n in [3u64, 10, 4097, 123_457] {
            assert_eq!(floor_scale(n, n, n), 1.0, "n = {n}");
        }
        let binning = Binning { bin_width: 4, black: [64.0; POSITIONS], white: 1023 };
        let (a, b) = (samples(&binning, 4000, 3), samples(&binning, 2000, 4));
        let f = Floor::measure(&a, &b, 3000).expect("floor");
        assert_eq!((f.samples_a, f.samples_b), (4000, 2000));
        assert_eq!(f.scale, (2.0 / 3000.0) / (1.0 / 4000.0 + 1.0 / 2000.0));
        assert!(f.scores.conditional_overall > 0.0);
        assert_eq!(f.conditional_scaled(), f.scores.conditional_overall * f.scale);
        assert_eq!(f.marginal_scaled(), f.scores.marginal_overall * f.scale);
        assert!(Floor::measure(&a, &NoiseSamples::new(&binning, DEFAULT_GROUP_BINS), 3000).is_none());
        assert!(Floor::measure(&a, &b, 0).is_none());
    }

    #[test]
    fn seed_means_average_the_seeds() {
        let binning = Binning { bin_width: 4, black: [64.0; POSITIONS], white: 1023 };
        let real = samples(&binning, 4000, 3);
        let synth = [samples(&binning, 4000, 2), samples(&binning, 4000, 5)];
        let m = score_seeds(&real, &synth);
        let s: Vec<Scores> = synth.iter().map(|x| compare(&real, x)).collect();
        assert_eq!(m.per_seed_conditional, vec![s[0].conditional_overall, s[1].conditional_overall]);
        assert_eq!(m.conditional_overall, (s[0].conditional_overall + s[1].conditional_overall) / 2.0);
        assert_eq!(
            m.marginal[0],
            Some((s[0].marginal[0].expect("marginal") + s[1].marginal[0].expect("marginal")) / 2.0)
        );
        let (k0, k0_all) = kl_per_position(&real, &synth[0]);
        let (k1, k1_all) = kl_per_position(&real, &synth[1]);
        assert_eq!(m.kl_overall, (k0_all + k1_all) / 2.0);
        assert_eq!(m.kl[3], Some((k0[3].expect("kl") + k1[3].expect("kl")) / 2.0));
        assert_eq!(m.groups.len(), s[0].groups.len());
        assert!(m.groups.iter().all(|g| g.real_samples == 1000 && g.jsd > 0.0));
    }
}
