//! Per-bin noise PMFs from the session's histograms, with every smoothing choice made by
//! held-out likelihood (method.md, "Estimation").
//!
//! The session keeps the samples of each (ISO, CFA position, bin) in [`FOLDS`] histograms: the
//! target frames of an ISO take turns (frame `i` goes to fold `i mod FOLDS`). Per ISO and
//! position this module:
//!
//! 1. **Flags clipped bins**: a bin is clipped when more than [`CLIP_FRACTION`] of its samples
//!    could have reached the white level or 0 (`n ≥ white − highest level of the bin`, or
//!    `n ≤ −lowest level`). Clipped bins never inform anything about unclipped ones.
//! 2. **Fits the noise law**: the mean and variance of the noise against the clean level, by
//!    local-linear regression over the measured, unclipped bins ([`Law`]). Outside the measured
//!    range the law is continued from its last local value along a global non-negative quadratic
//!    (variance, never decreasing towards white) and a global line (mean).
//! 3. **Pools**: bin `b`'s PMF is the sum of its own histogram and of its nearest unclipped
//!    neighbours' histograms, taken ring by ring (both sides at the same distance together)
//!    until the pool holds at least `m` samples; each neighbour `j` is moved onto `b` by the law
//!    (mean shifted by `μ(b) − μ(j)`, variance scaled by `v(b)/v(j)`, its own shape kept). With
//!    `m = 0` a bin is its own histogram, and an empty bin takes its nearest measured ring: the
//!    plain empirical estimator. To the pool is added one pseudo-sample spread as a discretised
//!    Laplace law with the law's mean and variance (weight `1/(N+1)` of an `N`-sample pool), so
//!    that no value has probability zero.
//! 4. **Chooses `m`** among [`POOLING_CANDIDATES`] by cross-validation: for every fold, PMFs are
//!    built from the other folds and scored by the log-likelihood of the held-out fold's
//!    samples; the `m` with the highest total wins. Because `m = 0` is among the candidates, the
//!    pack only smooths where held-out frames say smoothing helps.
//! 5. **Chooses the clip mode**: a clipped bin either keeps its own histogram
//!    ([`ClipMode::Own`]) or takes the unclipped noise the law predicts there, pooled from the
//!    nearest unclipped bins, and lets synthesis clip (`clamp(clean + n, 0, white)`,
//!    [`ClipMode::Law`]); held-out likelihood of the clipped bins decides (the law mode is
//!    scored with the clipping applied at each integer level of the bin).
//!
//! Everything is deterministic: sequential floating point per (ISO, position), no randomness.

use serde::{Deserialize, Serialize};

use crate::fit::{nn_poly_fit, poly_eval, wls};
use crate::histogram::NoiseHistogram;
use crate::layout::Binning;
use crate::pack::{BinModel, BinSource};
use crate::pmf::Pmf;

/// Folds of the cross-validation: target frames of an ISO take turns.
pub const FOLDS: usize = 4;

/// Pooling thresholds `m` (samples) tried by the cross-validation. 0 is the plain per-bin
/// histogram.
pub const POOLING_CANDIDATES: [u64; 9] = [0, 16, 64, 256, 1024, 4096, 16_384, 65_536, 262_144];

/// Pooling used when the data cannot cross-validate (fewer than two folds hold samples).
pub const DEFAULT_POOLING: u64 = 1024;

/// A bin is clipped when more than this fraction of its samples may have reached 0 or white
/// (heavy tails make even 10⁻³ shrink a variance by a few per cent) …
pub const CLIP_FRACTION: f64 = 1e-4;

/// … or when its levels lie within this many standard deviations of 0 or white.
pub const CLIP_SIGMAS: f64 = 4.0;

/// Neighbours farther than this (bins) are pooled only to reach a bin's first samples.
pub const MAX_RADIUS: usize = 32;

