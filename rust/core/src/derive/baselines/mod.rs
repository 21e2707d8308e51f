//! Parametric baselines fitted from the same calibration histograms as the non-parametric model
//! (method.md, "Measuring fidelity"): the heteroscedastic Gaussian (HG), the Poisson–Gaussian
//! with clipping (PG), and the camera's own NoiseProfile (DNG tag 51041 /
//! `SENSOR_NOISE_PROFILE`).
//!
//! All three share one variance law per ISO and CFA position, `σ² = a·(l − black) + b` (DN²,
//! [`NoiseParams`]):
//! - **HG**: `a`, `b` fitted by non-negative weighted least squares on the per-bin variances of
//!   the calibrated PMFs ([`fit_params`]). Noise is `round(N(0, σ²))`, zero mean.
//! - **PG**: the same fit read as `gain = a` (DN per electron) and read variance
//!   `b − 1/12` (the rest of `b` is quantisation). Noise is
//!   `clamp(round(l + gain·(P − λ) + N(0, read)), 0, white) − l`, `P ~ Poisson(λ)`,
//!   `λ = (l − black)/gain`: exact Poisson sums up to λ = 1000, the Gaussian limit above.
//! - **NoiseProfile**: `σ²/(white − black)² = S·x + O` with `x = (l − black)/(white − black)`, so
//!   `a = S·(white − black)` and `b = O·(white − black)²`. Noise is `round(N(0, σ²))`.
//!
//! The variance of every baseline is the variance of the **integer** noise (as measured), so the
//! continuous Gaussian behind the rounding gets `σ² − 1/12` (Sheppard) for HG and NoiseProfile
//! from 1.3 DN² up, and below that the SD whose rounding has `σ²` exactly
//! (`rounded_gaussian_sd` in `pmf.rs`): `σ² − 1/12` there drew less, 0.88× at 0.25 DN² and 0.36× at
//! 0.15, nothing below 1/12 (HG near black on an 8-bit sensor, EMVA 1288 set 002). PG keeps its
//! read variance `b − 1/12` (a physical read noise, its Poisson part added). Every baseline PMF includes the
//! clipping at 0 and white for the levels of its bin, so PMFs can be compared with calibrated
//! ones directly; synthesis clamps the same way (the sampler's `IsoSampler::noisy`).
//!
//! A baseline becomes an ordinary [`IsoModel`] with [`Baseline::to_model`] (one PMF per
//! position and bin, averaged over up to [`LEVELS_PER_BIN`] levels of the bin), so it reuses
//! the sampler (`IsoSampler`), synthesis and every metric: that is what
//! `synth --model hg|pg|noiseprofile` runs. Its sampler does not draw from those bins, though:
//! each clean level draws from the law at that level ([`Baseline::level_tables`], through
//! `resolve::sampler_for`); the bins stay what metrics compare.
//!
//! Across ISO the baselines are interpolated "the usual parametric way" (paper §4.1, after
//! \[34\]): `a` linear in ISO and `b = c + d·a²` (read noise before and after the gain), both
//! non-negative fits over the calibrated ISOs on the same side of any conversion-gain switch
//! ([`interpolate`]).
//!
//! Files: this module (kinds, fits, interpolation, the model a baseline becomes), [`pmf`] (the
//! integer-grid PMFs of each kind, clipping included) and [`levels`] (the per-level tables
//! synthesis draws from).

mod levels;
mod pmf;

use rayon::prelude::*;

pub use crate::derive::noise_law::{BinStat, NoiseParams, bin_stats, fit_all, fit_params, profile_params};
pub use pmf::bin_levels;

use crate::error::ModelError;
use crate::math::fit::{nn_poly_fit, poly_eval};
use crate::model::layout::{Binning, POSITIONS};
use crate::model::pack::{BinModel, IsoModel, ModelOrigin, ModelPack, NoiseProfile, PositionModel};
use crate::model::pmf::Pmf;
pub use levels::{LATTICE_SHOWS, LEVEL_STEP};
pub use pmf::{LEVELS_PER_BIN, PG_EXACT_MAX_LAMBDA, SHEPPARD_FROM, rounded_gaussian_sd, rounded_variance};
use pmf::{average, clip, gaussian_cells, pg_cells};

