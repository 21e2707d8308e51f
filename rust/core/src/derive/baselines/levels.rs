//! A baseline's noise at each clean level, for synthesis: its law read at the level itself, not
//! a bin's average (method.md, *Synthesis*, "Baselines at their level").
//!
//! A baseline's bin PMF ([`Baseline::bin_pmf`]) averages the PMFs of up to
//! [`super::LEVELS_PER_BIN`] levels across the bin, so every level of a bin drew the bin's mean
//! variance: where the law changes across a bin by much (near black on a sensor with a small
//! read noise and wide bins) a level at a bin's edge drew a variance far from its own (HG at
//! 16 DN above black on the EMVA 1288 set 001 CCD: 1.26× the law's there). The sampler of a
//! baseline draws from these tables instead: levels share a table while the law's variance stays
//! within [`LEVEL_STEP`] of the run's first, the table drawn at the run's middle variance; a
//! Poisson–Gaussian level whose lattice shows (read SD below half the gain, exact Poisson sums)
//! has a table of its own (the lattice's phase moves with the level). Tables are not clipped:
//! synthesis clamps to `[0, white]`, which is the clipping of [`Baseline::level_pmf`] at every
//! level of a run (a clipped table would fold at the run's level, not each level's).
//!
//! The bins themselves ([`Baseline::to_model`]) are unchanged: metrics compare bin PMFs.

use rayon::prelude::*;

use crate::derive::fine_levels::FineLevels;
use crate::model::layout::{Binning, reference_level};
use crate::model::pack::BinModel;

use super::pmf::PG_EXACT_MAX_LAMBDA;
use super::{Baseline, BaselineKind};

/// Levels share a table while the law's variance is within this ratio of the run's first
/// (0.5 %: the table at the run's middle is within ±0.25 % of every level's variance).
pub const LEVEL_STEP: f64 = 1.005;

/// A Poisson–Gaussian's lattice (period the gain `a`) shows where the read noise's SD is below
/// this fraction of `a`: the rounded Gaussian then leaves a modulation of
/// `exp(−2π²σ²/a²)` ≥ 0.7 % of the PMF. Below it levels get tables of their own (the lattice's
/// phase moves with the level); above it they share tables as HG's do, which keeps a high-gain
/// sensor with a larger read noise at a few hundred tables rather than one per level.
pub const LATTICE_SHOWS: f64 = 0.5;

impl Baseline {
    /// The level → table map of position `pos` for a sampler's clean levels `0..=white`, each
    /// standing for the reference level `black + (c − black)/gain` (`gain` 1: the reference
    /// brightness; the ISO's gain ratio for clean images at the target brightness, whose noise
    /// a baseline draws at the reference level), and the tables (indexed after the model's
    /// `bins`, as [`FineLevels`] are). `None` when they would pass 16-bit indices.
    pub fn level_tables(&self, binning: &Binning, pos: usize, gain: f64) -> Option<FineLevels> {
        let bins = binning.bins(pos);
        let black = binning.black[pos] as f64;
        let white = binning.white as usize;
        let gain = if gain.is_finite() && gain > 0.0 { gain } else { 1.0 };
        let p = self.params[pos];
        let above = |c: usize| (reference_level(c, black, gain, white as f64) - black).max(0.0);
        let own_table = |x: f64| match self.kind {
            BaselineKind::Pg => {
                let read = (p.b - 1.0 / 12.0).max(0.0);
                p.a > 0.0 && read.sqrt() < LATTICE_SHOWS * p.a && x / p.a <= PG_EXACT_MAX_LAMBDA && x > 0.0
            }
            BaselineKind::Hg | BaselineKind::NoiseProfile => false,
        };
        // Runs of levels: (first level, last level, first variance, own table).
        let mut runs: Vec<(usize, usize, f64, bool)> = Vec::new();
        for c in 0..=white {
            let x = above(c);
            let v = p.variance(x);
            let own = own_table(x);
            match runs.last_mut() {
                Some((_, last, v0, false)) if !own && v <= *v0 * LEVEL_STEP => *last = c,
                _ => runs.push((c, c, v, own)),
            }
        }
        if bins + runs.len() > u16::MAX as usize + 1 {
            return None;
        }
        let mut lut = vec![0u16; white + 1];
        for (i, &(first, last, _, _)) in runs.iter().enumerate() {
            lut[first..=last].fill((bins + i) as u16);
        }
        // A Poisson–Gaussian table is costly and runs are independent (order kept).
        let extra = runs
            .par_iter()
            .map(|&(first, last, v0, own)| {
                // The run's middle variance (geometric), at the level the law reaches it.
                let v_mid = (v0 * p.variance(above(last))).sqrt();
                let x = if own || p.a <= 0.0 { above(first) } else { ((v_mid - p.b) / p.a).max(0.0) };
                BinModel::from_pmf(&self.noise_above(pos, x), 0, true)
            })
            .collect();
        Some(FineLevels { lut, extra })
    }
}
