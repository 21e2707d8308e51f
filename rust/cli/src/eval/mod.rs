//! Measured fidelity on held-out captures (method.md "Measuring fidelity", paper §5.1–5.3).
//!
//! On the flat pixels of each EV step of a held-out set, real noise is `capture − round(clean)`
//! (the clean image is the mean of the step's reference burst) and synthetic noise is
//! `synthesized − round(clean)` for each model, synthesized on the same clean image with the same
//! number of frames, once per seed `0..seeds` (each frame gets its own stream). Scores are the
//! marginal and conditional JSD (natural log) and KL with add-one smoothing per ISO and CFA
//! position ([`noisecal_core::metrics`]), averaged over seeds.
//!
//! The **finite-sample floor** splits the real frames of an ISO into two halves (alternate frames
//! of each burst; a burst of one frame alternates across steps) and scores one half against the
//! other, scaled to the sample sizes of the model comparison ([`noisecal_core::metrics::Floor`],
//! ≈ ½): a model at that scaled floor is as close to the real noise as the held-out data can
//! show.
//!
//! Leave-one-out (paper §5.2, Fig. 4): each calibrated ISO strictly inside the calibrated range is
//! removed from the pack and interpolated from the rest ([`noisecal_core::derive::interp`]), and the HG
//! baseline is interpolated parametrically the usual way ([`noisecal_core::derive::baselines::interpolate`]);
//! both are scored on that ISO's held-out frames next to the calibrated model.
//!
//! Noise on noise (paper §5.3): the held-out frames at ISO A are re-noised to B with each method
//! ([`noisecal_core::renoise`], built-in clean estimate) and scored against the real frames at B of
//! the same EV steps; synthesizing B directly on the clean image is scored alongside.
//!
//! Levels are taken above black: a held-out set whose black level is not the pack's is carried
//! onto it ([`noisecal_core::SensorLayout::align_to`]), as `synth` and `renoise` do.
//!
//! The files, one job each: [`heldout`] streams the captures into bursts with their clean image,
//! [`candidates`] builds the models scored at an ISO, `scoring` and `renoise` measure them
//! (`noise` holds the noise samples both take), [`scores`] is the result (text, JSON and the
//! report's contract) and [`text`] prints it. This file runs them.

pub mod candidates;
pub mod heldout;
mod noise;
pub mod options;
mod renoise;
pub mod scores;
mod scoring;
pub mod text;

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::bail;
use noisecal_core::metrics::NoiseSamples;
use noisecal_core::model::NoiseProfile;
use noisecal_core::{Binning, ModelPack, POSITIONS};

pub use candidates::CandidateKind;
use heldout::{Burst, HeldOutVisitor};
use noise::StepClean;
pub use options::EvalOptions;
use renoise::RenoiseScoring;
pub use scores::{
    EvalReport, FloorScore, GroupRow, IsoEval, LooRow, ModelScore, RenoiseEval, SpatialEval, SpatialModelScore,
};
use scoring::IsoScoring;
pub use text::render_text;

use noisecal_input::source::SourceInfo;

/// Scores a pack against a held-out set (see the module docs).
pub fn evaluate(
    pack: &ModelPack,
    pack_path: &Path,
    heldout: &Path,
    opts: &EvalOptions,
    quiet: bool,
) -> anyhow::Result<EvalReport> {
    if opts.seeds == 0 {
        bail!("--seeds 0: use at least one synthetic set per model");
    }
    if opts.group_bins == 0 {
        bail!("--group-bins 0: a level group needs at least one bin");
    }
    let mut ev = Evaluator::new(pack, opts.clone())?;
    let notes = heldout::stream_heldout(heldout, pack.bin_width, quiet, &mut ev)?;
    ev.finish(pack_path, heldout, notes)
}

