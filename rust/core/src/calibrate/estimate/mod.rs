//! Per-bin noise PMFs from the session's histograms, with every smoothing choice made by
//! held-out likelihood (method.md, "Estimation").
//!
//! The session keeps the samples of each (ISO, CFA position, bin) in [`FOLDS`] histograms: the
//! target frames of an ISO take turns (frame `i` goes to fold `i mod FOLDS`). Per ISO and
//! position this module:
//!
//! 1. **Flags clipped bins**: a bin is clipped when more than [`CLIP_FRACTION`] of its samples
//!    could have reached the codes the sensor writes at either end (the output range: the
//!    black clamp below, the start of the full-well pile-up above), or, for a bin with fewer
//!    than 10⁴ samples, when its levels lie within [`CLIP_SIGMAS`] standard deviations of
//!    either end. Clipped bins never inform anything about unclipped ones.
//! 2. **Fits the noise law**: the mean and variance of the noise against the clean level, by
//!    local-linear regression over the measured, unclipped bins ([`Law`]; windows of at least
//!    8192 samples and 4 bins for the variance, 16 bins for the mean, bridging unmeasured
//!    gaps). Outside the measured range the law follows the trend of the nearest half of the
//!    measured range, the variance never decreasing towards white. Before anything is fitted
//!    or pooled, each bin's samples are corrected for the clean image's selection (the Tweedie
//!    shift and the variance it hides, [`crate::calibrate::deselect`]).
//! 3. **Pools**: bin `b`'s PMF is the sum of its own histogram and of its nearest unclipped
//!    neighbours' histograms, taken ring by ring (both sides at the same distance together)
//!    until the pool holds at least `m` samples; each neighbour `j` is moved onto `b` by the law
//!    (mean shifted by `μ(b) − μ(j)`, or onto `b`'s own mean where its samples alone put it off
//!    the law, variance scaled by `v(b)/v(j)`, its own shape kept). With
//!    `m = 0` a bin is its own histogram, and an empty bin takes its nearest measured ring: the
//!    plain empirical estimator. To the pool is added one pseudo-sample spread as a discretised
//!    Laplace law with the law's mean and variance (weight `1/(N+1)` of an `N`-sample pool), so
//!    that no value has probability zero.
//! 4. **Chooses `m`** among [`POOLING_CANDIDATES`] by cross-validation: for every fold, PMFs are
//!    built from the other folds and scored by the log-likelihood of the held-out fold's
//!    samples; the `m` with the highest total wins. Because `m = 0` is among the candidates, the
//!    pack only smooths where held-out frames say smoothing helps.
//! 5. **Chooses the clip mode per bin**: a clipped bin takes the unclipped noise the law
//!    predicts there, pooled from the nearest unclipped bins, and lets synthesis clip (`clean +
//!    n` clamped to the output range, [`ClipMode::Law`]), unless its own held-out samples favour
//!    its own histogram ([`ClipMode::Own`]) by more than [`OVERRIDE_NATS`] with at least
//!    [`OVERRIDE_MIN_HELDOUT`] of them (the law mode is scored with the clipping applied at each
//!    integer level of the bin). Saturated pixels at white, whose noise is nearly zero, keep
//!    their own; the sparse bins below them follow the law smoothly.
//! 6. **Overrides per bin**: a bin whose own histogram beats the chosen pooling on its held-out
//!    samples by more than [`OVERRIDE_NATS`] (with at least [`OVERRIDE_MIN_HELDOUT`] of them)
//!    keeps its own histogram, so no smoothing step loses to the raw histogram it smooths.
//!
//! Everything is deterministic: sequential floating point per (ISO, position), no randomness.

mod clip;
mod cv;
mod flags;
mod law;
mod marginal;
mod pool;
mod shrink;
mod stat;

use serde::{Deserialize, Serialize};

pub use crate::model::bin_levels::BinLevels;
pub use crate::model::estimate_report::{CandidateScore, Choice, ClipMode, EstimateReport};
pub use clip::{CLIP_FRACTION, CLIP_SIGMAS, clip_fraction_in, clip_fraction_of};
pub use cv::{OVERRIDE_MIN_HELDOUT, OVERRIDE_NATS, POOLING_CANDIDATES};
pub use law::Law;
pub use pool::{FILL_MIN_SAMPLES, MAX_RADIUS, MEAN_LIMIT_SD, MEAN_LIMIT_SE, MOVE_VAR_TOLERANCE};
pub use shrink::SHRINK_CANDIDATES;

