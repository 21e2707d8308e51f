//! The models scored at an ISO: the pack's own, the parametric baselines fitted on the same
//! calibration (HG, PG, the camera's NoiseProfile) and, for leave-one-out, the ISO interpolated
//! from the others (noisecal and HG).

use anyhow::anyhow;
use noisecal_core::ModelPack;
use noisecal_core::derive::baselines::{self, BaselineKind, BaselineSource};
use noisecal_core::derive::interp;
use noisecal_core::error::ModelError;
use noisecal_core::metrics::NoiseSamples;
use noisecal_core::metrics::spatial::SpatialSamples;
use noisecal_core::model::NoiseProfile;
use noisecal_core::model::pack::IsoModel;
use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::IsoSampler;
use rayon::prelude::*;

use crate::models::origin_text;

/// The pack's own row: every component but the fixed pattern ([`Components::ON_OWN_CAPTURES`]),
/// because the held-out clean images are burst means of this sensor's frames, which carry its
/// pattern already (adding it again read above pixel-only by about the pattern's variance on
/// EMVA 1288 set 002; method.md, *Fixed pattern*, "Which components for which clean image").
pub(super) const OWN_LABEL: &str = "noisecal (non-parametric; components pixel,row,column,frame: no fpn, the held-out clean images are burst means, which carry the fixed pattern)";

/// A model scored against held-out captures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CandidateKind {
    /// The pack's model of the ISO (calibrated, or interpolated).
    Noisecal,
    Hg,
    Pg,
    /// The camera's NoiseProfile: the pack's, else the held-out captures' own.
    NoiseProfile,
    /// The ISO left out of the pack and interpolated from the other calibrated ISOs.
    NoisecalLoo,
    /// HG interpolated parametrically from the other calibrated ISOs.
    HgLoo,
    /// The pack's model without its structured components (row, column, frame offsets): the
    /// pixel-independent model alone. Scored only where the pack has such components.
    NoisecalPixel,
}

impl CandidateKind {
    /// Every kind, in the order they are scored and reported.
    pub const ALL: [Self; 7] =
        [Self::Noisecal, Self::Hg, Self::Pg, Self::NoiseProfile, Self::NoisecalLoo, Self::HgLoo, Self::NoisecalPixel];

    /// The short key of the scores (`ModelScore::name`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Noisecal => "noisecal",
            Self::Hg => "hg",
            Self::Pg => "pg",
            Self::NoiseProfile => "noiseprofile",
            Self::NoisecalLoo => "noisecal-loo",
            Self::HgLoo => "hg-loo",
            Self::NoisecalPixel => "noisecal-pixel",
        }
    }

    pub fn is_leave_one_out(self) -> bool {
        matches!(self, Self::NoisecalLoo | Self::HgLoo)
    }
}

/// A model being scored: its sampler and one synthetic accumulator per seed.
pub(super) struct Candidate {
    pub(super) kind: CandidateKind,
    pub(super) label: String,
    pub(super) origin: String,
    pub(super) sampler: IsoSampler,
    pub(super) synth: Vec<NoiseSamples>,
    /// The spatial statistics of each synthetic set.
    pub(super) spatial: Vec<SpatialSamples>,
}

/// The candidates of one ISO, and what building them noticed.
pub(super) struct Candidates {
    /// Where the pack's model of the ISO comes from.
    pub(super) origin: String,
    pub(super) list: Vec<Candidate>,
    pub(super) notes: Vec<String>,
    /// With leave-one-out: the calibrated ISOs the left-out ISO was interpolated from.
    pub(super) loo_from: Option<Vec<u32>>,
}

/// A candidate other than the pack's own model, as built.
struct BuiltModel {
    label: String,
    origin: String,
    model: IsoModel,
    /// Leave-one-out: the calibrated ISOs the left-out ISO was interpolated from.
    from: Option<Vec<u32>>,
    /// A parametric baseline's law: its sampler draws at each clean level from the law at that
    /// level, as `synth --model` does ([`baselines::Baseline::level_tables`]), not from the
    /// bin's average.
    law: Option<baselines::Baseline>,
}

/// A candidate, or why it cannot be scored.
type Built = Result<BuiltModel, String>;