/// A bin leaves its position's pooling for another candidate only when its own held-out samples
/// favour that candidate by more than this log-likelihood (a likelihood ratio of e⁴ ≈ 55).
pub const OVERRIDE_NATS: f64 = 4.0;

/// … and only with at least this many held-out samples of its own: a few samples of one pixel
/// share its clean image's error across frames and would vote as one.
pub const OVERRIDE_MIN_HELDOUT: u64 = 200;

/// Bins without samples of their own, far from data, pool at least this many samples.
pub const FILL_MIN_SAMPLES: u64 = 256;

/// The local-linear law's variance window holds at least this many samples and
/// [`LAW_MIN_BINS`] bins …
const LAW_MIN_SAMPLES: f64 = 8192.0;
const LAW_MIN_BINS: usize = 4;
/// … and its mean window four times as many bins: what is left of the clean image's selection
/// shift ([`crate::deselect`]) swings the mean from bin to bin across a cluster of levels, and a
/// narrow window would carry one cluster edge's swing into the next gap.
const LAW_MIN_BINS_MEAN: usize = 16;

/// Smallest variance any PMF is given (DN²): the quantisation of a noiseless pixel.
const MIN_VAR: f64 = 1.0 / 12.0;

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

/// What clipped bins hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ClipMode {
    /// Their own (clipped) histogram.
    Own,
    /// The unclipped noise the law predicts, pooled from unclipped bins; synthesis clips.
    Law,
}

/// How the pooling and the clip mode were chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Choice {
    /// Cross-validated over this many folds that held samples.
    CrossValidated { folds: u8 },
    /// Set by the user.
    Fixed,
    /// Too few folds held samples to cross-validate: defaults used.
    Default,
    /// The plain per-bin histogram was asked for.
    Plain,
}

/// Held-out score of one candidate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateScore {
    /// Pooling threshold `m`.
    pub pooling: u64,
    /// Held-out cross-entropy, nats per held-out sample (lower is better).
    pub cross_entropy: f64,
}

/// What the estimator decided for one (ISO, position), kept in the pack for `inspect` and
/// `report`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EstimateReport {
    pub pooling: u64,
    pub clip_mode: ClipMode,
    pub choice: Choice,
    /// Cross-validation scores of every pooling candidate (empty unless cross-validated).
    pub candidates: Vec<CandidateScore>,
    /// Held-out cross-entropy of the clipped bins under each clip mode (own, law), when both
    /// could be scored.
    pub clip_scores: Option<[f64; 2]>,
    /// The fitted noise law per bin: (mean, variance) of `n` in DN and DN².
    pub law: Vec<[f32; 2]>,
    /// Bins flagged as clipped.
    pub clipped: Vec<u32>,
    /// Held-out samples scored.
    pub heldout_samples: u64,
}

impl EstimateReport {
    /// The score of the plain per-bin histogram (`m = 0`) and of the chosen pooling, when
    /// cross-validated.
    pub fn gain_over_plain(&self) -> Option<(f64, f64)> {
        let plain = self.candidates.iter().find(|c| c.pooling == 0)?;
        let chosen = self.candidates.iter().find(|c| c.pooling == self.pooling)?;
        Some((plain.cross_entropy, chosen.cross_entropy))
    }
}

/// The integer clean levels each bin of one position covers.
#[derive(Debug, Clone, PartialEq)]
pub struct BinLevels {
    /// Lowest and highest integer clean level of each bin.
    pub lo: Vec<i32>,
    pub hi: Vec<i32>,
    /// Centre level (DN) of each bin.
    pub center: Vec<f64>,
    /// The codes the sensor writes: clipped below at `floor`, above from `white` on (where its
    /// output starts to pile up, [`crate::lattice::output_range`]).
    pub floor: i32,
    pub white: i32,
}

