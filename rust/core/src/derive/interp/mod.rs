//! ISO interpolation (paper §4.1, Eq. 4–6; method.md "ISO interpolation") and conversion-gain
//! switch detection.
//!
//! For an uncalibrated ISO `j`, per CFA position and bin:
//! 1. **Neighbours**: the calibrated ISOs on `j`'s side of every conversion-gain switch
//!    ([`gaps`](crate::derive::gain_switch::gaps)), up to the nearest gaps whose read terms the
//!    data does not pin — the *segment* — and within it the two that bracket `j` plus one more on
//!    each side when there is one (2–4 ISOs, [`InterpOptions::max_neighbours`]). Fits are local
//!    so they follow real curves, and never straddle a switch or a gap that may hide one.
//! 2. **Variance** vs ISO: non-negative `c₀ + c₁·ISO + c₂·ISO²` (quantisation and post-gain read
//!    noise, shot noise, gained read noise), weighted by `samples / σ⁴`; degree 1 with two
//!    neighbours. Where the calibrated variances do *not* grow with ISO (clipping near white
//!    makes them shrink), a non-negative polynomial cannot follow them, and `log σ²` is
//!    interpolated linearly in `log ISO` instead. With a single neighbour, its variance is
//!    scaled by the physics of its own HG fit: shot part × `j/k`, read part × `(j/k)²`.
//! 3. **Mean** vs ISO: a bin's mean carries the gain ratio as `(g − 1)·l` (`l` its level above
//!    black): that part is taken at the model's own gain ratio (`log g` linear in `log ISO`
//!    between the bracketing ISOs), and what is left (offsets, clipping) by a weighted
//!    least-squares line in ISO over the same neighbours. A line in ISO through the whole means
//!    made a sensor with gain ∝ ISO^0.9 3–4 % too bright between its calibrated ISOs, and its
//!    means disagreed with its own gain ratio (`tests/interp_gain.rs`).
//! 4. **Shape** (Eq. 5): by default ([`ShapeSource::QuantileBlend`]) the standardised quantile
//!    functions of the two bracketing calibrated ISOs are blended with weight
//!    `t = ln(j/lo) / ln(hi/lo)`; [`ShapeSource::Nearest`] takes the nearest calibrated ISO (in
//!    log ISO) as the paper does. Measured on the simulated heavy-tailed 10-bit sensor
//!    (`tests/interp_truth.rs`: ISO 400 left out of 100–1600, 200k samples per bin, 1M-sample
//!    truth), mean per-bin JSD to the truth: blend 1.0·10⁻⁴, nearest 1.7·10⁻⁴, a calibration
//!    of ISO 400 itself 1.6·10⁻⁴ (the blend averages two calibrations' sampling noise), HG
//!    interpolated parametrically 5.4·10⁻⁴ (1.9·10⁻³ in the darkest bin).
//! 5. **Rescale** the shape to the fitted mean and variance on the integer grid (Eq. 6, as
//!    [`Pmf::rescaled_to`](crate::model::pmf::Pmf::rescaled_to): piecewise-uniform cells,
//!    Sheppard-corrected, and where those miss the moments by over 1 % (sub-DN bins) a re-binning
//!    that meets them).
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
//!
//! Files: [`plan`] (which calibrated ISOs an interpolation stands on), [`fit`] (mean and
//! variance against ISO per bin), [`blend`] (quantile blending of shapes); this module builds the
//! model.

mod blend;
mod fit;
mod plan;

use std::borrow::Cow;

pub use blend::blend_quantiles;
pub use plan::{CalibratedLaw, InterpOptions, InterpPlan, ShapeSource, calibrated_laws, plan, plan_among, plan_with};

use crate::derive::noise_law::fit_params;
use crate::error::ModelError;
use crate::model::layout::POSITIONS;
use crate::model::pack::{BinModel, IsoModel, ModelOrigin, ModelPack, NoiseProfile, PositionModel};
use fit::{Point, fit_mean, fit_variance, lin_lerp, log_lerp};
use rayon::prelude::*;

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