/// Which parametric baseline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BaselineKind {
    /// Heteroscedastic Gaussian `σ² = a·(l − black) + b`.
    Hg,
    /// Poisson–Gaussian with clipping.
    Pg,
    /// The capture's own NoiseProfile `σ² = S·x + O` (normalised units).
    NoiseProfile,
}

impl BaselineKind {
    pub const ALL: [BaselineKind; 3] = [Self::Hg, Self::Pg, Self::NoiseProfile];

    /// `hg`, `pg`, `noiseprofile` (case-insensitive; `np` and `noise-profile` accepted).
    pub fn parse(s: &str) -> Option<Self> {
        match s.to_ascii_lowercase().as_str() {
            "hg" => Some(Self::Hg),
            "pg" => Some(Self::Pg),
            "noiseprofile" | "noise-profile" | "np" => Some(Self::NoiseProfile),
            _ => None,
        }
    }

    /// The CLI name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Hg => "hg",
            Self::Pg => "pg",
            Self::NoiseProfile => "noiseprofile",
        }
    }

    /// A human label for reports.
    pub fn label(self) -> &'static str {
        match self {
            Self::Hg => "heteroscedastic Gaussian",
            Self::Pg => "Poisson–Gaussian (clipped)",
            Self::NoiseProfile => "camera NoiseProfile",
        }
    }
}

impl std::fmt::Display for BaselineKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Where a baseline's parameters come from.
#[derive(Debug, Clone, PartialEq)]
pub enum BaselineSource {
    /// Fitted on the calibrated histograms of this ISO.
    Fitted,
    /// The NoiseProfile stored with this ISO's captures.
    CameraProfile,
    /// Interpolated (or extrapolated) parametrically from these calibrated ISOs.
    Interpolated { from: Vec<u32>, extrapolated: bool },
}

/// A parametric baseline at one ISO.
#[derive(Debug, Clone, PartialEq)]
pub struct Baseline {
    pub kind: BaselineKind,
    pub iso: u32,
    pub params: [NoiseParams; POSITIONS],
    pub source: BaselineSource,
}

/// The baseline of a calibrated ISO model: fitted (HG, PG) or read from its NoiseProfile.
pub fn fit(pack: &ModelPack, model: &IsoModel, kind: BaselineKind) -> Result<Baseline, ModelError> {
    let binning = pack.binning();
    let (params, source) = match kind {
        BaselineKind::Hg | BaselineKind::Pg => (fit_all(&binning, model), BaselineSource::Fitted),
        BaselineKind::NoiseProfile => {
            let Some(p) = &model.noise_profile else {
                return Err(no_profile(model.iso));
            };
            refuse_impossible(model.iso, p)?;
            (profile_params(&binning, p), BaselineSource::CameraProfile)
        }
    };
    Ok(Baseline { kind, iso: model.iso, params, source })
}

/// A damaged NoiseProfile (from a DNG tag, a recording or a pack) is refused before it sizes
/// any PMF.
fn refuse_impossible(iso: u32, p: &NoiseProfile) -> Result<(), ModelError> {
    match p.problem() {
        Some(why) => Err(ModelError::NoNoiseProfile(format!(
            "ISO {iso}'s NoiseProfile is impossible ({why}): the camera's tag is damaged"
        ))),
        None => Ok(()),
    }
}

fn no_profile(iso: u32) -> ModelError {
    ModelError::NoNoiseProfile(format!(
        "ISO {iso} has no NoiseProfile: its captures did not carry DNG tag 51041 / SENSOR_NOISE_PROFILE"
    ))
}