impl BinLevels {
    pub fn new(binning: &Binning, pos: usize) -> Self {
        let n = binning.bins(pos);
        let black = binning.black[pos] as f64;
        let w = binning.bin_width as f64;
        let white = binning.white as i32;
        let mut lo = Vec::with_capacity(n);
        let mut hi = Vec::with_capacity(n);
        for b in 0..n {
            // Bin 0 also takes every level below black; those that occur lie within a bin
            // width of it.
            let l = if b == 0 { (black - w).floor().max(0.0) as i32 } else { (black + b as f64 * w).ceil() as i32 };
            let h = if b + 1 == n { white } else { ((black + (b + 1) as f64 * w).ceil() as i32 - 1).min(white) };
            lo.push(l.min(white));
            hi.push(h.max(l.min(white)));
        }
        let center = (0..n).map(|b| binning.center(pos, b) as f64).collect();
        Self { lo, hi, center, floor: 0, white }
    }

    /// The same bins for a sensor that writes only codes `range[0] ..= range[1]`.
    pub fn with_range(mut self, range: [u16; 2]) -> Self {
        self.floor = range[0] as i32;
        self.white = range[1] as i32;
        self
    }

    pub fn len(&self) -> usize {
        self.lo.len()
    }

    pub fn is_empty(&self) -> bool {
        self.lo.is_empty()
    }
}

/// The result for one (ISO, position).
#[derive(Debug, Clone, PartialEq)]
pub struct PositionEstimate {
    pub bins: Vec<BinModel>,
    pub report: EstimateReport,
}

/// Sample count, mean and variance of a histogram.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Stat {
    n: u64,
    mean: f64,
    var: f64,
}

impl Stat {
    fn of(h: &NoiseHistogram) -> Self {
        let n = h.total();
        let (mean, var) = h.moments();
        Self { n, mean, var }
    }
}

/// Fraction of a histogram's samples (counts over `first ..`) that may have reached 0 or white
/// for some integer level `lo ..= hi` of the bin: `n ≥ white − hi` or `n ≤ −lo`.
pub fn clip_fraction_of(first: i32, counts: &[u64], lo: i32, hi: i32, white: i32) -> f64 {
    clip_fraction_in(first, counts, lo, hi, 0, white)
}

/// [`clip_fraction_of`] for a sensor clipping at `floor` and `white`.
pub fn clip_fraction_in(first: i32, counts: &[u64], lo: i32, hi: i32, floor: i32, white: i32) -> f64 {
    let total: u64 = counts.iter().sum();
    if total == 0 {
        return 0.0;
    }
    let top = white - hi;
    let bottom = floor - lo;
    let c: u64 = counts
        .iter()
        .enumerate()
        .filter(|(i, _)| {
            let n = first + *i as i32;
            n >= top || n <= bottom
        })
        .map(|(_, &k)| k)
        .sum();
    c as f64 / total as f64
}

fn clip_fraction(h: &NoiseHistogram, lo: i32, hi: i32, floor: i32, white: i32) -> f64 {
    clip_fraction_in(h.first, &h.counts, lo, hi, floor, white)
}

/// Bins flagged as clipped, from all samples: more than [`CLIP_FRACTION`] of their samples may
/// have reached 0 or white, or — for bins with too few samples to show a fraction that small —
/// their levels lie within [`CLIP_SIGMAS`] standard deviations of 0 or white by the noise law
/// fitted on the bins not flagged so far.
fn clip_flags(hists: &[NoiseHistogram], levels: &BinLevels) -> Vec<bool> {
    let mut clipped: Vec<bool> = hists
        .iter()
        .enumerate()
        .map(|(b, h)| clip_fraction(h, levels.lo[b], levels.hi[b], levels.floor, levels.white) > CLIP_FRACTION)
        .collect();
    let stats: Vec<Stat> = hists.iter().map(Stat::of).collect();
    let law = Law::fit(&stats, &clipped, levels);
    for (b, c) in clipped.iter_mut().enumerate() {
        // A bin with enough samples shows its clipping itself.
        if stats[b].n as f64 * CLIP_FRACTION >= 1.0 {
            continue;
        }
        let sd = law.var[b].sqrt();
        let to_white = (levels.white - levels.hi[b]) as f64 - law.mean[b];
        let to_zero = (levels.lo[b] - levels.floor) as f64 + law.mean[b];
        if to_white < CLIP_SIGMAS * sd || to_zero < CLIP_SIGMAS * sd {
            *c = true;
        }
    }
    clipped
}

