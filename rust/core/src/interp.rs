//! ISO interpolation (paper §4.1, Eq. 4–6; method.md "ISO interpolation") and conversion-gain
//! switch detection.
//!
//! For an uncalibrated ISO `j`, per CFA position and bin:
//! 1. **Neighbours**: the calibrated ISOs on `j`'s side of every conversion-gain switch
//!    ([`detect_gain_switches`]) — the *segment* — and within it the two that bracket `j` plus
//!    one more on each side when there is one (2–4 ISOs, [`InterpOptions::max_neighbours`]).
//!    Fits are local so they follow real curves, and never straddle a switch.
//! 2. **Variance** vs ISO: non-negative `c₀ + c₁·ISO + c₂·ISO²` (quantisation and post-gain read
//!    noise, shot noise, gained read noise), weighted by `samples / σ⁴`; degree 1 with two
//!    neighbours. Where the calibrated variances do *not* grow with ISO (clipping near white
//!    makes them shrink), a non-negative polynomial cannot follow them, and `log σ²` is
//!    interpolated linearly in `log ISO` instead. With a single neighbour, its variance is
//!    scaled by the physics of its own HG fit: shot part × `j/k`, read part × `(j/k)²`.
//! 3. **Mean** vs ISO: weighted least-squares line over the same neighbours.
//! 4. **Shape** (Eq. 5): by default ([`ShapeSource::QuantileBlend`]) the standardised quantile
//!    functions of the two bracketing calibrated ISOs are blended with weight
//!    `t = ln(j/lo) / ln(hi/lo)`; [`ShapeSource::Nearest`] takes the nearest calibrated ISO (in
//!    log ISO) as the paper does. Measured on the simulated heavy-tailed 10-bit sensor
//!    (`tests/interp_truth.rs`: ISO 400 left out of 100–1600, 200k samples per bin, 1M-sample
//!    truth), mean per-bin JSD to the truth: blend 1.0·10⁻⁴, nearest 1.7·10⁻⁴, a calibration
//!    of ISO 400 itself 1.6·10⁻⁴ (the blend averages two calibrations' sampling noise), HG
//!    interpolated parametrically 5.4·10⁻⁴ (1.9·10⁻³ in the darkest bin).
//! 5. **Rescale** the shape to the fitted mean and variance on the integer grid (Eq. 6, as
//!    [`Pmf::rescaled`]: piecewise-uniform cells, Sheppard-corrected).
//!
//! Outside the calibrated range the fit is refused ([`ModelError::IsoOutOfRange`]) unless
//! `extrapolate`, in which case the nearest three calibrated ISOs of the end segment are used and
//! the model's origin is [`ModelOrigin::Extrapolated`].
//!
//! Interpolated bins carry, as `samples`, the smallest sample count among the calibrated bins
//! they were fitted from (the support they stand on) and are `filled` when any of those was.
//!
//! The target ISO's own calibrated model, if the pack has one, is never used: `interpolate` on a
//! calibrated ISO is exactly the leave-one-out study of paper §5.2 (switch detection also runs
//! without it).

use std::borrow::Cow;

use crate::baselines::{NoiseParams, fit_params};
use crate::error::ModelError;
use crate::fit::{nn_poly_fit, poly_eval, wls};
use crate::layout::{Binning, POSITIONS};
use crate::pack::{BinModel, IsoModel, ModelOrigin, ModelPack, PositionModel};
use crate::pmf::Pmf;

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

/// Where the normalised shape of an interpolated PMF comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShapeSource {
    /// The nearest calibrated ISO (in log ISO), as in the paper.
    Nearest,
    /// The standardised quantile functions of the two bracketing calibrated ISOs, blended
    /// linearly in log ISO (the default; see the module docs).
    QuantileBlend,
}

/// Options of [`interpolate_with`].
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

