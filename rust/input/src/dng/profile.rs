//! The DNG `NoiseProfile` of a model: what a written DNG tells other tools about its noise.

use noisecal_core::derive::noise_law::fit_all;
use noisecal_core::model::pack::{IsoModel, NoiseProfile};
use noisecal_core::{ModelPack, SensorLayout};

/// The `NoiseProfile` (per CFA position, `σ²/R² = S·x + O` with `x = (l − black)/R` and
/// `R = white − black` of `layout`, the written image's levels) of the noise `model` synthesizes:
/// the variance law `σ² = a·(l − black) + b` fitted on the model's per-bin PMFs
/// ([`noisecal_core::derive::noise_law::fit_all`], the HG baseline's fit), normalised. `None`
/// when the fit is not a usable profile (not finite, or noise wider than the range).
pub fn fitted_noise_profile(pack: &ModelPack, model: &IsoModel, layout: &SensorLayout) -> Option<NoiseProfile> {
    let params = fit_all(&pack.binning(), model);
    let profile = NoiseProfile(std::array::from_fn(|p| {
        let r = (f64::from(layout.white) - f64::from(layout.black[p])).max(1.0);
        [params[p].a.max(0.0) / r, params[p].b.max(0.0) / (r * r)]
    }));
    profile.is_valid().then_some(profile)
}
