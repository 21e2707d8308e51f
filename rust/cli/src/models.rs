//! Picking the noise model a command uses: a calibrated ISO, an interpolated one, or a baseline.

use std::path::Path;

use anyhow::bail;
use noisecal_core::derive::baselines::{self, BaselineKind};
use noisecal_core::derive::interp;
use noisecal_core::model::pack::{IsoModel, ModelOrigin};
use noisecal_core::model::structure::Components;
use noisecal_core::synth::CleanAt;
use noisecal_core::synth::sampler::{IsoSampler, carried_gain_ratio};
use noisecal_core::{BlackAlignment, ModelPack, SensorLayout};

/// Which noise model to synthesize with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, clap::ValueEnum)]
pub enum ModelKind {
    /// The calibrated non-parametric model (interpolated between calibrated ISOs when needed).
    Noisecal,
    /// Heteroscedastic Gaussian fitted on the same calibration data.
    Hg,
    /// Poisson–Gaussian with clipping fitted on the same calibration data.
    Pg,
    /// The camera's own NoiseProfile (DNG tag 51041 / SENSOR_NOISE_PROFILE).
    Noiseprofile,
}

impl ModelKind {
    /// The parametric baseline this kind names, if any.
    pub fn baseline(self) -> Option<BaselineKind> {
        match self {
            ModelKind::Noisecal => None,
            ModelKind::Hg => Some(BaselineKind::Hg),
            ModelKind::Pg => Some(BaselineKind::Pg),
            ModelKind::Noiseprofile => Some(BaselineKind::NoiseProfile),
        }
    }
}

/// The model for `iso`, and a note for stderr when it was interpolated or is a baseline.
pub fn resolve_model(
    pack: &ModelPack,
    iso: u32,
    kind: ModelKind,
    extrapolate: bool,
) -> anyhow::Result<(IsoModel, Option<String>)> {
    match kind.baseline() {
        None => {
            let (m, derived) = interp::model_for(pack, iso, extrapolate)?;
            let note = derived.then(|| match &m.origin {
                ModelOrigin::Interpolated { from } => {
                    format!("ISO {iso} is not calibrated: interpolated from ISOs {from:?}")
                }
                ModelOrigin::Extrapolated { from } => {
                    format!(
                        "ISO {iso} is outside the calibrated range: extrapolated from ISOs {from:?} (--extrapolate)"
                    )
                }
                ModelOrigin::Calibrated => String::new(),
            });
            Ok((m.into_owned(), note))
        }
        Some(b) => {
            let m = baselines::baseline_model(pack, iso, b, extrapolate)?;
            Ok((m, Some(format!("synthesizing with the {} baseline ({}) at ISO {iso}", b.name(), b.label()))))
        }
    }
}

/// The sampler of a resolved model ([`resolve_model`]) with the components `which`, for clean
/// images at the brightness `clean_at` says. At the target brightness the levels are divided by
/// the ISO's gain ratios (the model's own, or the pack's at that ISO for a baseline:
/// [`interp::gain_ratio_at`]) to pick their bins; the shift the non-parametric model's PMFs
/// carry ([`carried_gain_ratio`]) is taken back out (the baselines are zero-mean: nothing to
/// take out).
pub fn sampler_for(
    pack: &ModelPack,
    model: &IsoModel,
    kind: ModelKind,
    which: Components,
    clean_at: CleanAt,
    extrapolate: bool,
) -> anyhow::Result<IsoSampler> {
    let sampler = IsoSampler::with_components(pack, model, which);
    if clean_at == CleanAt::Reference {
        return Ok(sampler);
    }
    let (gains, carried) = match kind {
        ModelKind::Noisecal => (model.gain_ratio, Some(carried_gain_ratio(pack, model))),
        _ => (interp::gain_ratio_at(pack, model.iso, extrapolate)?, None),
    };
    sampler.clean_at(clean_at, pack.layout.black, gains, carried).map_err(anyhow::Error::msg)
}

/// Where an ISO model comes from, as reports and tables say it.
pub fn origin_text(origin: &ModelOrigin) -> String {
    match origin {
        ModelOrigin::Calibrated => "calibrated".into(),
        ModelOrigin::Interpolated { from } => format!("interpolated from {from:?}"),
        ModelOrigin::Extrapolated { from } => format!("extrapolated from {from:?}"),
    }
}

/// How an input image's levels carry onto the pack's black level (models are binned above
/// black, [`SensorLayout::align_to`]); said on stderr when they move.
pub fn align_input(pack: &ModelPack, layout: &SensorLayout, path: &Path, quiet: bool) -> BlackAlignment {
    let align = layout.align_to(&pack.layout);
    if !align.is_identity() && !quiet {
        eprintln!(
            "noisecal: warning: {} has black level {:?} but the pack's sensor has {:?} (off by up to {:.1} DN): levels are taken above black (shifted onto the pack's black level and back)",
            path.display(),
            layout.black,
            pack.layout.black,
            align.max_offset()
        );
    }
    align
}

/// Refuses an image whose CFA phase or levels do not match the pack's sensor.
pub fn check_layout_matches(pack: &ModelPack, layout: &SensorLayout, path: &Path) -> anyhow::Result<()> {
    if layout.cfa != pack.layout.cfa {
        bail!(
            "{} has CFA {} but the pack's sensor is {}: crop it to the pack's CFA phase or use a pack of this camera",
            path.display(),
            layout.cfa,
            pack.layout.cfa
        );
    }
    if layout.white != pack.layout.white {
        bail!(
            "{} has white level {} but the pack's sensor has {}: it comes from another camera or mode",
            path.display(),
            layout.white,
            pack.layout.white
        );
    }
    Ok(())
}