/// Conversion-gain switches between neighbouring calibrated ISOs of a pack.
pub fn detect_gain_switches(pack: &ModelPack) -> Vec<GainSwitch> {
    let models: Vec<&IsoModel> = pack.isos.iter().filter(|m| m.is_calibrated()).collect();
    detect(&pack.binning(), &models)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
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

fn detect(binning: &Binning, models: &[&IsoModel]) -> Vec<GainSwitch> {
    let n = models.len();
    if n < 2 {
        return Vec::new();
    }
    let params: Vec<[Option<NoiseParams>; POSITIONS]> = models
        .iter()
        .map(|m| std::array::from_fn(|pos| fit_params(binning, m, pos).filter(|p| p.a > 0.0 && p.b > 0.0)))
        .collect();
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
        let ratio = median(ratios);
        if ratio < SWITCH_RATIO {
            out.push(GainSwitch {
                below_iso: models[j].iso,
                above_iso: models[j + 1].iso,
                ratio,
                input_read_var_below: median(below_r),
                input_read_var_above: median(above_r),
                positions: agree,
            });
            seg_start = j + 1;
        }
    }
    out
}

/// The calibrated models a plan may stand on: every calibrated ISO except the target.
fn sources(pack: &ModelPack, iso: u32) -> Vec<&IsoModel> {
    pack.isos.iter().filter(|m| m.is_calibrated() && m.iso != iso).collect()
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
    let models = sources(pack, iso);
    if models.is_empty() {
        return Err(ModelError::IsoMissing {
            iso,
            available: if pack.isos.is_empty() { "none".into() } else { format!("none calibrated besides ISO {iso}") },
        });
    }
    let isos: Vec<u32> = models.iter().map(|m| m.iso).collect();
    let (min, max) = (isos[0], isos[isos.len() - 1]);
    let outside = iso < min || iso > max;
    if outside && !extrapolate {
        return Err(ModelError::IsoOutOfRange { iso, min, max });
    }
    let switches = detect(&pack.binning(), &models);
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

/// The model of an uncalibrated ISO (see the module docs), with the default options.
pub fn interpolate(pack: &ModelPack, iso: u32, extrapolate: bool) -> Result<IsoModel, ModelError> {
    interpolate_with(pack, iso, extrapolate, &InterpOptions::default()).map(|(m, _)| m)
}

/// As [`interpolate`], with options; also returns the plan it followed.
pub fn interpolate_with(
    pack: &ModelPack,
    iso: u32,
    extrapolate: bool,
    opts: &InterpOptions,
) -> Result<(IsoModel, InterpPlan), ModelError> {
    let plan = plan_with(pack, iso, extrapolate, opts)?;
    Ok((interpolate_planned(pack, &plan), plan))
}

/// The calibrated model of `iso` when the pack has it, else one interpolated now. The flag is
/// true when the returned model is not a calibrated one (interpolated now, or materialized
/// earlier by `noisecal interp`), so callers can say so.
pub fn model_for(pack: &ModelPack, iso: u32, extrapolate: bool) -> Result<(Cow<'_, IsoModel>, bool), ModelError> {
    if let Some(m) = pack.iso(iso) {
        return Ok((Cow::Borrowed(m), !m.is_calibrated()));
    }
    Ok((Cow::Owned(interpolate(pack, iso, extrapolate)?), true))
}

/// One calibrated bin's data used by the fits.
struct Point<'a> {
    iso: f64,
    mean: f64,
    var: f64,
    weight: f64,
    bin: &'a BinModel,
}

