//! Conversion-gain switches between neighbouring calibrated ISOs (method.md, "ISO
//! interpolation"): the HG read term above a gap falls far below what a smooth single-gain fit
//! predicts across it. Interpolation never fits across a switch.

use crate::derive::noise_law::{NoiseParams, fit_params};
use crate::math::fit::{nn_poly_fit, poly_eval};
use crate::math::stats::median;
use crate::model::layout::{Binning, POSITIONS};
use crate::model::pack::{IsoModel, ModelPack};

/// Observed/predicted read-noise ratio below which a gap between two calibrated ISOs is a
/// conversion-gain switch.
pub const SWITCH_RATIO: f64 = 0.6;

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

/// Conversion-gain switches between neighbouring calibrated ISOs of a pack.
pub fn detect_gain_switches(pack: &ModelPack) -> Vec<GainSwitch> {
    let models: Vec<&IsoModel> = pack.isos.iter().filter(|m| m.is_calibrated()).collect();
    detect(&pack.binning(), &models)
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

pub(crate) fn detect(binning: &Binning, models: &[&IsoModel]) -> Vec<GainSwitch> {
    let laws: Vec<(u32, [Option<NoiseParams>; POSITIONS])> =
        models.iter().map(|m| (m.iso, std::array::from_fn(|pos| fit_params(binning, m, pos)))).collect();
    detect_laws(&laws)
}

/// [`detect`] from the calibrated ISOs' noise laws per position (sorted by ISO; each law as
/// [`fit_params`] gives it).
pub(crate) fn detect_laws(laws: &[(u32, [Option<NoiseParams>; POSITIONS])]) -> Vec<GainSwitch> {
    let n = laws.len();
    if n < 2 {
        return Vec::new();
    }
    let params: Vec<[Option<NoiseParams>; POSITIONS]> =
        laws.iter().map(|(_, law)| law.map(|p| p.filter(|p| p.a > 0.0 && p.b > 0.0))).collect();
    let mut out = Vec::new();
    let mut seg_start = 0usize;
    for j in 0..n - 1 {
        let mut ratios = Vec::new();
        let mut below_r = Vec::new();
        let mut above_r = Vec::new();
        for pos in 0..POSITIONS {
            let (Some(pj), Some(pk)) = (params[j][pos], params[j + 1][pos]) else {
                continue;
            };
            let below: Vec<NoiseParams> =
                (seg_start.max(j.saturating_sub(2))..=j).filter_map(|i| params[i][pos]).collect();
            let above: Vec<NoiseParams> = (j + 1..(j + 3).min(n)).filter_map(|i| params[i][pos]).collect();
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
        if ratios.is_empty() {
            continue;
        }
        let agree = ratios.iter().filter(|&&r| r < SWITCH_RATIO).count();
        let ratio = median(&ratios);
        if ratio < SWITCH_RATIO {
            out.push(GainSwitch {
                below_iso: laws[j].0,
                above_iso: laws[j + 1].0,
                ratio,
                input_read_var_below: median(&below_r),
                input_read_var_above: median(&above_r),
                positions: agree,
            });
            seg_start = j + 1;
        }
    }
    out
}
