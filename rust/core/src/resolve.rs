//! Which noise model a front-end synthesizes with, in one place for the CLI, the Python package
//! and the app: the model names, the model of an ISO (calibrated, interpolated, extrapolated, or
//! a parametric baseline), the noise components each kind carries, its sampler, and carrying an
//! image whose black level differs from the pack's onto the pack's and back.
//!
//! ```text
//! ModelKind::parse("hg") ─ ModelRequest { kind, iso, extrapolate } ─ resolve(pack) → Resolved
//!     Resolved::sampler(pack, components, clean_at) → IsoSampler
//! resolve_on_demand(LazyPack, iso, kind, components) → (the ISOs it needs as a ModelPack, Resolved)
//! BlackAlignment::around(image, white, origin, |on_pack_black| synthesize(…)) → on its own black
//! ```
//!
//! Messages name no front-end's flags: a front-end adds its own ("--extrapolate", `extrapolate=True`).

use std::borrow::Cow;

use ndarray::{Array2, ArrayView2};

use crate::ModelPack;
use crate::derive::baselines::{self, BaselineKind};
use crate::derive::fine_levels::target_fine_levels;
use crate::derive::interp;
use crate::derive::interp::{CalibratedLaw, InterpOptions};
use crate::derive::structure::{derived_structure_sources, structure_at};
use crate::error::{CodecError, Error, ModelError};
use crate::format::lazy_pack::LazyPack;
use crate::model::layout::{BlackAlignment, POSITIONS, SensorLayout};
use crate::model::pack::{IsoModel, ModelOrigin};
use crate::model::structure::Components;
use crate::synth::CleanAt;
use crate::synth::sampler::{IsoSampler, carried_gain_ratio};
use crate::synth::sampler_up_to::SamplerUpTo;

/// Which noise model to synthesize with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ModelKind {
    /// The calibrated non-parametric model (interpolated between calibrated ISOs when needed).
    #[default]
    Noisecal,
    /// Heteroscedastic Gaussian fitted on the same calibration data.
    Hg,
    /// Poisson–Gaussian with clipping fitted on the same calibration data.
    Pg,
    /// The camera's own NoiseProfile (DNG tag 51041 / SENSOR_NOISE_PROFILE).
    Noiseprofile,
}

impl ModelKind {
    /// Every kind, in the order the front-ends list them.
    pub const ALL: [ModelKind; 4] = [ModelKind::Noisecal, ModelKind::Hg, ModelKind::Pg, ModelKind::Noiseprofile];

    /// The kind's name, as every front-end spells it.
    pub fn name(self) -> &'static str {
        match self.baseline() {
            None => "noisecal",
            Some(b) => b.name(),
        }
    }

    /// Every name, in [`ModelKind::ALL`]'s order.
    pub fn names() -> [&'static str; 4] {
        Self::ALL.map(Self::name)
    }

    /// The kind a name says (any case).
    pub fn parse(name: &str) -> Result<Self, String> {
        Self::ALL.into_iter().find(|k| k.name().eq_ignore_ascii_case(name)).ok_or_else(|| {
            let names: Vec<String> = Self::names().iter().map(|n| format!("{n:?}")).collect();
            let (last, rest) = names.split_last().expect("four names");
            format!("unknown model {name:?}: use {} or {last}", rest.join(", "))
        })
    }

    /// The parametric baseline this kind names, if any.
    pub fn baseline(self) -> Option<BaselineKind> {
        match self {
            ModelKind::Noisecal => None,
            ModelKind::Hg => Some(BaselineKind::Hg),
            ModelKind::Pg => Some(BaselineKind::Pg),
            ModelKind::Noiseprofile => Some(BaselineKind::NoiseProfile),
        }
    }

    /// The noise components this kind synthesizes when `asked` are asked for (`None`: every
    /// component the pack calibrated). The parametric baselines are pixel-independent models:
    /// pixel noise only, whatever is asked.
    pub fn components(self, asked: Option<Components>) -> Components {
        match self {
            ModelKind::Noisecal => asked.unwrap_or(Components::ALL),
            _ => Components::PIXEL,
        }
    }
}

/// The model of an ISO, as it was resolved ([`resolve_model`]).
#[derive(Debug, Clone)]
pub struct Resolved {
    pub model: IsoModel,
    pub kind: ModelKind,
}

