//! The command line's side of picking a model: `--model` parsed by the core's names
//! ([`noisecal_core::resolve`], where the models, their components and the black alignment live),
//! and what the commands say on stderr about the model and an input's black level.

use std::path::Path;

use anyhow::bail;
use clap::builder::{PossibleValuesParser, TypedValueParser};
use noisecal_core::resolve::{ModelKind, Resolved, layout_mismatch};
use noisecal_core::{BlackAlignment, ModelPack, SensorLayout};

pub use noisecal_core::resolve::{origin_text, resolve_model};

/// `--model NAME`: one of the core's model names ([`ModelKind::names`]), listed in `--help`.
pub fn model_parser() -> impl TypedValueParser<Value = ModelKind> {
    PossibleValuesParser::new(ModelKind::names()).map(|name: String| ModelKind::parse(&name).unwrap_or_default())
}

/// What to say on stderr about a resolved model: how an uncalibrated ISO was derived (naming
/// `--extrapolate` when it was extrapolated), or which baseline is used.
pub fn note(resolved: &Resolved) -> Option<String> {
    let note = resolved.note()?;
    Some(if resolved.extrapolated() { format!("{note} (--extrapolate)") } else { note })
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
    if let Some(why) = layout_mismatch(pack, layout) {
        bail!("{} {why}", path.display());
    }
    Ok(())
}