/// The candidates scored at `iso`, each with `seeds` empty accumulators from `fresh`; errors for
/// an ISO the pack cannot model. `profile` is the held-out captures' NoiseProfile of the ISO.
pub(super) fn candidates(
    pack: &ModelPack,
    iso: u32,
    profile: Option<NoiseProfile>,
    leave_one_out: bool,
    seeds: u32,
    fresh: &(dyn Fn() -> NoiseSamples + Sync),
) -> anyhow::Result<Candidates> {
    let cal = pack.calibrated_isos();
    let (model, derived) = interp::model_for(pack, iso, false).map_err(|e| match e {
        ModelError::IsoOutOfRange { min, max, .. } => anyhow!(
            "the held-out set has frames at ISO {iso}, outside the pack's calibrated range ISO {min}–{max}: eval only scores ISOs the pack models; remove those frames or calibrate ISO {iso}"
        ),
        other => anyhow!("held-out frames at ISO {iso}: {other}"),
    })?;
    let model = model.into_owned();
    let mut notes = Vec::new();
    let origin = if derived && pack.iso(iso).is_none() {
        let from = interp::plan(pack, iso, false).map(|p| p.neighbours).unwrap_or_default();
        notes.push(format!("ISO {iso} is not in the pack: scored with a model interpolated now from ISOs {from:?}"));
        format!("interpolated now from {from:?}")
    } else {
        origin_text(&model.origin)
    };
    let inner =
        cal.len() >= 3 && pack.iso(iso).is_some_and(|m| m.is_calibrated()) && iso > cal[0] && iso < cal[cal.len() - 1];
    let loo = leave_one_out && inner;
    let without = loo.then(|| {
        let mut p = pack.clone();
        p.isos.retain(|m| m.iso != iso);
        p.structure.retain(|s| s.iso != iso);
        p
    });
    let binning = pack.binning();
    let candidate = |kind: CandidateKind,
                     label: String,
                     origin: String,
                     m: &IsoModel,
                     law: Option<&baselines::Baseline>| Candidate {
        kind,
        label,
        origin,
        // The parametric baselines are pixel-independent models: no structured components.
        sampler: match kind {
            // Held-out clean images are means of this sensor's frames: they carry its pattern.
            CandidateKind::Noisecal => IsoSampler::with_components(pack, m, Components::ON_OWN_CAPTURES),
            // Like with like: the interpolated model gets the same components as the calibrated
            // one, themselves derived from the other ISOs (with its pixel PMFs alone, the
            // calibrated row carried row, column and frame offsets the interpolated one did not).
            CandidateKind::NoisecalLoo => {
                IsoSampler::with_components(without.as_ref().unwrap_or(pack), m, Components::ON_OWN_CAPTURES)
            }
            // The held-out clean images are at the reference brightness: each level's law is the
            // law at that level (gain 1).
            _ => {
                let sampler = IsoSampler::with_components(pack, m, Components::PIXEL);
                match law {
                    Some(b) => sampler.with_level_tables(std::array::from_fn(|p| b.level_tables(&binning, p, 1.0))),
                    None => sampler,
                }
            }
        },
        synth: (0..seeds).map(|_| fresh()).collect(),
        spatial: (0..seeds).map(|_| SpatialSamples::new()).collect(),
    };
    let mut list = vec![candidate(CandidateKind::Noisecal, OWN_LABEL.into(), origin.clone(), &model, None)];
    // With structured components, the pixel-independent model alone is scored next to it: what
    // the components add (the pixel-only model and the full one side by side in one evaluation).
    if list[0].sampler.structure().is_some() {
        list.push(Candidate {
            kind: CandidateKind::NoisecalPixel,
            label: "noisecal, pixel noise only (components pixel: no row, column or frame offsets, no fixed pattern)"
                .into(),
            origin: origin.clone(),
            sampler: IsoSampler::with_components(pack, &model, Components::PIXEL),
            synth: (0..seeds).map(|_| fresh()).collect(),
            spatial: (0..seeds).map(|_| SpatialSamples::new()).collect(),
        });
    }
    // Baseline PMFs take a while to tabulate (PG sums Poisson terms): build them in parallel.
    let kinds: Vec<CandidateKind> =
        CandidateKind::ALL[1..].iter().copied().filter(|k| loo || !k.is_leave_one_out()).collect();
    let built: Vec<(CandidateKind, Option<Built>)> =
        kinds.par_iter().map(|&kind| (kind, build(kind, pack, iso, &model, profile, without.as_ref()))).collect();
    // Leave-one-out scores come in pairs (noisecal and HG) or not at all.
    let loo_ok = built.iter().filter(|(k, r)| k.is_leave_one_out() && matches!(r, Some(Ok(_)))).count() == 2;
    let mut loo_from = None;
    for (kind, r) in built {
        match r {
            Some(Ok(b)) => {
                if kind.is_leave_one_out() && !loo_ok {
                    continue;
                }
                if b.from.is_some() {
                    loo_from = b.from;
                }
                list.push(candidate(kind, b.label, b.origin, &b.model, b.law.as_ref()));
            }
            Some(Err(e)) => notes.push(e),
            None => {}
        }
    }
    Ok(Candidates { origin, list, notes, loo_from })
}