/// A baseline interpolated "the usual parametric way" across ISO: per position `a` linear in
/// ISO and `b = c + d·a²` (non-negative fits) over the calibrated ISOs on the target's side of
/// any conversion-gain switch ([`crate::derive::interp::plan`]). With one such ISO, `a` scales with the
/// ISO ratio `r` and `b` with `r²`. Outside the calibrated range this is refused unless
/// `extrapolate`. For NoiseProfile, only calibrated ISOs that carry a profile are used.
pub fn interpolate(pack: &ModelPack, iso: u32, kind: BaselineKind, extrapolate: bool) -> Result<Baseline, ModelError> {
    let plan = crate::derive::interp::plan(pack, iso, extrapolate)?;
    let binning = pack.binning();
    let mut pts: Vec<(f64, [NoiseParams; POSITIONS])> = Vec::new();
    for &k in &plan.segment {
        let Some(m) = pack.iso(k) else { continue };
        let params = match kind {
            BaselineKind::Hg | BaselineKind::Pg => fit_all(&binning, m),
            BaselineKind::NoiseProfile => match &m.noise_profile {
                Some(p) => {
                    refuse_impossible(k, p)?;
                    profile_params(&binning, p)
                }
                None => continue,
            },
        };
        pts.push((k as f64, params));
    }
    if pts.is_empty() {
        return Err(match kind {
            BaselineKind::NoiseProfile => {
                ModelError::NoNoiseProfile(format!("no calibrated ISO next to ISO {iso} carries a NoiseProfile"))
            }
            _ => ModelError::IsoMissing { iso, available: pack.iso_summary() },
        });
    }
    let j = iso as f64;
    let params = std::array::from_fn(|pos| {
        if pts.len() == 1 {
            let r = j / pts[0].0;
            let p = pts[0].1[pos];
            return NoiseParams { a: p.a * r, b: p.b * r * r };
        }
        let scale = pts.iter().map(|p| p.0).fold(0.0, f64::max);
        let xs: Vec<f64> = pts.iter().map(|p| p.0 / scale).collect();
        let av: Vec<f64> = pts.iter().map(|p| p.1[pos].a).collect();
        let bv: Vec<f64> = pts.iter().map(|p| p.1[pos].b).collect();
        let w_a: Vec<f64> = av.iter().map(|&a| 1.0 / a.max(1e-6).powi(2)).collect();
        let ca = nn_poly_fit(&xs, &av, &w_a, 1);
        let a = poly_eval(&ca, j / scale);
        let a2: Vec<f64> = av.iter().map(|&a| a * a).collect();
        let a2_scale = a2.iter().cloned().fold(1e-12, f64::max);
        let x2: Vec<f64> = a2.iter().map(|v| v / a2_scale).collect();
        let w_b: Vec<f64> = bv.iter().map(|&b| 1.0 / b.max(1e-6).powi(2)).collect();
        let cb = nn_poly_fit(&x2, &bv, &w_b, 1);
        let b = poly_eval(&cb, a * a / a2_scale);
        NoiseParams { a, b }
    });
    Ok(Baseline {
        kind,
        iso,
        params,
        source: BaselineSource::Interpolated {
            from: pts.iter().map(|p| p.0 as u32).collect(),
            extrapolated: plan.extrapolated,
        },
    })
}

/// The baseline at an ISO: fitted when the ISO is calibrated in the pack, else interpolated
/// parametrically ([`interpolate`]).
pub fn baseline(pack: &ModelPack, iso: u32, kind: BaselineKind, extrapolate: bool) -> Result<Baseline, ModelError> {
    match pack.iso(iso) {
        Some(m) if m.is_calibrated() => fit(pack, m, kind),
        _ => interpolate(pack, iso, kind, extrapolate),
    }
}

/// The baseline at an ISO as an [`IsoModel`] (for `synth --model hg|pg|noiseprofile`; ISOs
/// outside the calibrated range are refused unless `extrapolate`, within the bounds of
/// [`crate::derive::interp::plan`]).
pub fn baseline_model(
    pack: &ModelPack,
    iso: u32,
    kind: BaselineKind,
    extrapolate: bool,
) -> Result<IsoModel, ModelError> {
    Ok(baseline(pack, iso, kind, extrapolate)?.to_model(pack))
}