use crate::model::histogram::NoiseHistogram;
use crate::model::pack::{BinModel, BinSource};
use crate::model::pmf::Pmf;
use cv::{argmax, cross_validate};
use flags::clip_flags;
use pool::{Acc, Data, laplace_pmf, pool_bin};
use shrink::gauss_pmf;
use stat::{MIN_VAR, Stat};

/// Folds of the cross-validation: target frames of an ISO take turns.
pub const FOLDS: usize = 4;

/// Pooling used when the data cannot cross-validate (fewer than two folds hold samples).
pub const DEFAULT_POOLING: u64 = 1024;

/// How the pooling threshold is set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Pooling {
    /// Chosen by cross-validation among [`POOLING_CANDIDATES`].
    Auto,
    /// A fixed threshold (user override).
    Fixed(u64),
    /// The plain per-bin histogram, the nearest bin with samples for empty bins: no law, no
    /// pooling, no prior ([`plain_empirical`]), for comparisons.
    Plain,
}

/// The result for one (ISO, position).
#[derive(Debug, Clone, PartialEq)]
pub struct PositionEstimate {
    pub bins: Vec<BinModel>,
    pub report: EstimateReport,
    /// The weight of the law's Gaussian chosen for the position's unclipped bins
    /// ([`SHRINK_CANDIDATES`]; 0 unless cross-validated). Bins whose own held-out samples
    /// decided otherwise keep their own.
    pub shrink: f64,
}

/// Estimates the bins of one (ISO, position) from its fold histograms (`folds[k][bin]`) and the
/// clean image's selection summed over each fold's samples (`shifts[k][bin]` = `[Σδ, Σδ², Σa]`,
/// [`crate::calibrate::deselect`]; empty slices for none). The pooling is chosen on the samples as
/// measured; the PMFs are built from samples with the selection undone.
pub fn estimate_position(
    folds: &[&[NoiseHistogram]],
    shifts: &[&[[f64; 3]]],
    levels: &BinLevels,
    pooling: Pooling,
) -> PositionEstimate {
    // Shrinkage stays off by default: on the random sensor family it made pack / plain worse
    // (median 0.917 → 0.925, worst 1.003 → 1.011) while tying the heteroscedastic Gaussian on the
    // EMVA burst (method.md, "Estimation" 4).
    estimate_position_among(folds, shifts, levels, pooling, &[0.0])
}

/// Below this variance (DN²) the noise at black is shaped by the lattice: a sample is
/// `round(c + e) − round(c)`, whose spread depends on where the clean levels `c` sit in their
/// codes by an amount of order `exp(−2π²σ²)` of it (0.7 % at 0.25 DN², 17 % at 0.09). Black's
/// level sits where the sensor's black offset puts it, which tells nothing about other levels.
pub const LATTICE_BOUND_VAR: f64 = 0.25;

