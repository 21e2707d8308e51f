//! Conversion-gain switches between neighbouring calibrated ISOs (method.md, "ISO
//! interpolation"): the read term at black above a gap falls far below what a smooth single-gain
//! fit predicts across it. Interpolation never fits across a switch, and stretches no fit across
//! a gap whose read terms the data does not pin ([`GapCall::Undetermined`]).

use crate::derive::noise_law::{NoiseParams, fit_params};
use crate::math::censored::unclamped_variance;
use crate::math::fit::{nn_poly_fit, poly_eval};
use crate::math::stats::median;
use crate::model::codes::CodeLattice;
use crate::model::layout::{POSITIONS, SensorLayout};
use crate::model::pack::{IsoModel, ModelPack};
use crate::model::structure::IsoStructure;

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

/// Measured over measured read term across a gap (`b` above over `b` below, median over
/// positions, both from dark frames) below which the gap is a switch whatever the fits predict.
/// On one conversion gain `b = q + p·a²` cannot fall as the ISO rises, so the bound is 1; dark
/// frames measure `b` to about 1 % (16 frames), and the pattern terms they carry move it by a
/// few %. Random sensor 13 (high gain from ISO 192) reads 0.69 from ISO 160 to 200, while the
/// high-gain line through ISO 200 and 320 predicts ISO 160 at 0.59–0.61 × its `b` (at the
/// simulator's true gains too): beside [`SWITCH_RATIO`] a call by rounding. The dark frames'
/// `b` must be the spread before the output's clamp at its floor ([`read_at_black`]): random
/// sensor 19 (10 bits, black 13.5 DN, single gain) clamps 26 % of its dark pixels at ISO 500
/// and 41 % at ISO 1600, which measured 0.64 and 0.43 of the truth and read as a drop to 0.66.
pub const DROP_RATIO: f64 = 0.8;

/// The read term at black a dark step measured at position `pos`, as the detector compares it:
/// the temporal variance with the output's clamp at its floor undone
/// ([`unclamped_variance`]; `headroom` is the black level's distance above the floor, DN) plus
/// the frame offsets' variance and the codes' rounding (as
/// [`crate::derive::fine_levels::variance_at_black`]). The pattern's change from the reference
/// (`in_pixel_noise`, which the pixel PMFs hold and synthesis needs) is not read noise: a
/// dark-signal non-uniformity grows as `(a − a_ref)²`, not as `q + p·a²`. `None` without dark
/// frames, or when the black level is not above the floor (half the dark pixels or more on
/// it: the spread's width is then not in the data).
pub fn read_at_black(structure: Option<&IsoStructure>, pos: usize, headroom: f64) -> Option<f64> {
    let st = structure?;
    let fpn = st.fpn.as_ref()?;
    let temporal = fpn.temporal_var[pos];
    if !(temporal.is_finite() && temporal > 0.0) {
        return None;
    }
    let frames = st.frames.as_ref().map_or(0.0, |f| f.variance(pos));
    let v = unclamped_variance(temporal, headroom)? + frames + 1.0 / 12.0;
    v.is_finite().then_some(v)
}

/// Per position, the black level's distance above the lowest code the ISO's output writes
/// (its clamp: [`IsoModel::range`]'s floor), DN.
fn headroom(layout: &SensorLayout, model: Option<&IsoModel>, pos: usize) -> f64 {
    layout.black[pos] as f64 - model.map_or(0.0, |m| m.range[pos][0] as f64)
}