/// Builds the model a plan describes. Panics only if the plan does not come from this pack.
pub fn interpolate_planned(pack: &ModelPack, plan: &InterpPlan) -> IsoModel {
    let binning = pack.binning();
    let j = plan.iso as f64;
    let nb: Vec<&IsoModel> = plan.neighbours.iter().filter_map(|&k| pack.iso(k)).collect();
    let shape_models: Vec<&IsoModel> = plan.shape_from.iter().filter_map(|&k| pack.iso(k)).collect();
    let t = if shape_models.len() == 2 {
        (j / shape_models[0].iso as f64).ln() / (shape_models[1].iso as f64 / shape_models[0].iso as f64).ln()
    } else {
        0.0
    };
    let positions = (0..POSITIONS)
        .map(|pos| {
            let single_params = (nb.len() == 1).then(|| fit_params(&binning, nb[0], pos)).flatten();
            let bins = (0..binning.bins(pos))
                .map(|b| {
                    let pts: Vec<Point<'_>> = nb
                        .iter()
                        .map(|m| {
                            let bin = &m.positions[pos].bins[b];
                            let (mean, var) = bin.moments();
                            let n = bin.samples.max(1) as f64;
                            Point { iso: m.iso as f64, mean, var: var.max(1e-6), weight: n, bin }
                        })
                        .collect();
                    let level_above = (b as f64 + 0.5) * binning.bin_width as f64;
                    let var = fit_variance(&pts, j, single_params, level_above).max(1e-3);
                    let mean = fit_mean(&pts, j);
                    let pmf = match shape_models.as_slice() {
                        [a, c] => blend_quantiles(
                            &a.positions[pos].bins[b].pmf(),
                            &c.positions[pos].bins[b].pmf(),
                            t,
                            mean,
                            var,
                        ),
                        [a] => a.positions[pos].bins[b].pmf().rescaled(mean, var),
                        _ => pts[0].bin.pmf().rescaled(mean, var),
                    };
                    let samples = pts.iter().map(|p| p.bin.samples).min().unwrap_or(0);
                    let filled = pts.iter().any(|p| p.bin.filled());
                    BinModel::from_pmf(&pmf, samples, filled)
                })
                .collect();
            PositionModel::new(bins)
        })
        .collect();
    let lerp = |f: &dyn Fn(&IsoModel) -> f64| -> f64 { log_lerp(&nb, j, f) };
    let gain_ratio = std::array::from_fn(|pos| lerp(&|m: &IsoModel| m.gain_ratio[pos]));
    let noise_profile = if nb.iter().all(|m| m.noise_profile.is_some()) {
        Some(std::array::from_fn(|pos| {
            std::array::from_fn(|c| {
                lin_lerp(&nb, j, &|m: &IsoModel| m.noise_profile.map_or(0.0, |p| p[pos][c])).max(0.0)
            })
        }))
    } else {
        None
    };
    let from = plan.neighbours.clone();
    IsoModel {
        iso: plan.iso,
        origin: if plan.extrapolated { ModelOrigin::Extrapolated { from } } else { ModelOrigin::Interpolated { from } },
        frames: 0,
        drift_frames: 0,
        gain_ratio,
        noise_profile,
        // Where the output piles up moves with the gain: interpolated like the gain ratios.
        range: std::array::from_fn(|pos| {
            let white = pack.layout.white as f64;
            let floor = lerp(&|m: &IsoModel| m.range[pos][0] as f64).clamp(0.0, white);
            let ceiling = lerp(&|m: &IsoModel| m.range[pos][1] as f64).clamp(floor + 1.0, white);
            [floor.round() as u16, ceiling.round() as u16]
        }),
        // The interpolated ISO's digital gain, if any, is unknown: no lattice.
        lattice: [None; POSITIONS],
        positions,
    }
}

/// The two models bracketing `j` (or the nearest two), for piecewise interpolation.
fn pair<'a>(nb: &[&'a IsoModel], j: f64) -> Option<(&'a IsoModel, &'a IsoModel)> {
    if nb.len() < 2 {
        return None;
    }
    let at = nb.partition_point(|m| (m.iso as f64) < j).clamp(1, nb.len() - 1);
    Some((nb[at - 1], nb[at]))
}

/// Linear interpolation in log ISO of a per-model quantity (constant with one model).
fn log_lerp(nb: &[&IsoModel], j: f64, f: &dyn Fn(&IsoModel) -> f64) -> f64 {
    match pair(nb, j) {
        Some((a, b)) => {
            let t = (j / a.iso as f64).ln() / (b.iso as f64 / a.iso as f64).ln();
            f(a) + t * (f(b) - f(a))
        }
        None => nb.first().map_or(1.0, |m| f(m)),
    }
}