/// [`estimate_position`] with the noise the ISO's dark frames measure at black
/// ([`crate::calibrate::dark::DarkBurst::black_noise`]; `None` without a dark step). Where bin 0
/// (black's) holds fewer lit samples than [`OVERRIDE_MIN_HELDOUT`] (a session whose darkest
/// step is all dark frames) and the dark frames reach no end of the output range there, bin 0
/// stands on the dark frames' samples instead of its neighbours' noise moved there by the
/// law's extrapolation (method.md, "Estimation" 8):
/// - below [`LATTICE_BOUND_VAR`] its PMF is their histogram (with the estimator's pseudo-sample
///   of weight `1/(N+1)`) and nothing else changes: at sub-DN noise black's variance is that of
///   black's place in its code, which the law must not carry to the other levels;
/// - from it up they join bin 0's lit samples, in one fold (they are one frame), so the bin
///   keeps its own histogram (a one-frame bin, "Estimation" 5) and the law toward black is
///   fitted on them.
///
/// A bin 0 with lit samples of its own is left as it is.
pub fn estimate_position_with_black(
    folds: &[&[NoiseHistogram]],
    shifts: &[&[[f64; 3]]],
    levels: &BinLevels,
    pooling: Pooling,
    black: Option<&NoiseHistogram>,
) -> PositionEstimate {
    let lit: u64 = folds.iter().filter_map(|f| f.first()).map(NoiseHistogram::total).sum();
    let usable = |h: &&NoiseHistogram| {
        h.total() > 0
            && lit < OVERRIDE_MIN_HELDOUT
            && !levels.is_empty()
            && clip::clip_fraction(h, levels.lowest_sure(0), levels.hi[0], levels.floor, levels.white) <= CLIP_FRACTION
    };
    let Some(black) = black.filter(usable) else {
        return estimate_position(folds, shifts, levels, pooling);
    };
    let mut own = NoiseHistogram::default();
    for f in folds {
        if let Some(h) = f.first() {
            own.merge(h);
        }
    }
    own.merge(black);
    let own = own.trimmed();
    let stat = Stat::of(&own);
    if stat.var < LATTICE_BOUND_VAR {
        let mut e = estimate_position(folds, shifts, levels, pooling);
        e.bins[0] = if pooling == Pooling::Plain {
            BinModel::from_histogram(&own)
        } else {
            let eps = 1.0 / (stat.n as f64 + 1.0);
            let mut mix = Acc::default();
            let n = own.total() as f64;
            mix.add(&Pmf { first: own.first, p: own.counts.iter().map(|&c| c as f64 / n).collect() }, 1.0 - eps);
            mix.add(&laplace_pmf(stat.mean, stat.var, levels.reach()), eps);
            let pmf = Pmf::from_weights(mix.first, mix.w.iter().copied())
                .unwrap_or(Pmf { first: stat.mean.round() as i32, p: vec![1.0] });
            BinModel::estimated(&pmf, stat.n, BinSource::Measured, Some([stat.mean, stat.var]), false)
        };
        return e;
    }
    // The first fold that holds samples takes them (fold 0 when none does).
    let k = folds.iter().position(|f| f.iter().any(|h| h.total() > 0)).unwrap_or(0);
    let mut with: Vec<NoiseHistogram> = folds.get(k).map_or_else(Vec::new, |f| f.to_vec());
    if with.len() < levels.len() {
        with.resize(levels.len(), NoiseHistogram::default());
    }
    with[0].merge(black);
    let mut all: Vec<&[NoiseHistogram]> = folds.to_vec();
    if all.is_empty() {
        all.push(&with);
    } else {
        all[k] = &with;
    }
    estimate_position(&all, shifts, levels, pooling)
}

