//! Conversion-gain switches between neighbouring calibrated ISOs (method.md, "ISO
//! interpolation"): the read term at black above a gap falls far below what a smooth single-gain
//! fit predicts across it. Interpolation never fits across a switch, and stretches no fit across
//! a gap whose read terms the data does not pin ([`GapCall::Undetermined`]).

use crate::derive::fine_levels::variance_at_black;
use crate::derive::noise_law::{NoiseParams, fit_params};
use crate::math::fit::{nn_poly_fit, poly_eval};
use crate::math::stats::median;
use crate::model::layout::POSITIONS;
use crate::model::pack::ModelPack;

/// Observed/predicted read-noise ratio below which a gap between two calibrated ISOs is a
/// conversion-gain switch.
pub const SWITCH_RATIO: f64 = 0.6;

/// How far from their median (either way) the CFA positions' input-referred read variances
/// `b / a²` of one ISO may lie, all but one of them, for a chart's intercepts to pin that ISO's
/// read term: the effect the detector looks for (a drop to [`SWITCH_RATIO`]). One position may
/// stray (phone12's ISO 800 from 6 000 samples per bin: 25.6 / 23.1 / 13.1 / 22.6 DN²). The positions share the read chain, so on one ISO they
/// differ by sampling only; intercepts extrapolated from patches far above black scatter by
/// far more (random sensor 22 at ISO 1024: 508 / 0 / 0 / 890 DN² where the dark frames give 56).
pub const PIN_SPREAD: f64 = 1.0 / SWITCH_RATIO;

/// A calibrated ISO as the switch detector and the interpolation plan read it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibratedLaw {
    pub iso: u32,
    /// The noise law per CFA position, as [`fit_params`] gives it (what a pack file's index
    /// stores).
    pub law: [Option<NoiseParams>; POSITIONS],
    /// The variance at black the ISO's dark step measured per position
    /// ([`variance_at_black`]), `None` without one.
    pub at_black: [Option<f64>; POSITIONS],
}

impl CalibratedLaw {
    /// The read terms the detector compares, per position: the law's shot slope `a` with `b` the
    /// dark step's variance at black where it was measured, else the fitted intercept; `None`
    /// where either is not positive.
    fn read_terms(&self) -> [Option<NoiseParams>; POSITIONS] {
        std::array::from_fn(|p| {
            let law = self.law[p]?;
            let b = self.at_black[p].unwrap_or(law.b);
            (law.a > 0.0 && b > 0.0 && b.is_finite()).then_some(NoiseParams { a: law.a, b })
        })
    }

    /// Whether the read terms are pinned: measured by a dark step at every position with a law,
    /// or, from the chart alone, positive at every position with all but one of them within
    /// [`PIN_SPREAD`] of their median, referred to the input (the detector reads the median).
    pub fn pinned(&self) -> bool {
        let terms = self.read_terms();
        let with_law: Vec<usize> = (0..POSITIONS).filter(|&p| self.law[p].is_some()).collect();
        if with_law.is_empty() || with_law.iter().any(|&p| terms[p].is_none()) {
            return false;
        }
        if with_law.iter().all(|&p| self.at_black[p].is_some()) {
            return true;
        }
        // The detector reads the median over positions: it stands when all but one position lie
        // within the spread of it.
        let input: Vec<f64> = with_law.iter().filter_map(|&p| terms[p].map(|t| t.input_read_variance())).collect();
        let mid = median(&input);
        let agree = input.iter().filter(|&&v| v <= PIN_SPREAD * mid && mid <= PIN_SPREAD * v).count();
        with_law.len() == POSITIONS && agree + 1 >= POSITIONS
    }
}

/// The laws of the pack's calibrated ISOs, sorted by ISO, each with its dark step's variance at
/// black where it has one.
pub fn calibrated_laws(pack: &ModelPack) -> Vec<CalibratedLaw> {
    let binning = pack.binning();
    pack.isos
        .iter()
        .filter(|m| m.is_calibrated())
        .map(|m| CalibratedLaw {
            iso: m.iso,
            law: std::array::from_fn(|pos| fit_params(&binning, m, pos)),
            at_black: std::array::from_fn(|pos| variance_at_black(pack.structure_of(m.iso), pos)),
        })
        .collect()
}