/// The noise law of one (ISO, position): mean and variance of `n` at every bin.
#[derive(Debug, Clone, PartialEq)]
pub struct Law {
    pub mean: Vec<f64>,
    pub var: Vec<f64>,
}

impl Law {
    /// Fits the law on the measured bins (`stats`) not flagged clipped; see the module docs.
    fn fit(stats: &[Stat], clipped: &[bool], levels: &BinLevels) -> Self {
        let nbins = levels.len();
        let mut pts: Vec<(f64, f64, f64, f64)> = stats
            .iter()
            .enumerate()
            .filter(|(b, s)| s.n >= 2 && !clipped[*b])
            .map(|(b, s)| (levels.center[b], s.n as f64, s.mean, s.var))
            .collect();
        if pts.is_empty() {
            // Everything measured is clipped (or nothing is measured): use what there is.
            pts = stats
                .iter()
                .enumerate()
                .filter(|(_, s)| s.n >= 1)
                .map(|(b, s)| (levels.center[b], s.n as f64, s.mean, s.var))
                .collect();
        }
        if pts.is_empty() {
            return Self { mean: vec![0.0; nbins], var: vec![1.0; nbins] };
        }
        let first_level = pts[0].0;
        let last_level = pts[pts.len() - 1].0;
        let bw = if nbins > 1 { (levels.center[1] - levels.center[0]).abs().max(1.0) } else { 1.0 };
        let local =
            |x: f64| (local_linear(&pts, x, bw, LAW_MIN_BINS_MEAN).0, local_linear(&pts, x, bw, LAW_MIN_BINS).1);
        // Global trends for extrapolation.
        // Trends for extrapolation: shot noise makes the variance linear in the level, so each
        // end continues along a non-negative line fitted on the half of the measured levels
        // next to it (the slope the data shows there, not one bent by the far end).
        let mid = 0.5 * (first_level + last_level);
        // Weights from the local law's variance at each point (a sparse bin's own variance can
        // be near 0 by chance and would take all the weight).
        let smooth_var: Vec<f64> = pts.iter().map(|p| local(p.0).1.max(MIN_VAR)).collect();
        let trend = |upper: bool| -> (Vec<f64>, Vec<f64>) {
            // (variance line, mean line) of one half
            let sel: Vec<(f64, f64, f64, f64)> = pts
                .iter()
                .zip(&smooth_var)
                .filter(|(p, _)| if upper { p.0 >= mid } else { p.0 <= mid })
                .map(|(p, &sv)| (p.0, p.1, p.2, sv))
                .collect();
            let raw: Vec<f64> =
                pts.iter().filter(|p| if upper { p.0 >= mid } else { p.0 <= mid }).map(|p| p.3).collect();
            // In levels above the first selected one, so that "non-negative" means a variance
            // ≥ 0 there and a slope ≥ 0, whatever the intercept at level 0 would be.
            let x0 = sel.first().map_or(0.0, |p| p.0);
            let xs: Vec<f64> = sel.iter().map(|p| p.0 - x0).collect();
            let vs = raw;
            let ms: Vec<f64> = sel.iter().map(|p| p.2).collect();
            let wv: Vec<f64> = sel.iter().map(|p| p.1 / p.3.powi(2)).collect();
            let wm: Vec<f64> = sel.iter().map(|p| p.1 / p.3).collect();
            let (gv, gm) = if sel.len() < 2 {
                (vec![vs.first().copied().unwrap_or(1.0), 0.0], vec![ms.first().copied().unwrap_or(0.0), 0.0])
            } else {
                (nn_poly_fit(&xs, &vs, &wv, 1), wls(&xs, &ms, &wm, &[0, 1]).unwrap_or(vec![ms[0], 0.0]))
            };
            // Back to absolute levels.
            (vec![gv[0] - gv[1] * x0, gv[1]], vec![gm[0] - gm[1] * x0, gm[1]])
        };
        let (gv_hi, gm_hi) = trend(true);
        let (gv_lo, gm_lo) = trend(false);
        let (m_first, v_first) = local(first_level);
        let (m_last, v_last) = local(last_level);
        let mut mean = Vec::with_capacity(nbins);
        let mut var = Vec::with_capacity(nbins);
        for &x in &levels.center {
            // Beyond an end: the trend line, joined to the local law at the end by an offset
            // that fades over a few bins.
            let v = if x > last_level {
                let fade = (-(x - last_level) / (4.0 * bw)).exp();
                let tv = poly_eval(&gv_hi, x) + fade * (v_last - poly_eval(&gv_hi, last_level));
                tv.max(v_last.min(poly_eval(&gv_hi, last_level)))
            } else if x < first_level {
                let fade = (-(first_level - x) / (4.0 * bw)).exp();
                let tv = poly_eval(&gv_lo, x) + fade * (v_first - poly_eval(&gv_lo, first_level));
                tv.min(v_first.max(poly_eval(&gv_lo, first_level))).max(0.5 * v_first)
            } else {
                local(x).1
            };
            // The mean likewise, except that a local slope is never carried past an end: the
            // trend of the half next to it takes over.
            let m = if x > last_level {
                let fade = (-(x - last_level) / (4.0 * bw)).exp();
                poly_eval(&gm_hi, x) + fade * (m_last - poly_eval(&gm_hi, last_level))
            } else if x < first_level {
                let fade = (-(first_level - x) / (4.0 * bw)).exp();
                poly_eval(&gm_lo, x) + fade * (m_first - poly_eval(&gm_lo, first_level))
            } else {
                local(x).0
            };
            mean.push(m);
            var.push(v.max(MIN_VAR));
        }
        Self { mean, var }
    }
}