impl Resolved {
    /// What a front-end tells the user about this model: how an uncalibrated ISO was derived, or
    /// which baseline is used; `None` for a calibrated ISO of the non-parametric model.
    pub fn note(&self) -> Option<String> {
        let iso = self.model.iso;
        match self.kind.baseline() {
            Some(b) => Some(format!("synthesizing with the {} baseline ({}) at ISO {iso}", b.name(), b.label())),
            None => match &self.model.origin {
                ModelOrigin::Calibrated => None,
                ModelOrigin::Interpolated { from } => {
                    Some(format!("ISO {iso} is not calibrated: interpolated from ISOs {from:?}"))
                }
                ModelOrigin::Extrapolated { from } => {
                    Some(format!("ISO {iso} is outside the calibrated range: extrapolated from ISOs {from:?}"))
                }
            },
        }
    }

    /// Whether the model was extrapolated beyond the calibrated ISOs.
    pub fn extrapolated(&self) -> bool {
        matches!(self.model.origin, ModelOrigin::Extrapolated { .. })
    }

    /// The sampler of this model ([`sampler_for`]).
    pub fn sampler(
        &self,
        pack: &ModelPack,
        which: Components,
        clean_at: CleanAt,
        extrapolate: bool,
    ) -> Result<IsoSampler, ModelError> {
        sampler_for(pack, &self.model, self.kind, which, clean_at, extrapolate)
    }

    /// [`Self::sampler`] for clean images whose levels are all at most `top`, which it alone
    /// draws ([`SamplerUpTo`]: an image with a level above `top` is refused). At the reference
    /// brightness only the bins those levels reach are deconvolved (the same bytes on such
    /// images); at the target brightness it is [`Self::sampler`]'s.
    pub fn sampler_up_to(
        &self,
        pack: &ModelPack,
        which: Components,
        clean_at: CleanAt,
        extrapolate: bool,
        top: u16,
    ) -> Result<SamplerUpTo, ModelError> {
        if clean_at != CleanAt::Reference {
            return Ok(SamplerUpTo::full(self.sampler(pack, which, clean_at, extrapolate)?, top));
        }
        let structure = if which.structured() { structure_at(pack, self.model.iso) } else { None };
        let sampler = SamplerUpTo::new(pack, &self.model, structure.as_ref(), which, top);
        sampler.map(|s| baseline_levels(pack, &self.model, self.kind, s, [1.0; POSITIONS], extrapolate))
    }
}

/// The sampler of a model of `kind` ([`resolve_model`]) with the components `which`, for clean
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
) -> Result<IsoSampler, ModelError> {
    let sampler = IsoSampler::with_components(pack, model, which);
    if clean_at == CleanAt::Reference {
        return baseline_levels(pack, model, kind, sampler, [1.0; POSITIONS], extrapolate);
    }
    let (gains, carried) = match kind {
        ModelKind::Noisecal => (model.gain_ratio, Some(carried_gain_ratio(pack, model))),
        _ => (interp::gain_ratio_at(pack, model.iso, extrapolate)?, None),
    };
    let sampler = sampler.clean_at(clean_at, pack.layout.black, gains, carried).map_err(ModelError::Unsupported)?;
    if kind != ModelKind::Noisecal {
        return baseline_levels(pack, model, kind, sampler, gains, extrapolate);
    }
    // Near black, the levels of a bin too wide for the noise there at their own reference level
    // (made from the model's own bins, deconvolved by the sampler as its bins are).
    let fine = std::array::from_fn(|p| {
        let own = &model.positions[p].bins;
        target_fine_levels(pack, model, p, || Cow::Borrowed(&own[..]), gains[p])
    });
    Ok(sampler.with_target_fine_levels(model, fine))
}

/// A parametric baseline's sampler drawing at each clean level from its law at that level (its
/// reference level `black + (c − black)/gain`), not from the bin's average
/// ([`baselines::Baseline::level_tables`]); the non-parametric model's sampler as it is.
fn baseline_levels(
    pack: &ModelPack,
    model: &IsoModel,
    kind: ModelKind,
    sampler: IsoSampler,
    gains: [f64; POSITIONS],
    extrapolate: bool,
) -> Result<IsoSampler, ModelError> {
    let Some(b) = kind.baseline() else { return Ok(sampler) };
    let baseline = baselines::baseline(pack, model.iso, b, extrapolate)?;
    let binning = pack.binning();
    let tables = std::array::from_fn(|p| baseline.level_tables(&binning, p, gains[p]));
    Ok(sampler.with_level_tables(tables))
}

