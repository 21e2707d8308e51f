//! The pack's self-check (method.md, "Self-check"): what a user must see when a pack's noise
//! leaves what was measured. Run by calibration and, on any pack (older versions included), by
//! `inspect` and `report`.
//!
//! - **Variance off the measured variance**: per ISO, position and level group of
//!   [`GROUP_BINS`] bins, the sample-weighted mean variance of the pack's PMFs against the
//!   sample-weighted mean measured variance of the same (unclipped, measured) bins. Groups with
//!   fewer than [`MIN_GROUP_SAMPLES`] samples are skipped: their measured variance is itself
//!   uncertain by more than the tolerance. Off by more than [`VARIANCE_TOLERANCE`]: reported.
//! - **Variance off the robust spread** ([`spread_check`], at calibration, where the histograms
//!   are): the measured variance is no clean reference when some samples carry wide errors (a
//!   chart edge that moved, a display, flicker), since the pack is built from the same samples;
//!   their median absolute deviation hardly moves. A level group whose pack variance exceeds
//!   [`SPREAD_RATIO_LIMIT`] × `(1.4826·MAD)²` is reported, naming the chart's motion when the
//!   frames' registration measured it.
//! - **A fill that spans clipped bins**: a run of filled bins between an unclipped measured
//!   bin and a clipped one whose variance falls along the run, i.e. interpolated towards the
//!   clipped bin's shrunken variance (what version 1 packs did).

use crate::model::histogram::NoiseHistogram;
use crate::model::layout::POSITIONS;
use crate::model::pack::{BinModel, ModelPack};

/// Bins per level group of the variance check.
pub const GROUP_BINS: usize = 8;
/// Relative departure of the pack's variance from the measured one that is reported.
pub const VARIANCE_TOLERANCE: f64 = 0.10;
/// Measured samples a level group needs to be checked.
pub const MIN_GROUP_SAMPLES: u64 = 4000;
/// A bin whose PMF puts this share or more on the output range's edges is shaped by clipping.
pub const CLIP_MASS: f64 = 0.01;

/// The largest ratio of a level group's noise variance to its robust spread (`(1.4826·MAD)²`)
/// that the noise's own shape explains: 2.3 for a Student-t with 3 degrees of freedom, 1.35–1.66
/// for the 4–6 of the heaviest-tailed sensors in the random family; motion measured as noise
/// (a few per cent of samples with wide errors) raises it far more than it raises the MAD.
pub const SPREAD_RATIO_LIMIT: f64 = 2.5;

/// One finding of the self-check.
#[derive(Debug, Clone, PartialEq)]
pub enum Finding {
    /// The pack's variance leaves the measured one in a level group.
    Variance { iso: u32, pos: usize, name: &'static str, levels: (f64, f64), pack: f64, measured: f64, samples: u64 },
    /// A run of filled bins interpolates towards a clipped bin. `legacy`: the position was
    /// built by an estimator before clipping-aware fills (no estimate report), so recalibrating
    /// fixes it; otherwise the noise law fitted on the measured bins itself falls there.
    FillSpansClipped { iso: u32, pos: usize, name: &'static str, levels: (f64, f64), legacy: bool },
    /// The pack's variance is far wider than the measured samples' robust spread in a level
    /// group: a few samples with wide errors (something moved or flickered), not the noise's
    /// shape. `moved`: the largest registered shift of the ISO's frames (pixels), when the chart
    /// moved.
    Spread {
        iso: u32,
        pos: usize,
        name: &'static str,
        levels: (f64, f64),
        pack: f64,
        robust: f64,
        samples: u64,
        moved: Option<f64>,
    },
}

impl std::fmt::Display for Finding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Variance { iso, name, levels, pack, measured, samples, .. } => write!(
                f,
                "self-check: ISO {iso} {name} levels {:.0}–{:.0} DN: the pack's noise variance {pack:.3} DN² is {:+.0} % off the measured {measured:.3} DN² ({samples} samples)",
                levels.0,
                levels.1,
                (pack / measured - 1.0) * 100.0
            ),
            Self::FillSpansClipped { iso, name, levels, legacy: true, .. } => write!(
                f,
                "self-check: ISO {iso} {name} levels {:.0}–{:.0} DN: filled bins interpolate towards clipped bins (their variance falls towards the clip); recalibrate with this noisecal",
                levels.0, levels.1
            ),
            Self::Spread { iso, name, levels, pack, robust, samples, moved, .. } => {
                write!(
                    f,
                    "self-check: ISO {iso} {name} levels {:.0}–{:.0} DN: the pack's noise variance {pack:.3} DN² is {:.1}× the samples' robust spread ((1.4826·MAD)² = {robust:.3} DN², {samples} samples), more than heavy tails make: ",
                    levels.0,
                    levels.1,
                    pack / robust
                )?;
                match moved {
                    Some(px) => write!(
                        f,
                        "the chart moved between frames (up to {px:.2} px) and what registration could not take out is in the noise; re-take these bursts on a sturdier mount"
                    ),
                    None => write!(
                        f,
                        "something at these levels changed from frame to frame (a chart edge that moved, a display, flicker); re-take with the chart and the light steady"
                    ),
                }
            }
            Self::FillSpansClipped { iso, name, levels, legacy: false, .. } => write!(
                f,
                "self-check: ISO {iso} {name} levels {:.0}–{:.0} DN: the noise variance of the unmeasured bins falls towards the clipped ones, following the law fitted on sparse measured bins nearby; more frames at these levels would settle it",
                levels.0, levels.1
            ),
        }
    }
}

