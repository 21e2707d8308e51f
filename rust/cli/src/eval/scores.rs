//! What `eval` measured: the result types, the contract of its text table ([`super::text`]), its
//! JSON (`--json`, read back by `noisecal report`) and the report's fidelity section. The numbers
//! come from [`noisecal_core::metrics`].

use noisecal_core::POSITIONS;
use noisecal_core::metrics::spatial::{NpsCurves, SpatialComparison, SpatialFloor};
use noisecal_core::metrics::{Floor, SeedMean};
use serde::{Deserialize, Serialize};

/// The scores of one level group (averaged over seeds).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroupRow {
    pub pos: usize,
    /// Clean levels `[lo, hi)` in DN.
    pub lo: f32,
    pub hi: f32,
    pub real_samples: u64,
    pub jsd: f64,
}

/// The scores of one model (or re-noise method) at one ISO, averaged over seeds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelScore {
    /// Short key: `noisecal`, `hg`, `pg`, `noiseprofile`, `noisecal-loo`, `hg-loo`, `bridge`, …
    pub name: String,
    pub label: String,
    /// Where the model comes from (calibrated, interpolated from …, fitted, camera profile).
    pub origin: String,
    pub marginal: [Option<f64>; POSITIONS],
    pub conditional: [Option<f64>; POSITIONS],
    /// KL(real ‖ synthetic) of the marginal histograms with add-one smoothing.
    pub kl: [Option<f64>; POSITIONS],
    pub marginal_overall: f64,
    pub conditional_overall: f64,
    pub kl_overall: f64,
    pub per_seed_marginal: Vec<f64>,
    pub per_seed_conditional: Vec<f64>,
    pub groups: Vec<GroupRow>,
}

impl ModelScore {
    /// A model's scores, averaged over its synthetic sets ([`noisecal_core::metrics::score_seeds`]).
    pub fn new(name: String, label: String, origin: String, s: SeedMean) -> Self {
        Self {
            name,
            label,
            origin,
            marginal: s.marginal,
            conditional: s.conditional,
            kl: s.kl,
            marginal_overall: s.marginal_overall,
            conditional_overall: s.conditional_overall,
            kl_overall: s.kl_overall,
            per_seed_marginal: s.per_seed_marginal,
            per_seed_conditional: s.per_seed_conditional,
            groups: s
                .groups
                .into_iter()
                .map(|g| GroupRow {
                    pos: g.pos,
                    lo: g.levels.0,
                    hi: g.levels.1,
                    real_samples: g.real_samples,
                    jsd: g.jsd,
                })
                .collect(),
        }
    }
}

/// Real half against real half ([`noisecal_core::metrics::Floor`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FloorScore {
    pub marginal: [Option<f64>; POSITIONS],
    pub conditional: [Option<f64>; POSITIONS],
    pub kl: [Option<f64>; POSITIONS],
    pub marginal_overall: f64,
    pub conditional_overall: f64,
    pub kl_overall: f64,
    pub samples_a: u64,
    pub samples_b: u64,
    /// Factor that carries the halves' floor to the sample sizes of the model comparison
    /// ([`noisecal_core::metrics::floor_scale`]).
    pub scale: f64,
}

impl FloorScore {
    /// The marginal floor at the models' sample sizes.
    pub fn marginal_scaled(&self) -> f64 {
        self.marginal_overall * self.scale
    }
    /// The conditional floor at the models' sample sizes.
    pub fn conditional_scaled(&self) -> f64 {
        self.conditional_overall * self.scale
    }
}

impl From<Floor> for FloorScore {
    fn from(f: Floor) -> Self {
        Self {
            marginal: f.scores.marginal,
            conditional: f.scores.conditional,
            kl: f.kl,
            marginal_overall: f.scores.marginal_overall,
            conditional_overall: f.scores.conditional_overall,
            kl_overall: f.kl_overall,
            samples_a: f.samples_a,
            samples_b: f.samples_b,
            scale: f.scale,
        }
    }
}