/// Linear interpolation in ISO of a per-model quantity (proportional scaling with one model).
fn lin_lerp(nb: &[&IsoModel], j: f64, f: &dyn Fn(&IsoModel) -> f64) -> f64 {
    match pair(nb, j) {
        Some((a, b)) => {
            let t = (j - a.iso as f64) / (b.iso as f64 - a.iso as f64);
            f(a) + t * (f(b) - f(a))
        }
        None => nb.first().map_or(0.0, |m| f(m) * j / m.iso as f64),
    }
}

/// Variance at ISO `j` from the neighbours (see the module docs).
fn fit_variance(pts: &[Point<'_>], j: f64, single: Option<NoiseParams>, level_above: f64) -> f64 {
    match pts {
        [] => 1.0,
        [p] => {
            let r = j / p.iso;
            match single {
                Some(hg) => {
                    let shot = hg.a * level_above;
                    let read = hg.b;
                    if shot + read > 0.0 { p.var * (shot * r + read * r * r) / (shot + read) } else { p.var * r }
                }
                None => p.var * r,
            }
        }
        _ => {
            let growing = pts.windows(2).all(|w| w[1].var >= 0.98 * w[0].var);
            if growing {
                let x: Vec<f64> = pts.iter().map(|p| p.iso / j).collect();
                let y: Vec<f64> = pts.iter().map(|p| p.var).collect();
                let w: Vec<f64> = pts.iter().map(|p| p.weight / (p.var * p.var)).collect();
                let degree = if pts.len() >= 3 { 2 } else { 1 };
                let c = nn_poly_fit(&x, &y, &w, degree);
                poly_eval(&c, 1.0)
            } else {
                let at = pts.partition_point(|p| p.iso < j).clamp(1, pts.len() - 1);
                let (a, b) = (&pts[at - 1], &pts[at]);
                let t = (j / a.iso).ln() / (b.iso / a.iso).ln();
                (a.var.ln() + t * (b.var.ln() - a.var.ln())).exp()
            }
        }
    }
}

/// Mean at ISO `j`: weighted least-squares line in ISO.
fn fit_mean(pts: &[Point<'_>], j: f64) -> f64 {
    if pts.len() < 2 {
        return pts.first().map_or(0.0, |p| p.mean);
    }
    let x: Vec<f64> = pts.iter().map(|p| p.iso / j).collect();
    let y: Vec<f64> = pts.iter().map(|p| p.mean).collect();
    let w: Vec<f64> = pts.iter().map(|p| p.weight / p.var).collect();
    match wls(&x, &y, &w, &[0, 1]) {
        Some(c) if c.iter().all(|v| v.is_finite()) => poly_eval(&c, 1.0),
        _ => {
            let at = pts.partition_point(|p| p.iso < j).clamp(1, pts.len() - 1);
            let (a, b) = (&pts[at - 1], &pts[at]);
            a.mean + (j - a.iso) / (b.iso - a.iso) * (b.mean - a.mean)
        }
    }
}

/// Piecewise-linear quantile function of a PMF read as piecewise-uniform unit cells,
/// standardised to zero mean and unit variance: `(u0, u1, z0, z1)` per cell with mass.
fn standard_quantile(p: &Pmf) -> Vec<(f64, f64, f64, f64)> {
    let (m, v) = p.moments();
    let s = (v + 1.0 / 12.0).sqrt();
    let mut u = 0.0;
    let mut out = Vec::with_capacity(p.p.len());
    for (i, &q) in p.p.iter().enumerate() {
        if q <= 0.0 {
            continue;
        }
        let x = (p.first + i as i32) as f64;
        out.push((u, u + q, (x - 0.5 - m) / s, (x + 0.5 - m) / s));
        u += q;
    }
    if let Some(last) = out.last_mut() {
        last.1 = 1.0;
    }
    out
}

/// The value of a standardised quantile function at `u`, linear within the segment `seg`.
fn eval_seg(seg: &(f64, f64, f64, f64), u: f64) -> f64 {
    let (u0, u1, z0, z1) = *seg;
    if u1 > u0 { z0 + (z1 - z0) * ((u - u0) / (u1 - u0)).clamp(0.0, 1.0) } else { z0 }
}

/// Blends the standardised quantile functions of `a` and `b` (`(1 − t)·Q_a + t·Q_b`), then maps
/// the result to mean `mu` and variance `var` on the integer grid (as [`Pmf::rescaled`]).
pub fn blend_quantiles(a: &Pmf, b: &Pmf, t: f64, mu: f64, var: f64) -> Pmf {
    let t = t.clamp(0.0, 1.0);
    let qa = standard_quantile(a);
    let qb = standard_quantile(b);
    if qa.is_empty() || qb.is_empty() || t <= 0.0 {
        return a.rescaled(mu, var);
    }
    if t >= 1.0 {
        return b.rescaled(mu, var);
    }
    let mut knots: Vec<f64> = qa.iter().chain(&qb).map(|s| s.1).collect();
    knots.push(0.0);
    knots.sort_by(f64::total_cmp);
    knots.dedup_by(|x, y| (*x - *y).abs() < 1e-15);
    let mut segs: Vec<(f64, f64, f64)> = Vec::with_capacity(knots.len());
    let (mut ia, mut ib) = (0usize, 0usize);
    for w in knots.windows(2) {
        let (u0, u1) = (w[0], w[1]);
        let mid = 0.5 * (u0 + u1);
        while ia + 1 < qa.len() && qa[ia].1 < mid {
            ia += 1;
        }
        while ib + 1 < qb.len() && qb[ib].1 < mid {
            ib += 1;
        }
        let z0 = (1.0 - t) * eval_seg(&qa[ia], u0) + t * eval_seg(&qb[ib], u0);
        let z1 = (1.0 - t) * eval_seg(&qa[ia], u1) + t * eval_seg(&qb[ib], u1);
        segs.push((u1 - u0, z0, z1));
    }
    let mean: f64 = segs.iter().map(|(m, z0, z1)| m * 0.5 * (z0 + z1)).sum();
    let ez2: f64 = segs.iter().map(|(m, z0, z1)| m * (z0 * z0 + z0 * z1 + z1 * z1) / 3.0).sum();
    let sd = (ez2 - mean * mean).max(1e-12).sqrt();
    let target = (var - 1.0 / 12.0).max(1e-4).sqrt();
    let k = target / sd;
    let map = |z: f64| mu + k * (z - mean);
    let lo = map(segs.first().map_or(0.0, |s| s.1));
    let hi = map(segs.last().map_or(0.0, |s| s.2));
    let first = (lo + 0.5).floor() as i32;
    let last = (hi + 0.5).floor() as i32;
    let mut out = vec![0.0f64; (last - first + 1).max(1) as usize];
    for (m, z0, z1) in segs {
        if m <= 0.0 {
            continue;
        }
        let (x0, x1) = (map(z0), map(z1));
        if x1 - x0 < 1e-12 {
            let kc = ((x0 + 0.5).floor() as i32 - first).clamp(0, out.len() as i32 - 1);
            out[kc as usize] += m;
            continue;
        }
        let k0 = (x0 + 0.5).floor() as i32;
        let k1 = (x1 + 0.5).floor() as i32;
        for kc in k0..=k1 {
            let c0 = (kc as f64 - 0.5).max(x0);
            let c1 = (kc as f64 + 0.5).min(x1);
            if c1 > c0
                && let Some(slot) = out.get_mut((kc - first) as usize)
            {
                *slot += m * (c1 - c0) / (x1 - x0);
            }
        }
    }
    Pmf::from_weights(first, out).unwrap_or_else(|| a.rescaled(mu, var))
}