/// Local-linear (tricube-weighted) estimate of (mean, variance) at level `x` from
/// `(level, samples, mean, var)` points sorted by level.
fn local_linear(pts: &[(f64, f64, f64, f64)], x: f64, bw: f64, min_bins: usize) -> (f64, f64) {
    // Grow a window around x until it holds enough samples and bins.
    let start = pts.partition_point(|p| p.0 < x);
    let (mut lo, mut hi) = (start, start); // window is pts[lo..hi]
    let mut n = 0.0;
    let mut radius: f64 = 0.0;
    // Inside the measured range the window also reaches the nearest point on each side, so a
    // gap between measured levels is bridged (shot noise grows steadily across it) instead of
    // continuing one side's local slope.
    let inside = start > 0 && start < pts.len();
    while (n < LAW_MIN_SAMPLES || hi - lo < min_bins || (inside && (lo == start || hi == start)))
        && (lo > 0 || hi < pts.len())
    {
        let take_lo = match (lo > 0, hi < pts.len()) {
            (true, true) => (x - pts[lo - 1].0) <= (pts[hi].0 - x),
            (l, _) => l,
        };
        if take_lo {
            lo -= 1;
            n += pts[lo].1;
            radius = radius.max(x - pts[lo].0);
        } else {
            n += pts[hi].1;
            radius = radius.max(pts[hi].0 - x);
            hi += 1;
        }
    }
    let h = (radius * 1.25).max(2.5 * bw);
    let mut sel: Vec<(f64, f64, f64, f64)> = Vec::new();
    for p in pts {
        let d = (p.0 - x).abs() / h;
        if d < 1.0 {
            let k = (1.0 - d * d * d).powi(3);
            sel.push((p.0 - x, p.1 * k, p.2, p.3));
        }
    }
    if sel.is_empty() {
        let p = pts[start.min(pts.len() - 1)];
        return (p.2, p.3);
    }
    let xs: Vec<f64> = sel.iter().map(|s| s.0).collect();
    let w: Vec<f64> = sel.iter().map(|s| s.1).collect();
    let ms: Vec<f64> = sel.iter().map(|s| s.2).collect();
    let vs: Vec<f64> = sel.iter().map(|s| s.3).collect();
    let spread = {
        let sw: f64 = w.iter().sum();
        let mx = xs.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>() / sw;
        (xs.iter().zip(&w).map(|(a, b)| b * (a - mx).powi(2)).sum::<f64>() / sw).sqrt()
    };
    let fit = |ys: &[f64]| -> f64 {
        if sel.len() >= 2
            && spread > 0.25 * bw
            && let Some(c) = wls(&xs, ys, &w, &[0, 1])
        {
            return c[0];
        }
        let sw: f64 = w.iter().sum();
        ys.iter().zip(&w).map(|(y, w)| y * w).sum::<f64>() / sw
    };
    (fit(&ms), fit(&vs))
}