/// The gain ratios (target/reference brightness per CFA position, [`IsoModel::gain_ratio`]) of
/// `iso`: the pack's model's when it has one, else those [`interpolate`] would give (linear in
/// log ISO between the bracketing calibrated ISOs), without building the rest of the model.
pub fn gain_ratio_at(pack: &ModelPack, iso: u32, extrapolate: bool) -> Result<[f64; POSITIONS], ModelError> {
    if let Some(m) = pack.iso(iso) {
        return Ok(m.gain_ratio);
    }
    let plan = plan(pack, iso, extrapolate)?;
    let nb: Vec<&IsoModel> = plan.neighbours.iter().filter_map(|&k| pack.iso(k)).collect();
    Ok(planned_gain_ratio(&nb, iso as f64))
}

/// Gain ratios at ISO `j` from the neighbours: `log g` linear in `log ISO` between the two
/// bracketing ones (brightness against ISO is a power law where the gain is not ∝ ISO: exact
/// for gain ∝ ISO^γ), `g` linear in `log ISO` if a ratio is not positive.
fn planned_gain_ratio(nb: &[&IsoModel], j: f64) -> [f64; POSITIONS] {
    std::array::from_fn(|pos| {
        let positive = !nb.is_empty() && nb.iter().all(|m| m.gain_ratio[pos] > 0.0 && m.gain_ratio[pos].is_finite());
        if positive {
            log_lerp(nb, j, &|m: &IsoModel| m.gain_ratio[pos].ln()).exp()
        } else {
            log_lerp(nb, j, &|m: &IsoModel| m.gain_ratio[pos])
        }
    })
}

