//! Which calibrated ISOs an interpolation stands on: the segment between conversion-gain
//! switches, the bracketing neighbours, the shape sources.

use crate::derive::gain_switch::{GainSwitch, detect_laws};
use crate::derive::noise_law::{NoiseParams, fit_params};
use crate::error::ModelError;
use crate::model::layout::POSITIONS;
use crate::model::pack::ModelPack;

/// Where the normalised shape of an interpolated PMF comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShapeSource {
    /// The nearest calibrated ISO (in log ISO), as in the paper.
    Nearest,
    /// The standardised quantile functions of the two bracketing calibrated ISOs, blended
    /// linearly in log ISO (the default; see the module docs).
    QuantileBlend,
}

/// Options of [`interpolate_with`](super::interpolate_with).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InterpOptions {
    pub shape: ShapeSource,
    /// Calibrated ISOs per fit, 2–4 (default 4: the bracketing pair and one more each side).
    pub max_neighbours: usize,
}

impl Default for InterpOptions {
    fn default() -> Self {
        Self { shape: ShapeSource::QuantileBlend, max_neighbours: 4 }
    }
}

/// How far extrapolation may reach beyond the calibrated ISOs (a factor: 16 = 4 stops).
pub const MAX_EXTRAPOLATION: u64 = 16;

/// What an interpolation of one ISO will stand on.
#[derive(Debug, Clone, PartialEq)]
pub struct InterpPlan {
    pub iso: u32,
    /// Outside the calibrated range (only when extrapolation was allowed).
    pub extrapolated: bool,
    /// Every calibrated ISO on the target's side of all conversion-gain switches.
    pub segment: Vec<u32>,
    /// The calibrated ISOs the mean and variance fits use (sorted).
    pub neighbours: Vec<u32>,
    /// The calibrated ISO(s) the normalised shape comes from (one, or the bracketing two when
    /// blended).
    pub shape_from: Vec<u32>,
    /// Switches next to the segment: calibrated ISOs beyond them were not used.
    pub avoided: Vec<GainSwitch>,
    /// Set when the target lies strictly between the two ISOs of a switch: which conversion
    /// gain the camera uses there is unknown, and the nearer side (in log ISO; the upper side on
    /// a tie) was used. Calibrate that ISO to be sure.
    pub in_switch_gap: Option<GainSwitch>,
    pub shape: ShapeSource,
}

/// A calibrated ISO as a plan reads it: its noise law per CFA position, as
/// [`fit_params`] gives it (which conversion-gain switches lie between calibrated ISOs).
pub type CalibratedLaw = (u32, [Option<NoiseParams>; POSITIONS]);

/// The noise laws of the pack's calibrated ISOs, sorted by ISO.
pub fn calibrated_laws(pack: &ModelPack) -> Vec<CalibratedLaw> {
    let binning = pack.binning();
    pack.isos
        .iter()
        .filter(|m| m.is_calibrated())
        .map(|m| (m.iso, std::array::from_fn(|pos| fit_params(&binning, m, pos))))
        .collect()
}

/// Plans the interpolation of `iso` with the default options.
pub fn plan(pack: &ModelPack, iso: u32, extrapolate: bool) -> Result<InterpPlan, ModelError> {
    plan_with(pack, iso, extrapolate, &InterpOptions::default())
}

/// Plans the interpolation of `iso`: which calibrated ISOs it will use and which switches it
/// avoids. Errors: no calibrated ISO ([`ModelError::IsoMissing`]), outside the calibrated
/// range without `extrapolate` ([`ModelError::IsoOutOfRange`]).
pub fn plan_with(
    pack: &ModelPack,
    iso: u32,
    extrapolate: bool,
    opts: &InterpOptions,
) -> Result<InterpPlan, ModelError> {
    plan_among(&calibrated_laws(pack), pack.isos.is_empty(), iso, extrapolate, opts)
}