/// Runs every check on every calibrated ISO of a pack.
pub fn self_check(pack: &ModelPack) -> Vec<Finding> {
    let binning = pack.binning();
    let mut out = Vec::new();
    for m in pack.isos.iter().filter(|m| m.is_calibrated()) {
        for pos in 0..POSITIONS.min(m.positions.len()) {
            let name = pack.layout.cfa.position_name(pos);
            let bins = &m.positions[pos].bins;
            let level = |b: usize| binning.black[pos] as f64 + b as f64 * binning.bin_width as f64;
            for (g, group) in bins.chunks(GROUP_BINS).enumerate() {
                let (mut n, mut sp, mut sm) = (0u64, 0.0, 0.0);
                for b in group.iter().filter(|b| !b.clipped) {
                    let Some([_, v]) = b.measured else { continue };
                    let (_, pv) = b.moments();
                    n += b.samples;
                    sp += b.samples as f64 * pv;
                    sm += b.samples as f64 * v;
                }
                if n < MIN_GROUP_SAMPLES || sm <= 0.0 {
                    continue;
                }
                let (pv, mv) = (sp / n as f64, sm / n as f64);
                if (pv / mv - 1.0).abs() > VARIANCE_TOLERANCE {
                    let b0 = g * GROUP_BINS;
                    out.push(Finding::Variance {
                        iso: m.iso,
                        pos,
                        name,
                        levels: (level(b0), level(b0 + group.len())),
                        pack: pv,
                        measured: mv,
                        samples: n,
                    });
                }
            }
            // The share of a bin's PMF that lands on the codes where the sensor's output piles
            // up: a fill next to the clip is meant to be shrunk by it.
            let [floor, ceiling] = m.range[pos].map(f64::from);
            let clip_mass = |b: usize| {
                let bm = &bins[b];
                let c = binning.center(pos, b) as f64;
                let total: u64 = bm.counts.iter().sum();
                let at_edge: u64 = bm
                    .counts
                    .iter()
                    .enumerate()
                    .filter(|&(i, _)| {
                        let v = c + (bm.first + i as i32) as f64;
                        v >= ceiling || v <= floor
                    })
                    .map(|(_, &w)| w)
                    .sum();
                if total == 0 { 0.0 } else { at_edge as f64 / total as f64 }
            };
            let legacy = m.positions[pos].estimate.is_none();
            // Towards the floor the noise law itself falls (shot noise fades towards black, and
            // the estimator follows it there, method.md "Estimation" 3): only a legacy pack's
            // fill is suspect on that side.
            let towards_floor = |a: usize| a > 0 && bins[a - 1].clipped;
            out.extend(fill_spans(bins, clip_mass).into_iter().filter(|&(a, _)| legacy || !towards_floor(a)).map(
                |(a, b)| Finding::FillSpansClipped { iso: m.iso, pos, name, levels: (level(a), level(b + 1)), legacy },
            ));
        }
    }
    out
}

