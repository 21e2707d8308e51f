//! Which calibrated ISOs an interpolation stands on: the segment between conversion-gain
//! switches, the bracketing neighbours, the shape sources.

pub use crate::derive::gain_switch::{CalibratedLaw, calibrated_laws};
use crate::derive::gain_switch::{GainSwitch, Gap, GapCall, gaps};
use crate::error::ModelError;
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
    /// The calibrated ISOs the target's model may stand on: those on its side of every
    /// conversion-gain switch, up to the nearest gaps whose read terms are not pinned (see
    /// `unpinned`).
    pub segment: Vec<u32>,
    /// The calibrated ISOs the mean and variance fits use (sorted).
    pub neighbours: Vec<u32>,
    /// The calibrated ISO(s) the normalised shape comes from (one, or the bracketing two when
    /// blended).
    pub shape_from: Vec<u32>,
    /// Switches next to the segment: calibrated ISOs beyond them were not used.
    pub avoided: Vec<GainSwitch>,
    /// Gaps next to the segment whose read terms the data does not pin
    /// ([`GapCall::Undetermined`]: a switch there can be neither shown nor ruled out), as
    /// (below, above) ISO: calibrated ISOs beyond them were not used either. When the target
    /// lies inside such a gap, the segment is the two ISOs around it.
    pub unpinned: Vec<(u32, u32)>,
    /// Set when the target lies strictly between the two ISOs of a switch: which conversion
    /// gain the camera uses there is unknown, and the nearer side (in log ISO; the lower side on
    /// a tie) was used. Calibrate that ISO to be sure.
    pub in_switch_gap: Option<GainSwitch>,
    pub shape: ShapeSource,
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
    let models: Vec<CalibratedLaw> = laws.iter().filter(|l| l.iso != iso).copied().collect();
    if models.is_empty() {
        return Err(ModelError::IsoMissing {
            iso,
            available: if no_isos { "none".into() } else { format!("none calibrated besides ISO {iso}") },
        });
    }
    let isos: Vec<u32> = models.iter().map(|l| l.iso).collect();
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
    let gaps = gaps(&models);
    // Runs: index ranges of `isos` between gaps that are switches or undetermined.
    let mut bounds = vec![0usize];
    bounds.extend(gaps.iter().enumerate().filter(|(_, g)| g.call != GapCall::NoSwitch).map(|(i, _)| i + 1));
    bounds.push(isos.len());
    let runs: Vec<(usize, usize)> = bounds.windows(2).map(|w| (w[0], w[1])).collect();
    let mut in_switch_gap = None;
    let (s0, s1) = if iso < min {
        runs[0]
    } else if iso > max {
        runs[runs.len() - 1]
    } else if let Some(&run) = runs.iter().find(|&&(a, b)| isos[a] <= iso && iso <= isos[b - 1]) {
        run
    } else {
        // In a gap between two runs: index `a` of the run above.
        let ri = runs.iter().position(|&(a, _)| isos[a] > iso).unwrap_or(runs.len() - 1);
        let (below_run, above_run) = (runs[ri - 1], runs[ri]);
        match &gaps[above_run.0 - 1].call {
            GapCall::Switch(s) => {
                // Which gain the camera uses here is unknown: the nearer side in log ISO, the
                // lower (low-gain, larger read noise) one on a tie, compared exactly:
                // iso/below ≤ above/iso.
                in_switch_gap = Some(s.clone());
                let below = isos[below_run.1 - 1] as u64;
                let above = isos[above_run.0] as u64;
                if (iso as u64) * (iso as u64) <= below * above { below_run } else { above_run }
            }
            // Not pinned: the two ISOs around the target, no further.
            _ => (above_run.0 - 1, above_run.0 + 1),
        }
    };
    let segment: Vec<u32> = isos[s0..s1].to_vec();
    let next_to = |g: &Gap| g.above_iso == segment[0] || g.below_iso == segment[segment.len() - 1];
    let avoided: Vec<GainSwitch> = gaps
        .iter()
        .filter(|g| next_to(g))
        .filter_map(|g| match &g.call {
            GapCall::Switch(s) => Some(s.clone()),
            _ => None,
        })
        .collect();
    let within = |g: &Gap| g.below_iso >= segment[0] && g.above_iso <= segment[segment.len() - 1];
    let unpinned: Vec<(u32, u32)> = gaps
        .iter()
        .filter(|g| (next_to(g) || within(g)) && g.call == GapCall::Undetermined)
        .map(|g| (g.below_iso, g.above_iso))
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
        unpinned,
        in_switch_gap,
        shape: opts.shape,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::derive::gain_switch::CalibratedLaw;
    use crate::derive::noise_law::NoiseParams;
    use crate::model::layout::POSITIONS;

    /// A sensor's laws at `isos` (gain ∝ ISO, 2 e⁻ read noise before the gain and 1 DN after
    /// it, 0.8 e⁻ from `switch_at` on), each with a dark step (here, rather than in
    /// `gain_switch.rs`'s tests: `gain_switch.rs` must not use this file, which uses it).
    fn laws(isos: &[u32], switch_at: u32) -> Vec<CalibratedLaw> {
        isos.iter()
            .map(|&iso| {
                let a = iso as f64 / 400.0;
                let pre = if iso >= switch_at { 0.8 } else { 2.0 };
                let b = pre * pre * a * a + 1.0;
                CalibratedLaw::new(iso, [Some(NoiseParams { a, b }); POSITIONS], [Some(b); POSITIONS])
            })
            .collect()
    }

    #[test]
    fn a_tie_in_a_switch_gap_takes_the_low_gain_side() {
        // Random 22 (switch between 256 and 1024, at 1024 in truth): ISO 512 is halfway.
        let l = laws(&[128, 256, 1024, 2048], 1024);
        let opts = InterpOptions::default();
        let plan = |iso| plan_among(&l, false, iso, false, &opts).expect("inside");
        assert!(plan(512).in_switch_gap.is_some());
        assert!(plan(512).neighbours.iter().all(|&k| k <= 256), "{:?}", plan(512));
        assert!(plan(513).neighbours.iter().all(|&k| k >= 1024), "{:?}", plan(513));
        assert!(plan(511).neighbours.iter().all(|&k| k <= 256), "{:?}", plan(511));
    }
}