/// [`plan_with`] from the calibrated ISOs' noise laws alone (`laws`, sorted by ISO, as
/// [`calibrated_laws`] gives them; `no_isos` when the pack holds no ISO at all): the plan of a
/// pack whose ISOs are not decoded yet, the same as the decoded pack's.
pub fn plan_among(
    laws: &[CalibratedLaw],
    no_isos: bool,
    iso: u32,
    extrapolate: bool,
    opts: &InterpOptions,
) -> Result<InterpPlan, ModelError> {
    // Every calibrated ISO except the target may be stood on.
    let models: Vec<CalibratedLaw> = laws.iter().filter(|(k, _)| *k != iso).copied().collect();
    if models.is_empty() {
        return Err(ModelError::IsoMissing {
            iso,
            available: if no_isos { "none".into() } else { format!("none calibrated besides ISO {iso}") },
        });
    }
    let isos: Vec<u32> = models.iter().map(|(k, _)| *k).collect();
    let (min, max) = (isos[0], isos[isos.len() - 1]);
    let outside = iso < min || iso > max;
    if outside && !extrapolate {
        return Err(ModelError::IsoOutOfRange { iso, min, max });
    }
    if outside && (iso as u64 > max as u64 * MAX_EXTRAPOLATION || (iso as u64) * MAX_EXTRAPOLATION < min as u64) {
        return Err(ModelError::Unsupported(format!(
            "ISO {iso} is more than {} stops beyond the calibrated ISOs {min}–{max}: extrapolating that far is guesswork; calibrate an ISO nearer to it, or ask for one within {}–{}",
            MAX_EXTRAPOLATION.ilog2(),
            min.div_ceil(MAX_EXTRAPOLATION as u32).max(1),
            (max as u64 * MAX_EXTRAPOLATION).min(u32::MAX as u64)
        )));
    }
    let switches = detect_laws(&models);
    // Segments: index ranges of `isos` between switches.
    let mut bounds = vec![0usize];
    for s in &switches {
        if let Some(i) = isos.iter().position(|&k| k == s.above_iso) {
            bounds.push(i);
        }
    }
    bounds.push(isos.len());
    let segments: Vec<(usize, usize)> = bounds.windows(2).map(|w| (w[0], w[1])).collect();
    let mut in_switch_gap = None;
    let seg_idx = if iso < min {
        0
    } else if iso > max {
        segments.len() - 1
    } else if let Some(si) = segments.iter().position(|&(a, b)| isos[a] <= iso && iso <= isos[b - 1]) {
        si
    } else {
        // In the gap of a switch: the nearer side in log ISO.
        let si = segments.iter().position(|&(a, _)| isos[a] > iso).unwrap_or(segments.len() - 1);
        let below = isos[segments[si - 1].1 - 1] as f64;
        let above = isos[segments[si].0] as f64;
        in_switch_gap = switches.get(si - 1).cloned();
        if (iso as f64 / below).ln() < (above / iso as f64).ln() { si - 1 } else { si }
    };
    let (s0, s1) = segments[seg_idx];
    let segment: Vec<u32> = isos[s0..s1].to_vec();
    let avoided: Vec<GainSwitch> = switches
        .iter()
        .filter(|s| s.above_iso == segment[0] || s.below_iso == segment[segment.len() - 1])
        .cloned()
        .collect();
    let k = opts.max_neighbours.clamp(2, 4);
    let at = segment.partition_point(|&x| x < iso);
    let bracketed = at > 0 && at < segment.len();
    let neighbours: Vec<u32> = if bracketed {
        let (mut lo, mut hi) = (at - 1, at); // inclusive indices
        let len = segment.len();
        // One more on each side first (k = 4), then whichever side is nearer in log ISO.
        if k == 4 {
            lo = lo.saturating_sub(1);
            if hi + 1 < len {
                hi += 1;
            }
        }
        while hi - lo + 1 < k && (lo > 0 || hi + 1 < len) {
            let dl = (lo > 0).then(|| (iso as f64 / segment[lo - 1] as f64).ln());
            let dh = (hi + 1 < len).then(|| (segment[hi + 1] as f64 / iso as f64).ln());
            match (dl, dh) {
                (Some(a), Some(b)) if a <= b => lo -= 1,
                (Some(_), None) => lo -= 1,
                _ => hi += 1,
            }
        }
        segment[lo..=hi].to_vec()
    } else {
        let m = k.min(3).min(segment.len());
        if at == 0 { segment[..m].to_vec() } else { segment[segment.len() - m..].to_vec() }
    };
    let shape_from = if bracketed {
        let (lo, hi) = (segment[at - 1], segment[at]);
        match opts.shape {
            ShapeSource::QuantileBlend => vec![lo, hi],
            ShapeSource::Nearest => {
                if (iso as f64 / lo as f64).ln() <= (hi as f64 / iso as f64).ln() {
                    vec![lo]
                } else {
                    vec![hi]
                }
            }
        }
    } else if at == 0 {
        vec![segment[0]]
    } else {
        vec![segment[segment.len() - 1]]
    };
    Ok(InterpPlan {
        iso,
        extrapolated: outside,
        segment,
        neighbours,
        shape_from,
        avoided,
        in_switch_gap,
        shape: opts.shape,
    })
}