/// Everything measured at one ISO.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IsoEval {
    pub iso: u32,
    /// The pack's model of this ISO: calibrated, interpolated (materialized), or interpolated now.
    pub origin: String,
    pub frames: u64,
    pub steps: usize,
    pub samples: [u64; POSITIONS],
    pub floor: Option<FloorScore>,
    pub models: Vec<ModelScore>,
    /// Spatial measures (row, column and frame-level noise, noise power spectra); absent from
    /// the JSON of evaluations made before they existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spatial: Option<SpatialEval>,
}

/// The spatial measures of one ISO ([`noisecal_core::metrics::spatial`]): what the real frames
/// show, the finite-sample floor (real half against real half) and each model's synthetic
/// against real.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpatialEval {
    /// Real frames measured.
    pub frames: u64,
    /// Variance across rows of the centred per-row mean noise (DN²), mean over frames, and its
    /// standard error.
    pub row_var: Option<f64>,
    pub row_var_se: Option<f64>,
    /// The same across columns.
    pub col_var: Option<f64>,
    pub col_var_se: Option<f64>,
    /// Row means pooled into the row-offset histogram.
    pub row_offsets: u64,
    /// The common bin width of the row-offset histograms (DN).
    pub row_offset_bin_width: Option<f64>,
    /// Within-burst variance of the per-frame mean noise per position (DN²).
    pub frame_offset_var: [Option<f64>; POSITIONS],
    /// Real noise power spectrum curves per position.
    pub nps: [Option<NpsCurves>; POSITIONS],
    /// Real half against real half.
    pub floor: Option<SpatialFloor>,
    /// Each model's synthetic noise against the real noise (averaged over seeds).
    pub models: Vec<SpatialModelScore>,
}

impl SpatialEval {
    /// The spatial scores of a model.
    pub fn model(&self, name: &str) -> Option<&SpatialModelScore> {
        self.models.iter().find(|m| m.name == name)
    }
}

/// One model's spatial measures at one ISO: ratios synthetic/real, the row-offset JSD and the
/// NPS distance (averaged over seeds), and its NPS curves (seeds pooled).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpatialModelScore {
    pub name: String,
    #[serde(flatten)]
    pub scores: SpatialComparison,
    pub nps: [Option<NpsCurves>; POSITIONS],
}

impl IsoEval {
    pub fn model(&self, name: &str) -> Option<&ModelScore> {
        self.models.iter().find(|m| m.name == name)
    }
}

/// One row of the leave-one-out study (conditional and marginal JSD, overall).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LooRow {
    pub iso: u32,
    /// Calibrated ISOs the interpolation used.
    pub from: Vec<u32>,
    pub calibrated: [f64; 2],
    pub interpolated: [f64; 2],
    pub hg_calibrated: [f64; 2],
    pub hg_interpolated: [f64; 2],
    /// Scaled finite-sample floor.
    pub floor: Option<[f64; 2]>,
}

/// Noise on noise from ISO `from` to ISO `to`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RenoiseEval {
    pub from: u32,
    pub to: u32,
    pub frames_from: u64,
    pub frames_to: u64,
    pub steps: usize,
    /// One score per method, and `direct` (noisecal at `to` synthesized on the clean image).
    pub methods: Vec<ModelScore>,
    pub floor: Option<FloorScore>,
    pub warnings: Vec<String>,
}

/// The result of `noisecal eval`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub pack: String,
    pub heldout: String,
    pub camera: String,
    pub seeds: u32,
    pub group_bins: usize,
    /// Names of CFA positions 0..4 (R, Gr, Gb, B in the pack's CFA order).
    pub positions: Vec<String>,
    pub isos: Vec<IsoEval>,
    pub leave_one_out: Option<Vec<LooRow>>,
    pub renoise: Option<RenoiseEval>,
    pub notes: Vec<String>,
}