/// A growing weighted PMF on the integer grid.
#[derive(Debug, Clone, Default)]
struct Acc {
    first: i32,
    w: Vec<f64>,
    total: f64,
}

impl Acc {
    fn add(&mut self, p: &Pmf, weight: f64) {
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

    fn at(&self, n: i32) -> f64 {
        let i = n as i64 - self.first as i64;
        if i < 0 || i as usize >= self.w.len() { 0.0 } else { self.w[i as usize] }
    }
}

/// Discretised Laplace law with mean `mu` and variance `var`: `P(n)`.
fn laplace_mass(n: i32, mu: f64, var: f64) -> f64 {
    let s = (var.max(MIN_VAR) / 2.0).sqrt();
    let cdf = |x: f64| {
        let z = (x - mu) / s;
        if z < 0.0 { 0.5 * z.exp() } else { 1.0 - 0.5 * (-z).exp() }
    };
    (cdf(n as f64 + 0.5) - cdf(n as f64 - 0.5)).max(0.0)
}

/// The Laplace prior as a PMF over ±12 standard deviations (the mass beyond is below 10⁻⁷).
fn laplace_pmf(mu: f64, var: f64) -> Pmf {
    let sd = var.max(MIN_VAR).sqrt();
    let lo = (mu - 12.0 * sd).floor() as i32 - 1;
    let hi = (mu + 12.0 * sd).ceil() as i32 + 1;
    Pmf::from_weights(lo, (lo..=hi).map(|n| laplace_mass(n, mu, var)))
        .unwrap_or(Pmf { first: mu.round() as i32, p: vec![1.0] })
}

/// Everything the pooling needs about one data set (all samples, or the training folds).
struct Data<'a> {
    stats: Vec<Stat>,
    pmfs: Vec<Option<Pmf>>,
    law: Law,
    clipped: &'a [bool],
}