/// [`estimate_position`] with the Gaussian's weights taken among `shrinks` (ascending, `0`
/// first): `&[0.0]` is the estimator without shrinkage, for comparisons.
pub(crate) fn estimate_position_among(
    folds: &[&[NoiseHistogram]],
    shifts: &[&[[f64; 3]]],
    levels: &BinLevels,
    pooling: Pooling,
    shrinks: &[f64],
) -> PositionEstimate {
    let nbins = levels.len();
    let mut total: Vec<NoiseHistogram> = vec![NoiseHistogram::default(); nbins];
    for f in folds {
        for (t, h) in total.iter_mut().zip(f.iter()) {
            t.merge(h);
        }
    }
    let total: Vec<NoiseHistogram> = total.iter().map(|h| h.trimmed()).collect();
    let clipped = clip_flags(&total, levels);
    if pooling == Pooling::Plain {
        let mut bins = plain_empirical(&total);
        for (b, c) in bins.iter_mut().zip(&clipped) {
            b.clipped = *c;
        }
        let law = Law::fit(&total.iter().map(Stat::of).collect::<Vec<_>>(), &clipped, levels);
        let report = EstimateReport {
            pooling: 0,
            clip_mode: ClipMode::Own,
            choice: Choice::Plain,
            candidates: Vec::new(),
            clip_scores: None,
            law: law.mean.iter().zip(&law.var).map(|(&m, &v)| [m as f32, v as f32]).collect(),
            clipped: clipped.iter().enumerate().filter(|(_, c)| **c).map(|(b, _)| b as u32).collect(),
            heldout_samples: 0,
        };
        return PositionEstimate { bins, report, shrink: 0.0 };
    }
    let live_folds: Vec<usize> = (0..folds.len()).filter(|&k| folds[k].iter().any(|h| h.total() > 0)).collect();

    // Per bin, the pooling and the weight of the law's Gaussian it uses: the position's choice,
    // or another where the bin's own held-out samples decide for it by more than
    // `OVERRIDE_NATS`.
    let per_bin: Vec<(u64, f64)>;
    // Per bin, whether its held-out samples clearly favour its own histogram over law mode
    // (clipped bins, cross-validated only; see the clip mode below).
    let own_votes: Vec<bool>;
    // The law mode gives clipped bins what the noise law, fitted on unclipped bins, predicts:
    // with fewer unclipped samples than one window of the law, nothing measured stands behind
    // it (a high ISO whose noise reaches the floor from every level: a 96 × 72 session at 50 ×
    // its base ISO drew every bin with 3 × the measured variance in law mode), and the clipped
    // bins keep their own samples.
    let unclipped: u64 = (0..nbins).filter(|&b| !clipped[b]).map(|b| total[b].total()).sum();
    let law_supported = unclipped as f64 >= law::LAW_MIN_SAMPLES;
    let s = shrinks.len();
    let candidate = |i: usize| (POOLING_CANDIDATES[i / s], shrinks[i % s]);
    let (m, shrink, choice, candidates, clip_scores, heldout) = match pooling {
        Pooling::Fixed(m) => {
            per_bin = vec![(m, 0.0); nbins];
            own_votes = vec![false; nbins];
            (m, 0.0, Choice::Fixed, Vec::new(), None, 0)
        }
        Pooling::Auto | Pooling::Plain if live_folds.len() < 2 => {
            per_bin = vec![(DEFAULT_POOLING, 0.0); nbins];
            own_votes = vec![false; nbins];
            (DEFAULT_POOLING, 0.0, Choice::Default, Vec::new(), None, 0)
        }
        Pooling::Auto | Pooling::Plain => {
            let cv = cross_validate(folds, &total, &clipped, levels, &live_folds, shrinks);
            let n = cv.heldout.max(1) as f64;
            // A shrinkage is a candidate only where the held-out samples over all levels at once
            // do not score it below the same pooling unshrunk (`marginal.rs`).
            let allowed: Vec<bool> = (0..cv.ll.len()).map(|i| cv.marginal_ll[i] >= cv.marginal_ll[i - i % s]).collect();
            let best_among = |ll: &[f64]| {
                let masked: Vec<f64> =
                    ll.iter().zip(&allowed).map(|(&v, &ok)| if ok { v } else { f64::NEG_INFINITY }).collect();
                argmax(&masked)
            };
            let best = best_among(&cv.ll);
            // A bin whose samples sit (almost) all in one fold (a level one frame fed: an EMVA
            // pair's calibration frame, a one-frame dim step) is scored with its own samples (almost)
            // out of training: its held-out likelihoods compare its neighbours, not its own
            // histogram, so they cannot decide a pooling for it (on EMVA set 002 they chose the
            // widest pool for black's bin, which then drew its mean +0.2 DN and its variance
            // 1.7× off its own 130 000 samples). "Almost" is fewer than two folds' worth: the
            // inverse Simpson count `(Σ nₖ)² / Σ nₖ²` of its fold counts below 2 (a pair's two
            // frames give 2, a burst 4). Nothing held out says smoothing helps such a bin, so
            // with at least `OVERRIDE_MIN_HELDOUT` samples it keeps its own histogram (the
            // yardstick no smoothing may lose to); a sparser one takes the position's pooling.
            let fold_count = |b: usize| {
                let n: Vec<f64> =
                    live_folds.iter().map(|&k| folds[k].get(b).map_or(0.0, |h| h.total() as f64)).collect();
                let (s, s2) = n.iter().fold((0.0, 0.0), |(s, s2), &x| (s + x, s2 + x * x));
                if s2 > 0.0 { s * s / s2 } else { 0.0 }
            };
            per_bin = cv
                .bin_ll
                .iter()
                .zip(&cv.bin_heldout)
                .enumerate()
                .map(|(bin, (ll, &n))| {
                    let b = best_among(ll);
                    let one_frame = fold_count(bin) < 2.0;
                    if one_frame && total[bin].total() >= OVERRIDE_MIN_HELDOUT {
                        (0, 0.0)
                    } else if n >= OVERRIDE_MIN_HELDOUT && ll[b] - ll[best] > OVERRIDE_NATS && !one_frame {
                        candidate(b)
                    } else {
                        candidate(best)
                    }
                })
                .collect();
            // The pack's report lists the poolings alone (no shrinkage): its `m = 0` entry is the
            // plain per-bin histogram that `inspect` compares with.
            let candidates = POOLING_CANDIDATES
                .iter()
                .enumerate()
                .map(|(c, &pooling)| CandidateScore { pooling, cross_entropy: -cv.ll[c * s] / n })
                .collect();
            let best_pool = best / s;
            own_votes = (0..nbins)
                .map(|b| {
                    clipped[b]
                        && cv.bin_heldout[b] >= OVERRIDE_MIN_HELDOUT
                        && cv.clip_bin_own[b] - cv.clip_bin_law[b][best_pool] > OVERRIDE_NATS
                })
                .collect();
            // The clipped bins' scores in both modes, all together (for the report).
            let scores = match cv.clip_ll {
                Some([own, law]) if cv.clip_samples > 0 => {
                    let k = cv.clip_samples as f64;
                    Some([-own / k, -law / k])
                }
                _ => None,
            };
            (
                POOLING_CANDIDATES[best_pool],
                shrinks[best % s],
                Choice::CrossValidated { folds: live_folds.len() as u8 },
                candidates,
                scores,
                cv.heldout,
            )
        }
    };

    // Each bin's selection over all its samples: mean shift, and the variance to give back
    // (what the error lost, less the spread of the shift within the bin, which the samples
    // still carry).
    let deselect: Vec<(f64, f64)> = (0..nbins)
        .map(|b| {
            let mut s = [0.0f64; 3];
            for f in shifts {
                if let Some(v) = f.get(b) {
                    for k in 0..3 {
                        s[k] += v[k];
                    }
                }
            }
            let n = total[b].total() as f64;
            if n > 0.0 {
                let mean = s[0] / n;
                (mean, s[2] / n - (s[1] / n - mean * mean).max(0.0))
            } else {
                (0.0, 0.0)
            }
        })
        .collect();
    // Clip mode per bin. Law mode is the smooth one (the law's noise, clamped by synthesis, moves
    // with the level as the unclipped bins' does), so a clipped bin takes it unless its own
    // held-out samples favour its own histogram by more than `OVERRIDE_NATS` (with at least
    // `OVERRIDE_MIN_HELDOUT` of them), as for the pooling. One mode per position let the bins
    // at white decide for all: on the demo's 10-bit phone a top bin of saturated pixels (48 450
    // samples, noise ≈ 0) chose own mode for 145 clipped bins at ISO 3200, and bins of 10–30
    // samples kept their own histograms, means from −51 to +27 DN beside −30 DN neighbours.
    // Without a law to stand on (`law_supported`), every clipped bin keeps its own.
    let own_mode: Vec<bool> = (0..nbins).map(|b| clipped[b] && (!law_supported || own_votes[b])).collect();
    let clip_mode = if law_supported { ClipMode::Law } else { ClipMode::Own };
    let data = Data::new(&total, &clipped, levels).deselected(&deselect, levels);
    // Bin means onto the law where bursts explain their distance, unless the user fixed the
    // pooling (`--pooling 0` is each bin's own histogram, for comparisons).
    let data = if matches!(pooling, Pooling::Fixed(_)) { data } else { data.means_on_law(levels) };
    let bins = (0..nbins)
        .map(|b| {
            // Without a law to stand on, an empty bin takes the nearest measured bin's own
            // histogram (as the plain estimator does): the law fitted on clipped bins alone is
            // no prior (a 12-bit sensor at 50× its base ISO, every bin clipped, filled its
            // empty dark bins with noise of mean +1600 DN beside measured bins at −110).
            let nearest = (!law_supported && data.stats[b].n == 0)
                .then(|| nearest_bin(b, nbins, |j| data.stats[j].n > 0))
                .flatten();
            let (src, own_only) = match nearest {
                Some(j) => (j, true),
                None => (b, own_mode[b] && data.stats[b].n > 0),
            };
            let (m, alpha) = per_bin[b];
            // Shrinkage toward the law's Gaussian for bins that stand on the law; a clipped bin
            // (own or law mode) and a bin taking its nearest neighbour's histogram keep their pool.
            let alpha = if nearest.is_none() && !clipped[b] { alpha } else { 0.0 };
            let mut out: Option<(Acc, u64)> = None;
            pool_bin(&data, src, own_only, &[m], FILL_MIN_SAMPLES, |_, acc, cum| out = Some((acc.clone(), cum)));
            let (acc, cum) = out.unwrap_or_default();
            let (mu, var) = match nearest {
                Some(j) => (data.stats[j].mean, data.stats[j].var.max(MIN_VAR)),
                None => (data.centre[b], data.law.var[b]),
            };
            let eps = 1.0 / (cum as f64 + 1.0);
            let mut mix = Acc::default();
            if acc.total > 0.0 {
                let pool = Pmf { first: acc.first, p: acc.w.iter().map(|w| w / acc.total).collect() };
                mix.add(&pool, (1.0 - eps) * (1.0 - alpha));
                if alpha > 0.0 {
                    mix.add(&gauss_pmf(mu, var, levels.reach()), (1.0 - eps) * alpha);
                }
            }
            mix.add(&laplace_pmf(mu, var, levels.reach()), eps);
            let own = data.stats[b];
            let pooled_from_others = cum > own.n || (clipped[b] && !own_only);
            let source = if own.n == 0 || (clipped[b] && !own_only) {
                BinSource::Filled
            } else if pooled_from_others {
                BinSource::Pooled
            } else {
                BinSource::Measured
            };
            let pmf = Pmf::from_weights(mix.first, mix.w.iter().copied())
                .unwrap_or(Pmf { first: mu.round() as i32, p: vec![1.0] });
            let measured = (own.n > 0).then_some([own.mean, own.var]);
            BinModel::estimated(&pmf, own.n, source, measured, clipped[b])
        })
        .collect();
    let report = EstimateReport {
        pooling: m,
        clip_mode,
        choice,
        candidates,
        clip_scores,
        law: data.law.mean.iter().zip(&data.law.var).map(|(&m, &v)| [m as f32, v as f32]).collect(),
        clipped: clipped.iter().enumerate().filter(|(_, c)| **c).map(|(b, _)| b as u32).collect(),
        heldout_samples: heldout,
    };
    PositionEstimate { bins, report, shrink }
}