/// A conversion-gain switch between two neighbouring calibrated ISOs.
///
/// Physics: per ISO and position the HG fit gives `σ² = a·(l − black) + b` where the shot slope
/// `a` is the conversion gain (DN/e⁻) and `b = σ²_pre·a² + σ²_post` (read noise before and after
/// the gain). On one conversion gain, `b` is a non-negative function of `a²`, so it can be
/// predicted from the ISOs below the gap (and, backwards, from those above). At a switch to a
/// higher conversion gain the read noise referred to the input drops: `b` above the gap falls
/// far below the prediction while the shot slope keeps following ISO.
#[derive(Debug, Clone, PartialEq)]
pub struct GainSwitch {
    /// The highest calibrated ISO below the switch.
    pub below_iso: u32,
    /// The lowest calibrated ISO above the switch.
    pub above_iso: u32,
    /// Observed read variance `b` over what a smooth single-gain fit predicts across the gap,
    /// median over CFA positions (< [`SWITCH_RATIO`] here; ≈ 1 on a single-gain sensor).
    pub ratio: f64,
    /// Read variance referred to the input (`b / a²`, e⁻²), median over positions, at
    /// `below_iso` and at `above_iso`.
    pub input_read_var_below: f64,
    pub input_read_var_above: f64,
    /// CFA positions whose own ratio is below [`SWITCH_RATIO`].
    pub positions: usize,
}

impl GainSwitch {
    /// The ISO halfway between the switch's two calibrated ISOs in log ISO, rounded to a whole
    /// ISO: the one calibration that halves the range where the conversion gain is unknown.
    pub fn bisecting_iso(&self) -> u32 {
        ((self.below_iso as f64 * self.above_iso as f64).sqrt().round() as u32).clamp(self.below_iso, self.above_iso)
    }
}

impl std::fmt::Display for GainSwitch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "conversion-gain switch between ISO {} and {}: read noise {:.0} % of a smooth fit's prediction (input-referred {:.2} → {:.2} e⁻²)",
            self.below_iso,
            self.above_iso,
            100.0 * self.ratio,
            self.input_read_var_below,
            self.input_read_var_above
        )
    }
}

/// What the data says about the gap between two neighbouring calibrated ISOs.
#[derive(Debug, Clone, PartialEq)]
pub enum GapCall {
    /// Both sides' read terms are pinned and agree with one conversion gain.
    NoSwitch,
    /// A conversion-gain switch.
    Switch(GainSwitch),
    /// A side's read terms are not pinned ([`CalibratedLaw::pinned`]): the data can show neither.
    Undetermined,
}

/// One gap between neighbouring calibrated ISOs and what the data says about it.
#[derive(Debug, Clone, PartialEq)]
pub struct Gap {
    pub below_iso: u32,
    pub above_iso: u32,
    pub call: GapCall,
}

/// Conversion-gain switches between neighbouring calibrated ISOs of a pack.
pub fn detect_gain_switches(pack: &ModelPack) -> Vec<GainSwitch> {
    detect_laws(&calibrated_laws(pack))
}

/// The switches among [`gaps`].
pub fn detect_laws(laws: &[CalibratedLaw]) -> Vec<GainSwitch> {
    gaps(laws)
        .into_iter()
        .filter_map(|g| match g.call {
            GapCall::Switch(s) => Some(s),
            _ => None,
        })
        .collect()
}

/// Fits `b = q + p·a²` (non-negative) over the points and predicts `b` at `a`.
fn predict_read(points: &[NoiseParams], a: f64) -> Option<f64> {
    if points.len() < 2 {
        return None;
    }
    let scale = points.iter().map(|p| p.a * p.a).fold(1e-12, f64::max);
    let x: Vec<f64> = points.iter().map(|p| p.a * p.a / scale).collect();
    let y: Vec<f64> = points.iter().map(|p| p.b).collect();
    let w: Vec<f64> = y.iter().map(|b| 1.0 / b.max(1e-6).powi(2)).collect();
    let c = nn_poly_fit(&x, &y, &w, 1);
    Some(poly_eval(&c, a * a / scale))
}