/// `1.4826 · MAD` of a histogram, squared (DN²): the variance of a normal law with the same
/// median absolute deviation. `None` for an empty histogram.
pub fn robust_var(h: &NoiseHistogram) -> Option<f64> {
    let total = h.total();
    if total == 0 {
        return None;
    }
    let half = total.div_ceil(2);
    let mut acc = 0u64;
    let mut median = 0usize;
    for (i, &c) in h.counts.iter().enumerate() {
        acc += c;
        if acc >= half {
            median = i;
            break;
        }
    }
    // Count of |i − median| ≤ d grows with d: the smallest d holding half the samples.
    let mut within = h.counts[median];
    let mut d = 0usize;
    while within < half {
        d += 1;
        if let Some(&c) = median.checked_sub(d).and_then(|j| h.counts.get(j)) {
            within += c;
        }
        if let Some(&c) = h.counts.get(median + d) {
            within += c;
        }
    }
    // A MAD of 0 (more than half the samples on one value) is the quantisation's: half a DN.
    let mad = (d as f64).max(0.5);
    Some((1.4826 * mad).powi(2))
}

/// The robust-spread check (see [`Finding::Spread`]): per ISO, position and level group of
/// [`GROUP_BINS`] bins with at least [`MIN_GROUP_SAMPLES`] measured, unclipped samples, the
/// pack's variance against the sample-weighted robust variance of the same bins' histograms
/// (`hists(iso, pos)`, summed over folds); beyond [`SPREAD_RATIO_LIMIT`], reported. `moved(iso)`
/// is the ISO's largest registered shift when the chart moved.
pub fn spread_check(
    pack: &ModelPack,
    hists: impl Fn(u32, usize) -> Option<Vec<NoiseHistogram>>,
    moved: impl Fn(u32) -> Option<f64>,
) -> Vec<Finding> {
    let binning = pack.binning();
    let mut out = Vec::new();
    for m in pack.isos.iter().filter(|m| m.is_calibrated()) {
        for pos in 0..POSITIONS.min(m.positions.len()) {
            let Some(hs) = hists(m.iso, pos) else { continue };
            let name = pack.layout.cfa.position_name(pos);
            let bins = &m.positions[pos].bins;
            let level = |b: usize| binning.black[pos] as f64 + b as f64 * binning.bin_width as f64;
            for (g, group) in bins.chunks(GROUP_BINS).enumerate() {
                let b0 = g * GROUP_BINS;
                let (mut n, mut sp, mut sr) = (0u64, 0.0, 0.0);
                for (k, b) in group.iter().enumerate().filter(|(_, b)| !b.clipped && b.measured.is_some()) {
                    let Some(r) = hs.get(b0 + k).and_then(robust_var) else { continue };
                    n += b.samples;
                    sp += b.samples as f64 * b.moments().1;
                    sr += b.samples as f64 * r;
                }
                if n < MIN_GROUP_SAMPLES || sr <= 0.0 {
                    continue;
                }
                let (pv, rv) = (sp / n as f64, sr / n as f64);
                if pv > SPREAD_RATIO_LIMIT * rv {
                    out.push(Finding::Spread {
                        iso: m.iso,
                        pos,
                        name,
                        levels: (level(b0), level(b0 + group.len())),
                        pack: pv,
                        robust: rv,
                        samples: n,
                        moved: moved(m.iso),
                    });
                }
            }
        }
    }
    out
}