/// The bin nearest to `b` (itself first, then both sides at each distance, the lower first) of
/// the `n` bins that `ok` accepts.
fn nearest_bin(b: usize, n: usize, ok: impl Fn(usize) -> bool) -> Option<usize> {
    (0..n).flat_map(|d| [b.checked_sub(d), (b + d < n).then_some(b + d)]).flatten().find(|&j| ok(j))
}

/// The plain empirical estimator: each bin's own histogram, the nearest bin with samples for
/// empty bins (no law, no pooling, no prior). The yardstick of method.md: the pack must not lose
/// to it on held-out frames.
pub fn plain_empirical(hists: &[NoiseHistogram]) -> Vec<BinModel> {
    let nb = hists.len();
    (0..nb)
        .map(|b| {
            let pick = nearest_bin(b, nb, |j| hists[j].total() > 0);
            match pick {
                Some(j) => {
                    let t = hists[j].trimmed();
                    let own = hists[b].total();
                    let (m, v) = hists[b].moments();
                    BinModel {
                        first: t.first,
                        counts: t.counts,
                        samples: own,
                        source: if j == b { BinSource::Measured } else { BinSource::Filled },
                        measured: (own > 0).then_some([m, v]),
                        clipped: false,
                        grid_step: 0,
                    }
                }
                None => BinModel {
                    first: 0,
                    counts: vec![1],
                    samples: 0,
                    source: BinSource::Filled,
                    measured: None,
                    clipped: false,
                    grid_step: 0,
                },
            }
        })
        .collect()
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_flags;
#[cfg(test)]
mod tests_folds;
#[cfg(test)]
mod tests_shrink;