/// Every gap between neighbouring calibrated ISOs (`laws` sorted by ISO) and its call: a gap is
/// judged only when both its ISOs are [pinned](CalibratedLaw::pinned), and the predictions
/// across it stand on pinned ISOs of the same segment only.
pub fn gaps(laws: &[CalibratedLaw]) -> Vec<Gap> {
    let n = laws.len();
    let terms: Vec<[Option<NoiseParams>; POSITIONS]> = laws.iter().map(CalibratedLaw::read_terms).collect();
    let pinned: Vec<bool> = laws.iter().map(CalibratedLaw::pinned).collect();
    let mut out = Vec::with_capacity(n.saturating_sub(1));
    // The first ISO of the current segment (no switch or unpinned ISO between it and `j`).
    let mut seg_start = 0usize;
    for j in 0..n.saturating_sub(1) {
        let (below_iso, above_iso) = (laws[j].iso, laws[j + 1].iso);
        if !(pinned[j] && pinned[j + 1]) {
            out.push(Gap { below_iso, above_iso, call: GapCall::Undetermined });
            seg_start = j + 1;
            continue;
        }
        let mut ratios = Vec::new();
        let mut below_r = Vec::new();
        let mut above_r = Vec::new();
        // Pinned ISOs past the gap, up to the next unpinned one.
        let above_end = (j + 1..(j + 3).min(n)).take_while(|&i| pinned[i]).last().map_or(j + 1, |i| i + 1);
        for pos in 0..POSITIONS {
            let (Some(pj), Some(pk)) = (terms[j][pos], terms[j + 1][pos]) else {
                continue;
            };
            let below: Vec<NoiseParams> =
                (seg_start.max(j.saturating_sub(2))..=j).filter_map(|i| terms[i][pos]).collect();
            let above: Vec<NoiseParams> = (j + 1..above_end).filter_map(|i| terms[i][pos]).collect();
            let mut r = pk.b / pj.b;
            let mut preds = Vec::new();
            if let Some(pred) = predict_read(&below, pk.a) {
                preds.push((pk.b / pred.max(1e-12)).ln());
            }
            if let Some(pred) = predict_read(&above, pj.a) {
                preds.push((pred / pj.b).ln());
            }
            if !preds.is_empty() {
                r = r.min((preds.iter().sum::<f64>() / preds.len() as f64).exp());
            }
            ratios.push(r);
            below_r.push(pj.input_read_variance());
            above_r.push(pk.input_read_variance());
        }
        let ratio = median(&ratios);
        let call = if ratios.is_empty() {
            GapCall::Undetermined
        } else if ratio < SWITCH_RATIO {
            seg_start = j + 1;
            GapCall::Switch(GainSwitch {
                below_iso,
                above_iso,
                ratio,
                input_read_var_below: median(&below_r),
                input_read_var_above: median(&above_r),
                positions: ratios.iter().filter(|&&r| r < SWITCH_RATIO).count(),
            })
        } else {
            GapCall::NoSwitch
        };
        out.push(Gap { below_iso, above_iso, call });
    }
    out
}