/// Receives the held-out set and keeps the measurements of every ISO (and of noise on noise).
struct Evaluator<'a> {
    pack: &'a ModelPack,
    binning: Binning,
    opts: EvalOptions,
    isos: BTreeMap<u32, IsoScoring>,
    renoise: Option<RenoiseScoring>,
    profiles: BTreeMap<u32, NoiseProfile>,
    /// Real frames seen so far: the synthetic frame of real frame `k` is seeded by `k`.
    frame_counter: u64,
    notes: Vec<String>,
    loo_from: BTreeMap<u32, Vec<u32>>,
}

impl<'a> Evaluator<'a> {
    fn new(pack: &'a ModelPack, opts: EvalOptions) -> anyhow::Result<Self> {
        let binning = pack.binning();
        let fresh = || NoiseSamples::new(&binning, opts.group_bins);
        let renoise = match opts.renoise {
            None => None,
            Some((a, b)) => Some(RenoiseScoring::new(pack, a, b, opts.seeds, &fresh)?),
        };
        Ok(Self {
            pack,
            binning,
            opts,
            isos: BTreeMap::new(),
            renoise,
            profiles: BTreeMap::new(),
            frame_counter: 0,
            notes: Vec::new(),
            loo_from: BTreeMap::new(),
        })
    }

    fn finish(mut self, pack_path: &Path, heldout: &Path, mut notes: Vec<String>) -> anyhow::Result<EvalReport> {
        let cfa = self.pack.layout.cfa;
        let positions: Vec<String> = (0..POSITIONS).map(|p| cfa.position_name(p).to_string()).collect();
        for iso in self.pack.iso_list() {
            if !self.isos.contains_key(&iso) {
                notes.push(format!("ISO {iso} is in the pack but the held-out set has no frames at it: not scored"));
            }
        }
        if self.isos.is_empty() {
            bail!(
                "{}: no held-out target frame could be scored (see the notes above); a held-out set needs, per EV step, a reference burst at the lowest ISO and frames at the ISOs to score",
                heldout.display()
            );
        }
        let isos: Vec<IsoEval> = self.isos.values().map(IsoScoring::finish).collect();
        let leave_one_out = self.opts.leave_one_out.then(|| self.leave_one_out(&isos, &mut notes));
        let renoise = match self.renoise.take() {
            None => None,
            Some(r) => Some(r.finish(heldout)?),
        };
        notes.extend(self.notes);
        Ok(EvalReport {
            pack: pack_path.display().to_string(),
            heldout: heldout.display().to_string(),
            camera: format!("{} {}", self.pack.make, self.pack.model).trim().to_string(),
            seeds: self.opts.seeds,
            group_bins: self.opts.group_bins,
            positions,
            isos,
            leave_one_out,
            renoise,
            notes,
        })
    }

    /// The leave-one-out rows (paper Fig. 4), and notes on what could not be left out.
    fn leave_one_out(&self, isos: &[IsoEval], notes: &mut Vec<String>) -> Vec<LooRow> {
        use CandidateKind::{Hg, HgLoo, Noisecal, NoisecalLoo};
        let mut rows = Vec::new();
        for ie in isos {
            let (Some(c), Some(i), Some(hc), Some(hi)) =
                (ie.model(Noisecal.name()), ie.model(NoisecalLoo.name()), ie.model(Hg.name()), ie.model(HgLoo.name()))
            else {
                continue;
            };
            let pair = |m: &ModelScore| [m.conditional_overall, m.marginal_overall];
            rows.push(LooRow {
                iso: ie.iso,
                from: self.loo_from.get(&ie.iso).cloned().unwrap_or_default(),
                calibrated: pair(c),
                interpolated: pair(i),
                hg_calibrated: pair(hc),
                hg_interpolated: pair(hi),
                floor: ie.floor.as_ref().map(|f| [f.conditional_scaled(), f.marginal_scaled()]),
            });
        }
        let cal = self.pack.calibrated_isos();
        if cal.len() < 3 {
            notes.push(format!(
                "--leave-one-out needs at least three calibrated ISOs (an inner one to leave out); the pack has {}",
                cal.len()
            ));
        } else {
            for &k in &cal[1..cal.len() - 1] {
                if !rows.iter().any(|r| r.iso == k) {
                    notes.push(format!("leave-one-out: inner ISO {k} has no held-out frames; not scored"));
                }
            }
        }
        rows
    }
}

