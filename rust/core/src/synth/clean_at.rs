//! Which brightness a clean image is given at, and its names: the one choice both the sampler
//! and every front-end read.

/// Which brightness a clean image is given at (method.md, *Synthesis*).
///
/// A pack's bins are indexed by the **reference** ISO's level: calibration pairs a target burst
/// with the reference burst of the same EV step (ISO × exposure equal), and a bin's PMF is
/// `target − clean` at that clean level. Where the gain is not proportional to the ISO, the
/// target frames are `g` times brighter above black (`g` = [`IsoModel::gain_ratio`]), and the
/// PMFs carry that as a mean shift `(g − 1)·(level − black)`.
///
/// [`IsoModel::gain_ratio`]: crate::model::pack::IsoModel::gain_ratio
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum CleanAt {
    /// The clean image is at the reference ISO's brightness for the same ISO × exposure (a
    /// clean image averaged from base-ISO frames, as in calibration): the noisy image comes out
    /// at the target ISO's brightness, the gain ratio applied. The default: it is what the pack
    /// measures, and what every earlier release did (same bytes).
    #[default]
    Reference,
    /// The clean image is already at the target ISO's brightness (the expected target capture:
    /// averaged from target-ISO frames, or rendered to the output brightness): the noise has no
    /// gain shift, each level drawing the noise of the reference level `black + (level −
    /// black)/g`.
    Target,
}

impl CleanAt {
    /// `"reference"` or `"target"`.
    pub fn parse(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "reference" | "ref" => Ok(CleanAt::Reference),
            "target" => Ok(CleanAt::Target),
            other => Err(format!(
                "clean-at {other:?}: use \"reference\" (the clean image is at the reference ISO's brightness, the default) or \"target\" (it is already at the target ISO's brightness)"
            )),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            CleanAt::Reference => "reference",
            CleanAt::Target => "target",
        }
    }
}