/// What one more capture would settle about the conversion gain between the calibrated ISOs
/// (`laws` sorted by ISO), one sentence each: per switch whose gap holds a whole ISO between its
/// ends, the ISO halving the gap ([`GainSwitch::bisecting_iso`]); per undetermined gap, the ISOs
/// whose read term the chart does not pin and the dark step that would.
pub fn capture_advice(laws: &[CalibratedLaw]) -> Vec<String> {
    let pinned = |iso: u32| laws.iter().find(|l| l.iso == iso).is_some_and(CalibratedLaw::pinned);
    gaps(laws)
        .into_iter()
        .filter_map(|g| match g.call {
            GapCall::Switch(s) => {
                let half = s.bisecting_iso();
                (half > s.below_iso && half < s.above_iso).then(|| {
                    format!(
                        "the sensor switches conversion gain between ISO {} and {}: which gain it uses at the ISOs between them is unknown, and they are modelled from the nearer side; calibrate ISO {half} as well (halfway in log ISO) to halve that range",
                        s.below_iso, s.above_iso
                    )
                })
            }
            GapCall::Undetermined => {
                let unpinned: Vec<String> =
                    [g.below_iso, g.above_iso].into_iter().filter(|&k| !pinned(k)).map(|k| k.to_string()).collect();
                Some(format!(
                    "whether the conversion gain changes between ISO {} and {} is unknown: the chart does not pin the read noise at black of ISO {} (its darkest patches lie far above black, or its colour positions disagree), so interpolation does not reach across; dark frames (lens covered) at these ISOs settle it",
                    g.below_iso,
                    g.above_iso,
                    unpinned.join(" and ")
                ))
            }
            GapCall::NoSwitch => None,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A single-gain sensor's laws at `isos` (gain ∝ ISO, 2 e⁻ read noise before the gain and
    /// 1 DN after it), with a dark step when `dark`; `above` switches to 0.8 e⁻ from that ISO.
    fn laws(isos: &[u32], switch_at: Option<u32>, dark: bool) -> Vec<CalibratedLaw> {
        isos.iter()
            .map(|&iso| {
                let a = iso as f64 / 400.0;
                let pre = if switch_at.is_some_and(|s| iso >= s) { 0.8 } else { 2.0 };
                let b = pre * pre * a * a + 1.0;
                CalibratedLaw {
                    iso,
                    law: [Some(NoiseParams { a, b }); POSITIONS],
                    at_black: [dark.then_some(b); POSITIONS],
                }
            })
            .collect()
    }

    fn calls(l: &[CalibratedLaw]) -> Vec<&'static str> {
        gaps(l)
            .iter()
            .map(|g| match g.call {
                GapCall::NoSwitch => "none",
                GapCall::Switch(_) => "switch",
                GapCall::Undetermined => "undetermined",
            })
            .collect()
    }

    #[test]
    fn pinned_laws_show_the_switch_and_only_it() {
        let isos = [100, 200, 400, 800, 1600, 3200];
        assert_eq!(calls(&laws(&isos, None, false)), ["none"; 5]);
        assert_eq!(calls(&laws(&isos, Some(800), false)), ["none", "none", "switch", "none", "none"]);
        assert_eq!(calls(&laws(&isos, Some(800), true)), ["none", "none", "switch", "none", "none"]);
        let sw = detect_laws(&laws(&isos, Some(800), false));
        assert_eq!((sw[0].below_iso, sw[0].above_iso, sw[0].bisecting_iso()), (400, 800, 566));
        let advice = capture_advice(&laws(&[100, 200, 800, 3200], Some(800), false));
        assert_eq!(advice.len(), 1, "{advice:?}");
        assert!(advice[0].contains("between ISO 200 and 800") && advice[0].contains("calibrate ISO 400"), "{advice:?}");
    }

    #[test]
    fn intercepts_that_disagree_call_nothing() {
        // Random sensor 22's ISO 1024 from a chart: 508 / 0 / 0 / 890 DN² where the dark frames
        // give 56; beside it 0.6× the truth would read as a switch on the two positive ones.
        let isos = [256, 1024, 2048];
        let mut l = laws(&isos, None, false);
        let a = l[1].law[0].expect("law").a;
        for (p, b) in [508.0, 0.0, 0.0, 890.0].into_iter().enumerate() {
            l[1].law[p] = Some(NoiseParams { a, b });
        }
        assert!(!l[1].pinned());
        assert_eq!(calls(&l), ["undetermined", "undetermined"]);
        // One position astray is outvoted; two disagreeing by more than the effect are not pinned.
        let b = l[0].law[0].expect("law").b;
        for (p, f) in [1.0, 1.8, 1.0, 1.0].into_iter().enumerate() {
            l[0].law[p] = Some(NoiseParams { a: l[0].law[p].expect("law").a, b: b * f });
        }
        assert!(l[0].pinned());
        for (p, f) in [0.55, 1.8, 1.0, 1.0].into_iter().enumerate() {
            l[0].law[p] = Some(NoiseParams { a: l[0].law[p].expect("law").a, b: b * f });
        }
        assert!(!l[0].pinned());
        // The dark step's variance at black pins them again: the truth, no switch.
        for (k, law) in l.iter_mut().enumerate() {
            law.at_black = laws(&isos, None, false)[k].law.map(|p| p.map(|p| p.b));
        }
        assert_eq!(calls(&l), ["none", "none"]);
        let advice = capture_advice(&chart(&l));
        assert!(advice.iter().any(|a| a.contains("ISO 1024") && a.contains("dark frames")), "{advice:?}");
    }

    fn chart(l: &[CalibratedLaw]) -> Vec<CalibratedLaw> {
        l.iter().map(|c| CalibratedLaw { at_black: [None; POSITIONS], ..*c }).collect()
    }
}
