//! What the estimator decided for one (ISO, CFA position), as a pack stores it for `inspect`
//! and `report`: the pooling and clip mode chosen, how they were chosen, the held-out scores and
//! the fitted noise law (method.md, "Estimation").

use serde::{Deserialize, Serialize};

#[cfg(doc)]
use crate::model::bin_source::BinSource;

/// What clipped bins hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ClipMode {
    /// Their own (clipped) histogram.
    Own,
    /// The unclipped noise the law predicts, pooled from unclipped bins; synthesis clips.
    Law,
}

/// How the pooling and the clip mode were chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Choice {
    /// Cross-validated over this many folds that held samples.
    CrossValidated { folds: u8 },
    /// Set by the user.
    Fixed,
    /// Too few folds held samples to cross-validate: defaults used.
    Default,
    /// The plain per-bin histogram was asked for.
    Plain,
}

/// Held-out score of one candidate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateScore {
    /// Pooling threshold `m`.
    pub pooling: u64,
    /// Held-out cross-entropy, nats per held-out sample (lower is better).
    pub cross_entropy: f64,
}

/// What the estimator decided for one (ISO, position), kept in the pack for `inspect` and
/// `report`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EstimateReport {
    pub pooling: u64,
    /// The clipped bins' mode: [`ClipMode::Law`] for those without clear held-out evidence for
    /// their own histogram (a clipped bin that keeps its own is [`BinSource::Measured`], one in
    /// law mode [`BinSource::Filled`]); [`ClipMode::Own`] for all when no law stands behind them.
    pub clip_mode: ClipMode,
    pub choice: Choice,
    /// Cross-validation scores of every pooling candidate (empty unless cross-validated).
    pub candidates: Vec<CandidateScore>,
    /// Held-out cross-entropy of the clipped bins under each clip mode (own, law), when both
    /// could be scored.
    pub clip_scores: Option<[f64; 2]>,
    /// The fitted noise law per bin: (mean, variance) of `n` in DN and DN².
    pub law: Vec<[f32; 2]>,
    /// Bins flagged as clipped.
    pub clipped: Vec<u32>,
    /// Held-out samples scored.
    pub heldout_samples: u64,
}

impl EstimateReport {
    /// The score of the plain per-bin histogram (`m = 0`) and of the chosen pooling, when
    /// cross-validated.
    pub fn gain_over_plain(&self) -> Option<(f64, f64)> {
        let plain = self.candidates.iter().find(|c| c.pooling == 0)?;
        let chosen = self.candidates.iter().find(|c| c.pooling == self.pooling)?;
        Some((plain.cross_entropy, chosen.cross_entropy))
    }
}