/// Runs `a ..= b` of filled bins bounded by an unclipped measured bin on one side and a clipped
/// one on the other, whose variance falls towards the clipped side by more than the tolerance.
/// Only the part of the run whose PMFs stay clear of the output range counts (`clip_mass(bin)`
/// below [`CLIP_MASS`]): nearer the clip, a law fill is clipped as the sensor is, on purpose.
fn fill_spans(bins: &[BinModel], clip_mass: impl Fn(usize) -> f64) -> Vec<(usize, usize)> {
    let anchor = |b: &BinModel| !b.filled();
    let mut out = Vec::new();
    let mut i = 0;
    while i < bins.len() {
        if anchor(&bins[i]) {
            i += 1;
            continue;
        }
        let start = i;
        while i < bins.len() && !anchor(&bins[i]) {
            i += 1;
        }
        let end = i - 1;
        let (Some(lo), Some(hi)) = (start.checked_sub(1).map(|j| &bins[j]), bins.get(i)) else {
            continue;
        };
        if lo.clipped == hi.clipped {
            continue;
        }
        let (from, mut to) = if hi.clipped { (start, end) } else { (end, start) };
        while to != from && clip_mass(to) >= CLIP_MASS {
            to = if to > from { to - 1 } else { to + 1 };
        }
        if clip_mass(to) >= CLIP_MASS {
            continue;
        }
        let (vf, vt) = (bins[from].moments().1, bins[to].moments().1);
        if vt < vf * (1.0 - VARIANCE_TOLERANCE) {
            out.push((start, end));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::pack::BinSource;
    use crate::model::pmf::Pmf;

    fn gaussian(var: f64) -> Pmf {
        let sd = var.sqrt();
        let k = (8.0 * sd).ceil() as i32 + 1;
        Pmf::from_weights(-k, (-k..=k).map(|n| (-(n as f64).powi(2) / (2.0 * var)).exp())).expect("pmf")
    }

    fn bin(var: f64, measured: Option<f64>, source: BinSource, clipped: bool) -> BinModel {
        BinModel::estimated(
            &gaussian(var),
            if measured.is_some() { 1000 } else { 0 },
            source,
            measured.map(|v| [0.0, v]),
            clipped,
        )
    }

    /// Integer samples of `f(u)` at evenly spread quantiles `u`, as a histogram.
    fn histogram_of(n: usize, quantile: impl Fn(f64) -> f64) -> NoiseHistogram {
        let mut h = NoiseHistogram::default();
        for i in 0..n {
            h.add(quantile((i as f64 + 0.5) / n as f64).round() as i32);
        }
        h
    }

    fn normal_quantile(u: f64) -> f64 {
        // Bisection on the normal CDF (tests only).
        let (mut lo, mut hi) = (-10.0f64, 10.0f64);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if crate::math::special::normal_mass(-40.0, mid) < u { lo = mid } else { hi = mid }
        }
        0.5 * (lo + hi)
    }

    #[test]
    fn robust_spread_sees_contamination_that_heavy_tails_do_not_make() {
        // Normal noise, σ = 6: the robust variance is its variance (within quantisation).
        let clean = histogram_of(20_000, |u| 6.0 * normal_quantile(u));
        let r = robust_var(&clean).expect("samples");
        assert!((r / 36.0 - 1.0).abs() < 0.05, "robust var {r:.2} vs 36");
        // Student-t(3)-like tails (var/robust ≈ 2.3) stay under the limit; 5 % of samples with
        // errors 8× wider (a moving edge) push var/robust to 4: over it.
        let t3 = |u: f64| {
            let z = normal_quantile(u);
            6.0 * z * (1.0 + z * z / 6.0).sqrt()
        };
        let heavy = histogram_of(20_000, t3);
        let (_, hv) = heavy.moments();
        let ratio = hv / robust_var(&heavy).expect("samples");
        assert!(ratio < SPREAD_RATIO_LIMIT, "heavy tails alone: {ratio:.2}");
        let mut moved = histogram_of(19_000, |u| 6.0 * normal_quantile(u));
        moved.merge(&histogram_of(1_000, |u| 48.0 * normal_quantile(u)));
        let (_, mv) = moved.moments();
        let ratio = mv / robust_var(&moved).expect("samples");
        assert!(ratio > SPREAD_RATIO_LIMIT, "5 % moved: {ratio:.2}");
    }

    #[test]
    fn fill_towards_a_clipped_bin_is_found_and_a_law_fill_is_not() {
        use BinSource::*;
        // measured 10 | filled 9, 7, 5 | clipped measured 3: interpolated towards the clip.
        let bad = vec![
            bin(10.0, Some(10.0), Measured, false),
            bin(9.0, None, Filled, false),
            bin(7.0, None, Filled, false),
            bin(5.0, None, Filled, false),
            bin(3.0, Some(3.0), Measured, true),
        ];
        assert_eq!(fill_spans(&bad, |_| 0.0), vec![(1, 3)]);
        // Bin 3 touches the clip: bins 1–2 still fall (9 → 7), still found.
        assert_eq!(fill_spans(&bad, |b| if b == 3 { 0.5 } else { 0.0 }), vec![(1, 3)]);
        // A law fill that only falls where the clip shrinks it is not a finding.
        let clipped_law = vec![
            bin(10.0, Some(10.0), Measured, false),
            bin(10.5, None, Filled, false),
            bin(6.0, None, Filled, false),
            bin(3.0, Some(3.0), Measured, true),
        ];
        assert_eq!(fill_spans(&clipped_law, |_| 0.0), vec![(1, 2)]);
        assert!(fill_spans(&clipped_law, |b| if b == 2 { 0.2 } else { 0.0 }).is_empty());
        // The law keeps growing: nothing to report.
        let good = vec![
            bin(10.0, Some(10.0), Measured, false),
            bin(11.0, None, Filled, false),
            bin(12.0, None, Filled, false),
            bin(3.0, Some(3.0), Measured, true),
        ];
        assert!(fill_spans(&good, |_| 0.0).is_empty());
    }
}