impl Baseline {
    /// Variance (DN²) at a level (DN, black included) and position.
    pub fn variance(&self, binning: &Binning, pos: usize, level: f64) -> f64 {
        self.params[pos].variance(level - binning.black[pos] as f64)
    }

    /// PMF of `noisy − level` at one integer clean level (clipping at 0 and white included).
    pub fn level_pmf(&self, binning: &Binning, pos: usize, level: i32) -> Pmf {
        let above = (level as f64 - binning.black[pos] as f64).max(0.0);
        clip(&self.noise_above(pos, above), level, binning.white as i32)
    }

    /// PMF of the integer noise at a level `above` DN over black (black clamped to 0), before
    /// any clipping.
    fn noise_above(&self, pos: usize, above: f64) -> Pmf {
        let p = self.params[pos];
        let above = above.max(0.0);
        match self.kind {
            // The law is the integer noise's variance: the Gaussian behind the rounding gets the
            // SD whose rounding has it (`var − 1/12` from 1.3 DN² up, as before).
            BaselineKind::Hg | BaselineKind::NoiseProfile => {
                gaussian_cells(0.0, rounded_gaussian_sd(p.variance(above)).max(1e-4))
            }
            BaselineKind::Pg => pg_cells(p.a, (p.b - 1.0 / 12.0).max(0.0), above),
        }
    }

    /// PMF of one bin: the mean of [`Self::level_pmf`] over up to [`LEVELS_PER_BIN`] levels
    /// spread across the bin.
    pub fn bin_pmf(&self, binning: &Binning, pos: usize, bin: usize) -> Pmf {
        let levels = bin_levels(binning, pos, bin);
        let pmfs: Vec<Pmf> = levels.iter().map(|&l| self.level_pmf(binning, pos, l)).collect();
        average(&pmfs)
    }

    /// The baseline as an ordinary model of its ISO: gain ratios, frame counts and noise profile
    /// are copied from the pack's model of that ISO when it has one. Bins are marked filled
    /// (they are not measured PMFs) and keep the calibrated sample counts.
    pub fn to_model(&self, pack: &ModelPack) -> IsoModel {
        let binning = pack.binning();
        let src = pack.iso(self.iso);
        let positions = (0..POSITIONS)
            .map(|pos| {
                // PMFs of a Poisson–Gaussian bin are costly; bins are independent (order kept).
                PositionModel::new(
                    (0..binning.bins(pos))
                        .into_par_iter()
                        .map(|bin| {
                            let samples = src
                                .and_then(|m| m.positions.get(pos))
                                .and_then(|pm| pm.bins.get(bin))
                                .map_or(0, |b| b.samples);
                            BinModel::from_pmf(&self.bin_pmf(&binning, pos, bin), samples, true)
                        })
                        .collect(),
                )
            })
            .collect();
        let origin = match &self.source {
            BaselineSource::Interpolated { from, extrapolated: true } => {
                ModelOrigin::Extrapolated { from: from.clone() }
            }
            BaselineSource::Interpolated { from, .. } => ModelOrigin::Interpolated { from: from.clone() },
            _ => src.map_or(ModelOrigin::Calibrated, |m| m.origin.clone()),
        };
        IsoModel {
            iso: self.iso,
            origin,
            frames: src.map_or(0, |m| m.frames),
            drift_frames: src.map_or(0, |m| m.drift_frames),
            gain_ratio: src.map_or([1.0; POSITIONS], |m| m.gain_ratio),
            noise_profile: src.and_then(|m| m.noise_profile),
            // A parametric baseline knows nothing of the codes a sensor writes.
            range: [[0, pack.layout.white]; POSITIONS],
            lattice: [None; POSITIONS],
            positions,
        }
    }
}