/// One candidate other than the pack's own model; `None` where there is nothing to score (no
/// NoiseProfile, no leave-one-out).
fn build(
    kind: CandidateKind,
    pack: &ModelPack,
    iso: u32,
    model: &IsoModel,
    profile: Option<NoiseProfile>,
    without: Option<&ModelPack>,
) -> Option<Built> {
    let baseline = |b: baselines::Baseline, bk: BaselineKind| BuiltModel {
        label: bk.label().to_string(),
        origin: baseline_origin(&b.source),
        model: b.to_model(pack),
        from: None,
        law: Some(b),
    };
    match kind {
        CandidateKind::Noisecal | CandidateKind::NoisecalPixel => None,
        CandidateKind::Hg | CandidateKind::Pg => {
            let bk = if kind == CandidateKind::Hg { BaselineKind::Hg } else { BaselineKind::Pg };
            Some(
                baselines::baseline(pack, iso, bk, false)
                    .map(|b| baseline(b, bk))
                    .map_err(|e| format!("ISO {iso}: no {} baseline: {e}", kind.name())),
            )
        }
        // The pack's NoiseProfile, else the held-out captures' own for this ISO.
        CandidateKind::NoiseProfile => baselines::baseline(pack, iso, BaselineKind::NoiseProfile, false)
            .ok()
            .or_else(|| {
                let mut m = model.clone();
                m.noise_profile = Some(profile?);
                baselines::fit(pack, &m, BaselineKind::NoiseProfile).ok()
            })
            .map(|b| Ok(baseline(b, BaselineKind::NoiseProfile))),
        CandidateKind::NoisecalLoo => without.map(|w| {
            interp::interpolate_with(w, iso, false, &interp::InterpOptions::default())
                .map(|(m, plan)| BuiltModel {
                    label:
                        "noisecal interpolated (leave-one-out; components pixel,row,column,frame as the calibrated row)"
                            .to_string(),
                    origin: format!("interpolated from {:?} (ISO {iso} left out)", plan.neighbours),
                    model: m,
                    from: Some(plan.neighbours),
                    law: None,
                })
                .map_err(|e| format!("leave-one-out at ISO {iso}: {e}"))
        }),
        CandidateKind::HgLoo => without.map(|w| {
            baselines::interpolate(w, iso, BaselineKind::Hg, false)
                .map(|h| BuiltModel {
                    label: "HG interpolated parametrically (leave-one-out)".to_string(),
                    origin: baseline_origin(&h.source),
                    model: h.to_model(pack),
                    from: None,
                    law: Some(h),
                })
                .map_err(|e| format!("leave-one-out HG at ISO {iso}: {e}"))
        }),
    }
}

fn baseline_origin(s: &BaselineSource) -> String {
    match s {
        BaselineSource::Fitted => "fitted on the pack's histograms".into(),
        BaselineSource::CameraProfile => "the camera's NoiseProfile".into(),
        BaselineSource::Interpolated { from, extrapolated } => {
            format!("{} parametrically from {from:?}", if *extrapolated { "extrapolated" } else { "interpolated" })
        }
    }
}
