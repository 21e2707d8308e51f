//! Picking the noise model a command uses: a calibrated ISO, an interpolated one, or a baseline.

use std::path::Path;

use anyhow::bail;
use noisecal_core::pack::IsoModel;
use noisecal_core::{ModelPack, SensorLayout};

/// Which noise model to synthesize with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
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

/// The model for `iso`, and a note for stderr when it was interpolated or is a baseline.
pub fn resolve_model(pack: &ModelPack, iso: u32, kind: ModelKind, extrapolate: bool) -> anyhow::Result<(IsoModel, Option<String>)> {
    match kind {
        ModelKind::Noisecal => match pack.iso(iso) {
            Some(m) => Ok((m.clone(), None)),
            None => {
                let _ = extrapolate;
                bail!(noisecal_core::error::ModelError::IsoMissing { iso, available: pack.iso_summary() })
            }
        },
        other => bail!("the {other:?} baseline is not available in this build"),
    }
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