/// A calibrated ISO as the switch detector and the interpolation plan read it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibratedLaw {
    pub iso: u32,
    /// The noise law per CFA position, as [`fit_params`] gives it (what a pack file's index
    /// stores).
    pub law: [Option<NoiseParams>; POSITIONS],
    /// The read variance at black the ISO's dark step measured per position
    /// ([`read_at_black`]), `None` without one.
    pub at_black: [Option<f64>; POSITIONS],
    /// The ISO's measured brightness over nominal per position ([`crate::model::pack::IsoModel::gain_ratio`]): the
    /// law's `a` is per DN of the reference's level scaled by the ISO ratio, so the conversion
    /// gain is `a / gain_ratio` (random sensor 62, gain ∝ ISO^1.19: the laws' `a` run 1.30 ×
    /// and 1.64 × the conversion gain at 4 and 16 × base).
    pub gain_ratio: [f64; POSITIONS],
    /// The digital gain the ISO's code lattice shows ([`digital_gain`]; 1 without a lattice).
    pub digital_gain: f64,
}

impl CalibratedLaw {
    /// A calibrated ISO with gain exactly ∝ ISO and no digital gain (what a law alone shows).
    pub fn new(iso: u32, law: [Option<NoiseParams>; POSITIONS], at_black: [Option<f64>; POSITIONS]) -> Self {
        Self { iso, law, at_black, gain_ratio: [1.0; POSITIONS], digital_gain: 1.0 }
    }

    /// A calibrated ISO's `law` with what the rest comes from: its dark step's read terms at black
    /// ([`read_at_black`], the clamp's headroom from `model`'s output range), its gain ratios and
    /// its lattice's digital gain (`model` the ISO's fields, `None`: none known).
    pub fn measured(
        iso: u32,
        law: [Option<NoiseParams>; POSITIONS],
        layout: &SensorLayout,
        model: Option<&IsoModel>,
        structure: Option<&IsoStructure>,
    ) -> Self {
        Self {
            iso,
            law,
            at_black: std::array::from_fn(|p| read_at_black(structure, p, headroom(layout, model, p))),
            gain_ratio: model.map_or([1.0; POSITIONS], |m| m.gain_ratio),
            digital_gain: model.map_or(1.0, |m| digital_gain(&m.lattice)),
        }
    }