impl IsoSampler {
    /// The sampler of a model with every structured component the pack has for its ISO
    /// ([`Self::with_components`] with [`Components::ALL`]).
    pub fn new(pack: &ModelPack, model: &IsoModel) -> Self {
        Self::with_components(pack, model, Components::ALL)
    }

    /// The sampler of a model with the components `which` asks for, of those the pack has for
    /// its ISO: stored, or derived from the calibrated ISOs ([`structure_at`]), then handed to
    /// the sampler ([`IsoSampler::with_structure`]); the sampler itself derives nothing.
    pub fn with_components(pack: &ModelPack, model: &IsoModel, which: Components) -> Self {
        let structure = if which.structured() { structure_at(pack, model.iso) } else { None };
        Self::with_structure(pack, model, structure.as_ref(), which)
    }
}

/// The model of `kind` at `iso`: a calibrated ISO's own, one interpolated between calibrated
/// ISOs (or extrapolated beyond them when `extrapolate`), or a parametric baseline fitted on the
/// pack's data.
pub fn resolve_model(pack: &ModelPack, iso: u32, kind: ModelKind, extrapolate: bool) -> Result<Resolved, ModelError> {
    let model = match kind.baseline() {
        None => interp::model_for(pack, iso, extrapolate)?.0.into_owned(),
        Some(b) => baselines::baseline_model(pack, iso, b, extrapolate)?,
    };
    Ok(Resolved { model, kind })
}

/// The model of `kind` at `iso` from a pack read on demand, and the pack of the ISOs it and its
/// sampler with the components `which` stand on (decoded now if they were not): the same model
/// and sampler as [`resolve_model`] and [`Resolved::sampler`] on the whole pack. A calibrated
/// (or stored) ISO needs itself; an interpolated one its plan's neighbours, planned from the
/// index's noise laws ([`interp::plan_among`]); structured components not stored for the ISO
/// need the calibrated ISOs they are derived from ([`derived_structure_sources`]). The
/// parametric baselines are fitted over the calibrated ISOs: they decode the whole pack.
pub fn resolve_on_demand<B: std::ops::Deref<Target = [u8]>>(
    lazy: &LazyPack<B>,
    iso: u32,
    kind: ModelKind,
    which: Components,
    extrapolate: bool,
) -> Result<(ModelPack, Resolved), Error> {
    if kind.baseline().is_some() {
        let pack = lazy.to_pack()?;
        let resolved = resolve_model(&pack, iso, kind, extrapolate)?;
        return Ok((pack, resolved));
    }
    let index = lazy.index();
    let stored = index.entry(iso);
    let plan = match stored {
        Some(_) => None,
        None => {
            // The laws from the index; a dark step's variance at black from the ISO's
            // structured components (read without its weights): the whole pack's plan.
            let laws = index
                .isos
                .iter()
                .filter(|e| e.is_calibrated())
                .map(|e| {
                    // One read of the section for its fields and its components.
                    let (fields, st) = lazy.fields_of(e.iso)?.map_or((None, None), |(m, st)| (Some(m), st));
                    Ok(CalibratedLaw::measured(e.iso, e.noise_law(), &index.layout, fields.as_ref(), st.as_ref()))
                })
                .collect::<Result<Vec<CalibratedLaw>, CodecError>>()?;
            Some(interp::plan_among(&laws, index.isos.is_empty(), iso, extrapolate, &InterpOptions::default())?)
        }
    };
    let mut needed: Vec<u32> = match &plan {
        None => vec![iso],
        Some(p) => p.neighbours.iter().chain(&p.shape_from).copied().collect(),
    };
    if which.structured() && !stored.is_some_and(|e| e.structured) {
        let measured: Vec<u32> =
            index.isos.iter().filter(|e| e.is_calibrated() && e.structured).map(|e| e.iso).collect();
        needed.extend(derived_structure_sources(&measured, iso));
    }
    let pack = lazy.pack_with(&needed)?;
    let model = match &plan {
        None => pack.require_iso(iso)?.clone(),
        Some(p) => interp::interpolate_planned(&pack, p),
    };
    Ok((pack, Resolved { model, kind }))
}