/// Builds the model a plan describes. Panics only if the plan does not come from this pack.
pub fn interpolate_planned(pack: &ModelPack, plan: &InterpPlan) -> IsoModel {
    let binning = pack.binning();
    let j = plan.iso as f64;
    let nb: Vec<&IsoModel> = plan.neighbours.iter().filter_map(|&k| pack.iso(k)).collect();
    let shape_models: Vec<&IsoModel> = plan.shape_from.iter().filter_map(|&k| pack.iso(k)).collect();
    let gain_ratio = planned_gain_ratio(&nb, j);
    let t = if shape_models.len() == 2 {
        (j / shape_models[0].iso as f64).ln() / (shape_models[1].iso as f64 / shape_models[0].iso as f64).ln()
    } else {
        0.0
    };
    let positions = (0..POSITIONS)
        .map(|pos| {
            let single_params = (nb.len() == 1).then(|| fit_params(&binning, nb[0], pos)).flatten();
            // Bins are independent: built in parallel, collected in order (the same model on
            // any thread count).
            let bins = (0..binning.bins(pos))
                .into_par_iter()
                .map(|b| {
                    // A bin's mean carries the gain ratio, `(g − 1)·l` (calibration step 7):
                    // that part is taken at the ratio this model states, and only what is left
                    // (offsets, clipping) is fitted against ISO.
                    let level_above = (b as f64 + 0.5) * binning.bin_width as f64;
                    let pts: Vec<Point<'_>> = nb
                        .iter()
                        .map(|m| {
                            let bin = &m.positions[pos].bins[b];
                            let (mean, var) = bin.moments();
                            let n = bin.samples.max(1) as f64;
                            let mean = mean - (m.gain_ratio[pos] - 1.0) * level_above;
                            Point { iso: m.iso as f64, mean, var: var.max(1e-6), weight: n, bin }
                        })
                        .collect();
                    // Noise wider than the sensor's range is all clipping: bounding it keeps an
                    // extrapolated PMF (and its memory) within the codes the sensor can write.
                    let span = pack.layout.white as f64 + 1.0;
                    let var = fit_variance(&pts, j, single_params, level_above).clamp(1e-3, span * span);
                    let mean = (fit_mean(&pts, j) + (gain_ratio[pos] - 1.0) * level_above).clamp(-span, span);
                    let pmf = match shape_models.as_slice() {
                        [a, c] => blend_quantiles(
                            &a.positions[pos].bins[b].pmf(),
                            &c.positions[pos].bins[b].pmf(),
                            t,
                            mean,
                            var,
                        ),
                        [a] => a.positions[pos].bins[b].pmf().rescaled_to(mean, var),
                        _ => pts[0].bin.pmf().rescaled_to(mean, var),
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
    let noise_profile = if nb.iter().all(|m| m.noise_profile.is_some()) {
        Some(NoiseProfile(std::array::from_fn(|pos| {
            std::array::from_fn(|c| {
                lin_lerp(&nb, j, &|m: &IsoModel| m.noise_profile.map_or(0.0, |p| p.0[pos][c])).max(0.0)
            })
        })))
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

/// What [`materialize`] did for one asked ISO.
#[derive(Debug, Clone, PartialEq)]
pub enum Materialized {
    /// The pack holds this ISO calibrated: kept as is.
    Kept(u32),
    /// Derived and added, following this plan.
    Derived(InterpPlan),
}

impl InterpPlan {
    /// The warning to keep with the pack when the ISO lies inside a conversion-gain switch:
    /// which gain the camera uses anywhere strictly between the switch's two calibrated ISOs is
    /// unknown, so the warning names that range, the side used, and the calibration that
    /// settles it (the ISO itself; and the one halving the range when that is another).
    pub fn gap_warning(&self) -> Option<String> {
        let s = self.in_switch_gap.as_ref()?;
        let list = self.neighbours.iter().map(u32::to_string).collect::<Vec<_>>().join(", ");
        let half = s.bisecting_iso();
        let narrow = if half != self.iso {
            format!(" (or ISO {half}, halfway in log ISO, to halve the range where the gain is unknown)")
        } else {
            String::new()
        };
        Some(format!(
            "ISO {iso} lies between ISO {} and {}, where the sensor switches conversion gain; which gain the camera uses at any ISO strictly between them is unknown from these calibrations, so ISO {iso} was modelled from the nearer side in log ISO (ISO {list}; the lower side on a tie). Calibrate ISO {iso} to be sure{narrow}.",
            s.below_iso,
            s.above_iso,
            iso = self.iso,
        ))
    }
}

/// A copy of `pack` with a derived model for each ISO of `isos` it does not hold calibrated
/// (sorted, deduplicated; a derived model already there is replaced), each flagged as interpolated
/// or extrapolated. Gap warnings ([`InterpPlan::gap_warning`]) join the pack's warnings. ISO 0
/// is refused.
pub fn materialize(
    pack: &ModelPack,
    isos: &[u32],
    extrapolate: bool,
    opts: &InterpOptions,
) -> Result<(ModelPack, Vec<Materialized>), ModelError> {
    let mut isos = isos.to_vec();
    isos.sort_unstable();
    isos.dedup();
    if isos.first() == Some(&0) {
        return Err(ModelError::Unsupported(
            "ISO 0 is not an ISO; give the sensitivities to interpolate, e.g. 1000".into(),
        ));
    }
    let mut out = pack.clone();
    let mut done = Vec::with_capacity(isos.len());
    for iso in isos {
        if pack.iso(iso).is_some_and(|m| m.is_calibrated()) {
            done.push(Materialized::Kept(iso));
            continue;
        }
        let plan = plan_with(pack, iso, extrapolate, opts)?;
        out.insert(interpolate_planned(pack, &plan));
        if let Some(st) = crate::derive::structure::derived_structure(pack, iso) {
            out.insert_structure(st);
        }
        if let Some(w) = plan.gap_warning() {
            out.warnings.push(w);
        }
        done.push(Materialized::Derived(plan));
    }
    Ok((out, done))
}