    /// The read terms the detector compares, per position, at the ADC (before the digital gain
    /// `d`): the conversion gain `a / (gain_ratio · d)` with `b / d²`, `b` the dark step's
    /// variance at black where it was measured, else the fitted intercept; `None` where either
    /// is not positive. On one conversion gain `b = q + p·a²` holds there; after a digital gain
    /// the read noise after the analog gain is `d` × larger (random sensor 9: ISO 1000 is ISO
    /// 800's analog gain × 1.25, and its `b` 1.56 × ISO 800's read as a steep `p`).
    fn read_terms(&self) -> [Option<NoiseParams>; POSITIONS] {
        std::array::from_fn(|p| {
            let law = self.law[p]?;
            let b = self.at_black[p].unwrap_or(law.b);
            let (g, d) = (self.gain_ratio[p], self.digital_gain);
            let ok = law.a > 0.0 && b > 0.0 && b.is_finite() && g > 0.0 && g.is_finite() && d >= 1.0 && d.is_finite();
            ok.then(|| NoiseParams { a: law.a / (g * d), b: b / (d * d) })
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

/// The laws of the pack's calibrated ISOs, sorted by ISO, each with its dark step's read term at
/// black where it has one, its gain ratios and its digital gain.
pub fn calibrated_laws(pack: &ModelPack) -> Vec<CalibratedLaw> {
    let binning = pack.binning();
    pack.isos
        .iter()
        .filter(|m| m.is_calibrated())
        .map(|m| {
            let law = std::array::from_fn(|pos| fit_params(&binning, m, pos));
            CalibratedLaw::measured(m.iso, law, &pack.layout, Some(m), pack.structure_of(m.iso))
        })
        .collect()
}

/// The digital gain a code lattice shows: a gain `d` after the ADC writes `k` of every `n`
/// codes with `n / k = d` (1.25: 4 of every 5); the median over the positions with a lattice, 1
/// without one.
pub fn digital_gain(lattice: &[Option<CodeLattice>; POSITIONS]) -> f64 {
    let d: Vec<f64> = lattice
        .iter()
        .flatten()
        .filter(|l| l.allowed != 0)
        .map(|l| l.period as f64 / l.allowed.count_ones() as f64)
        .collect();
    if d.is_empty() { 1.0 } else { median(&d).max(1.0) }
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

/// How far apart (as a factor) the squared conversion gains of the points a prediction stands on
/// must lie for their read terms to show a slope `p`: two ISOs on nearly one analog gain (random
/// sensor 9's ISO 800 and ISO 1000 = 800 × 1.25 digital: conversion gains 2 % apart) differ in
/// `b` by their sampling and pattern terms only, and a line through them extrapolates those.
/// One third of a stop in a gain ∝ ISO (a factor 1.26 in `a`, 1.59 in `a²`) clears it.
pub const MIN_SLOPE_SPAN: f64 = 1.5;

/// Fits `b = q + p·a²` (non-negative) over the points and predicts `b` at `a`; `None` with
/// fewer than two points or when their `a²` span less than [`MIN_SLOPE_SPAN`].
fn predict_read(points: &[NoiseParams], a: f64) -> Option<f64> {
    if points.len() < 2 {
        return None;
    }
    let (lo, hi) = points.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), p| (lo.min(p.a), hi.max(p.a)));
    if hi * hi < MIN_SLOPE_SPAN * lo * lo {
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
        let mut drops = Vec::new();
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
            if laws[j].at_black[pos].is_some() && laws[j + 1].at_black[pos].is_some() {
                drops.push(r);
            }
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
        } else if ratio < SWITCH_RATIO || (drops.len() == ratios.len() && median(&drops) < DROP_RATIO) {
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
                CalibratedLaw::new(iso, [Some(NoiseParams { a, b }); POSITIONS], [dark.then_some(b); POSITIONS])
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

    /// Random sensor 62's chain (dark-frame read terms, gain ∝ ISO^1.187 against a reference at
    /// ISO 80, high gain from ISO 960): read 0.638 e⁻ + 1.695 DN below, 0.191 e⁻ + 1.583 DN above,
    /// row noise folded into the pre-gain term; `a` as the laws carry it, the conversion gain
    /// times the gain ratio.
    fn sensor_62(isos: &[u32], with_ratio: bool) -> Vec<CalibratedLaw> {
        isos.iter()
            .map(|&iso| {
                let ratio = (iso as f64 / 80.0).powf(0.187);
                let conv = 3.185 * (iso as f64 / 80.0) * ratio;
                let (pre, post) = if iso >= 960 { (0.217, 1.583) } else { (0.646, 1.695) };
                let b = (pre * conv).powi(2) + post * post;
                CalibratedLaw {
                    gain_ratio: [if with_ratio { ratio } else { 1.0 }; POSITIONS],
                    ..CalibratedLaw::new(
                        iso,
                        [Some(NoiseParams { a: conv * ratio, b }); POSITIONS],
                        [Some(b); POSITIONS],
                    )
                }
            })
            .collect()
    }

    #[test]
    fn the_conversion_gain_is_the_slope_over_the_gain_ratio() {
        // Read as conversion gains the laws show the switch (ratio 0.15 on the e2e pack); the
        // laws' `a` themselves (1.30 ×, 1.61 ×, 1.80 × the conversion gain) bend the high-gain
        // line's extrapolation to ISO 320 up to 0.73 × its read term: "no switch", the miss.
        let isos = [320, 1280, 2560];
        assert_eq!(calls(&sensor_62(&isos, true)), ["switch", "none"]);
        assert_eq!(calls(&sensor_62(&isos, false)), ["none", "none"]);
        let sw = detect_laws(&sensor_62(&isos, true));
        assert!(sw[0].ratio < 0.3, "{sw:?}");
        // Input-referred read variance is the truth's: 0.646² e⁻² + (1.695 DN / gain)² below.
        let conv = 3.185 * 4.0 * 4f64.powf(0.187);
        let truth = 0.646f64.powi(2) + (1.695 / conv).powi(2);
        assert!((sw[0].input_read_var_below / truth - 1.0).abs() < 1e-9, "{sw:?} vs {truth}");
    }

    #[test]
    fn a_digital_gain_is_no_switch() {
        // Random sensor 9's chain: high gain from ISO 300 (0.216 e⁻ + 4.656 DN, row 1.151 DN),
        // analog gain capped at ISO 800, ISO 1000 = 800 × 1.25 digital, gain ∝ ISO^0.958.
        let law = |iso: u32, lattice: bool| {
            let analog = iso.min(800) as f64 / 250.0 * 7.288;
            let d = iso as f64 / iso.min(800) as f64;
            let b = ((0.216 * analog).powi(2) + 4.656f64.powi(2) + 1.151f64.powi(2)) * d * d;
            CalibratedLaw {
                digital_gain: if lattice { d } else { 1.0 },
                ..CalibratedLaw::new(iso, [Some(NoiseParams { a: analog * d, b }); POSITIONS], [Some(b); POSITIONS])
            }
        };
        let l: Vec<CalibratedLaw> = [320, 800, 1000].iter().map(|&i| law(i, true)).collect();
        assert_eq!(calls(&l), ["none", "none"]);
        // Read without the lattice's digital gain, ISO 1000's post-gain read noise 1.25 × larger
        // makes a steep line through 800 and 1000 that predicts ISO 320 far below its read term.
        let blind: Vec<CalibratedLaw> = [320, 800, 1000].iter().map(|&i| law(i, false)).collect();
        assert_eq!(calls(&blind), ["switch", "none"]);
        // The lattice of a digital gain of 1.25 writes 4 of every 5 codes.
        let lattice = Some(CodeLattice { period: 5, allowed: 0b01111 });
        assert_eq!(digital_gain(&[lattice, lattice, None, lattice]), 1.25);
        assert_eq!(digital_gain(&[None; POSITIONS]), 1.0);
    }

    #[test]
    fn read_terms_on_one_gain_pin_no_slope() {
        // Two ISOs on one analog gain (a² 4 % apart) whose read terms differ by 5 % of pattern
        // and sampling: a line through them would predict ISO 320 below 0.6 × its read term.
        let mut l = laws(&[320, 800, 1000], None, true);
        for (k, (a, b)) in [(8.8, 27.6), (20.9, 44.8), (21.3, 47.1)].into_iter().enumerate() {
            l[k].law = [Some(NoiseParams { a, b }); POSITIONS];
            l[k].at_black = [Some(b); POSITIONS];
        }
        assert_eq!(calls(&l), ["none", "none"]);
        assert_eq!(predict_read(&[NoiseParams { a: 20.9, b: 44.8 }, NoiseParams { a: 21.3, b: 47.1 }], 8.8), None);
        assert!(predict_read(&[NoiseParams { a: 20.9, b: 44.8 }, NoiseParams { a: 26.0, b: 60.0 }], 8.8).is_some());
    }

    #[test]
    fn a_measured_drop_is_a_switch() {
        // Random sensor 13's read terms (medians over positions; `a` over the gain ratio): high
        // gain from ISO 192. The high-gain line through 200 and 320 predicts ISO 160 at 0.600 ×
        // its `b`, on the threshold; the dark frames' `b` falls to 0.69 × from 160 to 200, which
        // one gain cannot do.
        let terms = [(160, 3.871, 30.16), (200, 4.703, 20.78), (320, 7.505, 32.39), (2000, 45.44, 705.7)];
        let dark: Vec<CalibratedLaw> = terms
            .iter()
            .map(|&(iso, a, b)| CalibratedLaw::new(iso, [Some(NoiseParams { a, b }); POSITIONS], [Some(b); POSITIONS]))
            .collect();
        assert_eq!(calls(&dark), ["switch", "none", "none"]);
        // From the chart's intercepts alone (the same values) the drop is no measurement.
        assert_eq!(calls(&chart(&dark)), ["none", "none", "none"]);
        // A drop within the bound is not one: 0.85 ×.
        let mut mild = dark.clone();
        for p in 0..POSITIONS {
            mild[1].at_black[p] = Some(0.85 * 30.16);
        }
        assert_eq!(calls(&mild)[0], "none");
    }

    fn chart(l: &[CalibratedLaw]) -> Vec<CalibratedLaw> {
        l.iter().map(|c| CalibratedLaw { at_black: [None; POSITIONS], ..*c }).collect()
    }

    /// One ISO's dark step as the dark burst stores it: temporal variance
    /// `temporal`, a pattern change from the reference of variance `in_pixel`.
    fn dark_step(iso: u32, temporal: f64, in_pixel: f64) -> IsoStructure {
        use crate::model::structure::{FixedPattern, OffsetDistribution};
        let dist = |var: f64| OffsetDistribution {
            quantiles: vec![0.0; 2],
            count: 1000,
            measured_var: var,
            sampling_var: 0.0,
            significant: var > 0.0,
        };
        IsoStructure {
            fpn: Some(FixedPattern {
                pixels: std::array::from_fn(|_| dist(0.0)),
                shading: std::array::from_fn(|_| Vec::new()),
                grid: [0, 0],
                size: [0, 0],
                frames: 16,
                temporal_var: [temporal; POSITIONS],
                in_pixel_noise: std::array::from_fn(|_| dist(in_pixel)),
                significant: false,
            }),
            ..IsoStructure::empty(iso)
        }
    }

    #[test]
    fn a_clamp_at_black_is_no_switch() {
        use crate::math::censored::clamped_variance_ratio;
        // Random sensor 19's chain (10 bits, black 13.5 DN above the floor at 0, one conversion
        // gain, analog gain capped at ISO 400, digital gain 1.25 at ISO 500 and 4 at ISO 1600):
        // its output-referred read variance and slope per ISO, from the simulator's truth.
        let chain = [
            (125, 15.567, 0.9384, 1.0),
            (250, 78.411, 2.1946, 1.0),
            (500, 381.92, 4.8755, 1.25),
            (1600, 3871.4, 15.522, 4.0),
        ];
        let headroom = 13.5;
        // The dark frames' spread with the clamp at the floor: 0.64 × the truth at ISO 500,
        // 0.43 × at ISO 1600 (the e2e pack measured 242 and 1646 DN² against 382 and 3871).
        let clamped = |b: f64| b * clamped_variance_ratio(headroom / b.sqrt());
        let l = |at_black: &dyn Fn(f64) -> Option<f64>| -> Vec<CalibratedLaw> {
            chain
                .iter()
                .map(|&(iso, b, a, d)| CalibratedLaw {
                    digital_gain: d,
                    ..CalibratedLaw::new(iso, [Some(NoiseParams { a, b }); POSITIONS], [at_black(b); POSITIONS])
                })
                .collect()
        };
        // The clamped spread taken as the read term (the rule before): a drop to 0.66 at ISO
        // 500 → 1600, the false switch.
        assert_eq!(calls(&l(&|b| Some(clamped(b)))), ["none", "none", "switch"]);
        // Through the dark step's read term with the clamp undone: no switch.
        let read = |b: f64| read_at_black(Some(&dark_step(0, clamped(b), 0.0)), 0, headroom);
        assert_eq!(calls(&l(&read)), ["none", "none", "none"]);
        for &(_, b, _, _) in &chain {
            let got = read(b).expect("headroom above the floor");
            assert!((got / (b + 1.0 / 12.0) - 1.0).abs() < 1e-6, "{got} against {b}");
        }
        // The pattern's change from the reference is not read noise; no dark step, or black on
        // the floor, gives no read term.
        assert_eq!(read_at_black(Some(&dark_step(0, 50.0, 30.0)), 0, 1e9), Some(50.0 + 1.0 / 12.0));
        assert_eq!(read_at_black(Some(&IsoStructure::empty(0)), 0, 13.5), None);
        assert_eq!(read_at_black(Some(&dark_step(0, 50.0, 0.0)), 0, 0.0), None);
    }
}