/// Where an ISO model comes from, as reports and tables say it.
pub fn origin_text(origin: &ModelOrigin) -> String {
    match origin {
        ModelOrigin::Calibrated => "calibrated".into(),
        ModelOrigin::Interpolated { from } => format!("interpolated from {from:?}"),
        ModelOrigin::Extrapolated { from } => format!("extrapolated from {from:?}"),
    }
}

/// Why an image cannot take a pack's noise: another CFA phase or white level (another camera or
/// mode); `None` when it can. Black levels may differ ([`BlackAlignment`] carries them).
pub fn layout_mismatch(pack: &ModelPack, layout: &SensorLayout) -> Option<String> {
    if layout.cfa != pack.layout.cfa {
        return Some(format!(
            "has CFA {} but the pack's sensor is {}: crop it to the pack's CFA phase or use a pack of this camera",
            layout.cfa, pack.layout.cfa
        ));
    }
    if layout.white != pack.layout.white {
        return Some(format!(
            "has white level {} but the pack's sensor has {}: it comes from another camera or mode",
            layout.white, pack.layout.white
        ));
    }
    None
}

impl BlackAlignment {
    /// `f` applied to `img` carried onto the pack's black level, and its result carried back
    /// (models are binned by level above black, [`SensorLayout::align_to`]); `f` sees `img`
    /// itself when the black levels agree. `origin` is the CFA position (row, column) of `img`'s
    /// (0, 0) and `white` the sensor's white level. Synthesis and re-noising both go through
    /// here, so an input off the pack's black level is treated alike by every front-end.
    pub fn around(
        &self,
        img: ArrayView2<'_, u16>,
        white: u16,
        origin: (usize, usize),
        f: impl FnOnce(ArrayView2<'_, u16>) -> Array2<u16>,
    ) -> Array2<u16> {
        match self.try_around(img, white, origin, |a| Ok::<_, std::convert::Infallible>(f(a))) {
            Ok(out) => out,
            Err(never) => match never {},
        }
    }

    /// As [`Self::around`], for an `f` that can fail.
    pub fn try_around<E>(
        &self,
        img: ArrayView2<'_, u16>,
        white: u16,
        origin: (usize, usize),
        f: impl FnOnce(ArrayView2<'_, u16>) -> Result<Array2<u16>, E>,
    ) -> Result<Array2<u16>, E> {
        if self.is_identity() {
            return f(img);
        }
        let moved = self.apply_at(img, white, origin);
        Ok(self.undo_at(f(moved.view())?.view(), white, origin))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for k in ModelKind::ALL {
            assert_eq!(ModelKind::parse(k.name()), Ok(k));
            assert_eq!(ModelKind::parse(&k.name().to_ascii_uppercase()), Ok(k));
        }
        assert_eq!(
            ModelKind::parse("gauss").unwrap_err(),
            "unknown model \"gauss\": use \"noisecal\", \"hg\", \"pg\" or \"noiseprofile\""
        );
    }

    #[test]
    fn alignment_is_undone_around_the_work() {
        let img = Array2::from_shape_fn((4, 6), |(y, x)| (100 + 10 * y + x) as u16);
        let align = BlackAlignment::between([60.0, 64.0, 64.0, 70.0], [64.0; 4]);
        // The identity is undone exactly; at an odd origin each pixel moves by its own position's shift.
        for origin in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            assert_eq!(align.around(img.view(), 1023, origin, |a| a.to_owned()), img);
            let seen = align.around(img.view(), 1023, origin, |a| {
                assert_eq!(a, align.apply_at(img.view(), 1023, origin));
                a.to_owned()
            });
            assert_eq!(seen, img);
        }
        let none = BlackAlignment::between([64.0; 4], [64.0; 4]);
        assert_eq!(none.try_around(img.view(), 1023, (1, 1), |a| Ok::<_, ()>(a.to_owned())), Ok(img));
    }

    #[test]
    fn baselines_are_pixel_only() {
        assert_eq!(ModelKind::Hg.components(Some(Components::ALL)), Components::PIXEL);
        assert_eq!(ModelKind::Noisecal.components(None), Components::ALL);
        assert_eq!(ModelKind::Noisecal.components(Some(Components::PIXEL)), Components::PIXEL);
    }
}