impl<'a> Data<'a> {
    fn new(hists: &'a [NoiseHistogram], clipped: &'a [bool], levels: &BinLevels) -> Self {
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
    fn deselected(mut self, select: &[(f64, f64)], levels: &BinLevels) -> Self {
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
    fn moved(&self, j: usize, b: usize) -> Option<Pmf> {
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
    fn rings(&self, b: usize, own_only: bool) -> Vec<Vec<usize>> {
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
fn pool_bin(
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

/// Estimates the bins of one (ISO, position) from its fold histograms (`folds[k][bin]`) and the
/// clean image's selection summed over each fold's samples (`shifts[k][bin]` = `[Σδ, Σδ², Σa]`,
/// [`crate::deselect`]; empty slices for none). The pooling is chosen on the samples as
/// measured; the PMFs are built from samples with the selection undone.
pub fn estimate_position(
    folds: &[&[NoiseHistogram]],
    shifts: &[&[[f64; 3]]],
    levels: &BinLevels,
    pooling: Pooling,
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
        return PositionEstimate { bins, report };
    }
    let live_folds: Vec<usize> = (0..folds.len()).filter(|&k| folds[k].iter().any(|h| h.total() > 0)).collect();

    // Per bin, the pooling it uses: the position's choice, or a smaller one where the bin's own
    // held-out samples decide for it by more than `OVERRIDE_NATS`.
    let per_bin: Vec<u64>;
    let (m, clip_mode, choice, candidates, clip_scores, heldout) = match pooling {
        Pooling::Fixed(m) => {
            per_bin = vec![m; nbins];
            (m, ClipMode::Law, Choice::Fixed, Vec::new(), None, 0)
        }
        Pooling::Auto | Pooling::Plain if live_folds.len() < 2 => {
            per_bin = vec![DEFAULT_POOLING; nbins];
            (DEFAULT_POOLING, ClipMode::Law, Choice::Default, Vec::new(), None, 0)
        }
        Pooling::Auto | Pooling::Plain => {
            let cv = cross_validate(folds, &total, &clipped, levels, &live_folds);
            let n = cv.heldout.max(1) as f64;
            let best = argmax(&cv.ll);
            per_bin = cv
                .bin_ll
                .iter()
                .zip(&cv.bin_heldout)
                .map(|(ll, &n)| {
                    let b = argmax(ll);
                    if n >= OVERRIDE_MIN_HELDOUT && ll[b] - ll[best] > OVERRIDE_NATS {
                        POOLING_CANDIDATES[b]
                    } else {
                        POOLING_CANDIDATES[best]
                    }
                })
                .collect();
            let candidates = POOLING_CANDIDATES
                .iter()
                .zip(&cv.ll)
                .map(|(&pooling, &ll)| CandidateScore { pooling, cross_entropy: -ll / n })
                .collect();
            let (mode, scores) = match cv.clip_ll {
                Some([own, law]) if cv.clip_samples > 0 => {
                    let k = cv.clip_samples as f64;
                    (if own > law { ClipMode::Own } else { ClipMode::Law }, Some([-own / k, -law / k]))
                }
                _ => (ClipMode::Law, None),
            };
            (
                POOLING_CANDIDATES[best],
                mode,
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
    let data = Data::new(&total, &clipped, levels).deselected(&deselect, levels);
    let bins = (0..nbins)
        .map(|b| {
            let own_only = clipped[b] && clip_mode == ClipMode::Own && data.stats[b].n > 0;
            let mut out: Option<(Acc, u64)> = None;
            pool_bin(&data, b, own_only, &[per_bin[b]], FILL_MIN_SAMPLES, |_, acc, cum| out = Some((acc.clone(), cum)));
            let (acc, cum) = out.unwrap_or_default();
            let (mu, var) = (data.law.mean[b], data.law.var[b]);
            let eps = 1.0 / (cum as f64 + 1.0);
            let mut mix = Acc::default();
            if acc.total > 0.0 {
                mix.add(&Pmf { first: acc.first, p: acc.w.iter().map(|w| w / acc.total).collect() }, 1.0 - eps);
            }
            mix.add(&laplace_pmf(mu, var), eps);
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
    PositionEstimate { bins, report }
}

/// The index of the largest value (the first on ties).
fn argmax(v: &[f64]) -> usize {
    (0..v.len()).min_by(|&a, &b| v[b].total_cmp(&v[a]).then(a.cmp(&b))).unwrap_or(0)
}

struct CvResult {
    /// Held-out log-likelihood per pooling candidate (unclipped bins).
    ll: Vec<f64>,
    /// The same per bin, and each bin's held-out samples.
    bin_ll: Vec<Vec<f64>>,
    bin_heldout: Vec<u64>,
    heldout: u64,
    /// Held-out log-likelihood of clipped bins, own mode and law mode.
    clip_ll: Option<[f64; 2]>,
    clip_samples: u64,
}

fn cross_validate(
    folds: &[&[NoiseHistogram]],
    total: &[NoiseHistogram],
    clipped: &[bool],
    levels: &BinLevels,
    live: &[usize],
) -> CvResult {
    let nbins = levels.len();
    let mut bin_ll = vec![vec![0.0; POOLING_CANDIDATES.len()]; nbins];
    let mut bin_heldout = vec![0u64; nbins];
    let mut heldout = 0u64;
    // Clipped bins: scored per candidate in both modes, then read at the chosen pooling.
    let mut clip_own = 0.0;
    let mut clip_law = vec![0.0; POOLING_CANDIDATES.len()];
    let mut clip_samples = 0u64;
    let mut clip_scored = false;
    for &k in live {
        let train: Vec<NoiseHistogram> = total.iter().zip(folds[k].iter()).map(|(t, f)| subtract(t, f)).collect();
        let data = Data::new(&train, clipped, levels);
        for b in 0..nbins {
            let held = &folds[k][b];
            let nh = held.total();
            if nh == 0 {
                continue;
            }
            let (mu, var) = (data.law.mean[b], data.law.var[b]);
            if clipped[b] {
                clip_samples += nh;
                if data.stats[b].n > 0 {
                    let mut own = 0.0;
                    let prior = prior_on(held, mu, var);
                    pool_bin(&data, b, true, &[0], 0, |_, acc, cum| own = loglik(held, &prior, acc, cum));
                    clip_own += own;
                    clip_scored = true;
                } else {
                    clip_own = f64::NEG_INFINITY;
                }
                let prior = laplace_pmf(mu, var);
                pool_bin(&data, b, false, &POOLING_CANDIDATES, FILL_MIN_SAMPLES, |c, acc, cum| {
                    clip_law[c] += loglik_clamped(
                        held,
                        acc,
                        cum,
                        &prior,
                        levels.lo[b],
                        levels.hi[b],
                        (levels.floor, levels.white),
                    );
                });
                continue;
            }
            heldout += nh;
            bin_heldout[b] += nh;
            let prior = prior_on(held, mu, var);
            let bl = &mut bin_ll[b];
            pool_bin(&data, b, false, &POOLING_CANDIDATES, FILL_MIN_SAMPLES, |c, acc, cum| {
                bl[c] += loglik(held, &prior, acc, cum);
            });
        }
    }
    let ll: Vec<f64> = (0..POOLING_CANDIDATES.len()).map(|c| bin_ll.iter().map(|b| b[c]).sum()).collect();
    let best = argmax(&ll);
    CvResult {
        ll,
        bin_ll,
        bin_heldout,
        heldout,
        clip_ll: (clip_samples > 0 && clip_scored).then_some([clip_own, clip_law[best]]),
        clip_samples,
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

/// The plain empirical estimator: each bin's own histogram, the nearest bin with samples for
/// empty bins (no law, no pooling, no prior). The yardstick of method.md: the pack must not lose
/// to it on held-out frames.
pub fn plain_empirical(hists: &[NoiseHistogram]) -> Vec<BinModel> {
    let nb = hists.len();
    (0..nb)
        .map(|b| {
            let pick = (0..nb)
                .flat_map(|d| [b.checked_sub(d), (b + d < nb).then_some(b + d)])
                .flatten()
                .find(|&j| hists[j].total() > 0);
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
                    }
                }
                None => BinModel {
                    first: 0,
                    counts: vec![1],
                    samples: 0,
                    source: BinSource::Filled,
                    measured: None,
                    clipped: false,
                },
            }
        })
        .collect()
}

#[cfg(test)]
mod tests;