impl HeldOutVisitor for Evaluator<'_> {
    fn start(&mut self, info: &SourceInfo) -> anyhow::Result<()> {
        crate::models::check_layout_matches(self.pack, &info.layout, Path::new("the held-out set"))?;
        let align = info.layout.align_to(&self.pack.layout);
        if let Some(p) = (0..POSITIONS).find(|&p| align.offset[p].abs() > 0.5) {
            self.notes.push(format!(
                "the held-out black level at position {p} is {:.1} DN but the pack's is {:.1} DN: levels are taken above black (the held-out captures are shifted onto the pack's black level)",
                info.layout.black[p], self.pack.layout.black[p]
            ));
        }
        self.profiles.extend(info.noise_profiles.iter().map(|(k, v)| (*k, *v)));
        // Fail fast on ISOs the pack cannot model (DNG folders list them up front).
        let cal = self.pack.calibrated_isos();
        if let (Some(&lo), Some(&hi)) = (cal.first(), cal.last()) {
            for &iso in &info.target_isos {
                if (iso < lo || iso > hi) && self.pack.iso(iso).is_none() {
                    bail!(
                        "the held-out set has frames at ISO {iso}, outside the pack's calibrated range ISO {lo}–{hi}: eval only scores ISOs the pack models; remove those frames or calibrate ISO {iso}"
                    );
                }
            }
            if let Some((a, b)) = self.opts.renoise
                && !info.target_isos.is_empty()
            {
                for (iso, flag) in [(a, "--renoise-from"), (b, "--to")] {
                    if !info.target_isos.contains(&iso) {
                        bail!(
                            "{flag} {iso}: the held-out set has no frames at ISO {iso} (it has ISOs {:?}); noise on noise is scored on real frames at both ISOs",
                            info.target_isos
                        );
                    }
                }
            }
        }
        Ok(())
    }

    fn burst(&mut self, b: Burst<'_>) -> anyhow::Result<()> {
        let (binning, group_bins, seeds) = (&self.binning, self.opts.group_bins, self.opts.seeds);
        let fresh = || NoiseSamples::new(binning, group_bins);
        if !self.isos.contains_key(&b.iso) {
            let c = candidates::candidates(
                self.pack,
                b.iso,
                self.profiles.get(&b.iso).copied(),
                self.opts.leave_one_out,
                seeds,
                &fresh,
            )?;
            self.notes.extend(c.notes.iter().cloned());
            if let Some(from) = &c.loo_from {
                self.loo_from.insert(b.iso, from.clone());
            }
            self.isos.insert(b.iso, IsoScoring::new(b.iso, c, &fresh));
        }
        let clean = StepClean::new(b.clean, b.width, b.height, b.black, &self.pack.layout);
        let first_frame = self.frame_counter;
        self.frame_counter += b.frames.len() as u64;
        if let Some(iso) = self.isos.get_mut(&b.iso) {
            iso.add_burst(b.step, &clean, &b.frames, first_frame, seeds)?;
        }
        if let Some(r) = self.renoise.as_mut() {
            r.add_burst(b.iso, || clean, b.frames);
        }
        Ok(())
    }

    fn end_step(&mut self) -> anyhow::Result<()> {
        match self.renoise.as_mut() {
            Some(r) => r.end_step(self.opts.seeds, &mut self.frame_counter),
            None => Ok(()),
        }
    }

    fn noise_profile(&mut self, iso: u32, profile: NoiseProfile) {
        self.profiles.insert(iso, profile);
    }
}
