//! Scoring noise on noise (paper §5.3): the held-out frames at ISO A of each EV step are
//! re-noised to ISO B with every method ([`noisecal_core::renoise`], built-in clean estimate)
//! and scored against the real frames at B of the same step; noisecal at B synthesized directly
//! on the step's clean image is scored alongside (`direct`).

use std::path::Path;

use anyhow::{Context, bail};
use ndarray::Array2;
use noisecal_core::derive::interp;
use noisecal_core::metrics::{Floor, NoiseSamples, score_seeds};
use noisecal_core::model::pack::IsoModel;
use noisecal_core::renoise::{Method, Renoiser};
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::synthesize;
use noisecal_core::{FrameMeta, ModelPack, POSITIONS};
use rayon::prelude::*;

use super::noise::{StepClean, synth_seed};
use super::scores::{ModelScore, RenoiseEval};

/// What has been measured of noise on noise from ISO `from` to ISO `to` so far.
pub(super) struct RenoiseScoring {
    from: u32,
    to: u32,
    renoisers: Vec<Renoiser>,
    /// Noisecal at `to`, synthesized directly on the clean image.
    direct: IsoSampler,
    /// Per method (then `direct` last), per seed.
    synth: Vec<Vec<NoiseSamples>>,
    real: NoiseSamples,
    halves: [NoiseSamples; 2],
    frames_from: u64,
    frames_to: u64,
    steps: usize,
    /// The current step: its clean image and its frames at both ISOs.
    step_clean: Option<StepClean>,
    step_from: Vec<(FrameMeta, Array2<u16>)>,
    step_to: Vec<(FrameMeta, Array2<u16>)>,
    warnings: Vec<String>,
}

impl RenoiseScoring {
    /// Prepares every method from ISO `a` to ISO `b`, with `seeds` synthetic sets each.
    pub(super) fn new(
        pack: &ModelPack,
        a: u32,
        b: u32,
        seeds: u32,
        fresh: &dyn Fn() -> NoiseSamples,
    ) -> anyhow::Result<Self> {
        if b <= a {
            bail!(
                "--renoise-from {a} --to {b}: noise on noise only adds noise, so the target ISO must be higher than the source ISO; pick --to above {a}"
            );
        }
        let model = |iso: u32, flag: &str| -> anyhow::Result<IsoModel> {
            let (m, _) = interp::model_for(pack, iso, false).map_err(|e| anyhow::anyhow!("{flag} {iso}: {e}"))?;
            Ok(m.into_owned())
        };
        let (src, dst) = (model(a, "--renoise-from")?, model(b, "--to")?);
        let mut renoisers = Vec::new();
        let mut warnings = Vec::new();
        for method in Method::ALL {
            let r = Renoiser::new(pack, &src, &dst, method)
                .with_context(|| format!("preparing the {method} re-noise from ISO {a} to ISO {b}"))?;
            for w in r.warnings() {
                if !warnings.contains(w) {
                    warnings.push(w.clone());
                }
            }
            renoisers.push(r);
        }
        Ok(Self {
            from: a,
            to: b,
            direct: IsoSampler::with_components(
                pack,
                &dst,
                noisecal_core::model::structure::Components::ON_OWN_CAPTURES,
            ),
            synth: (0..=renoisers.len()).map(|_| (0..seeds).map(|_| fresh()).collect()).collect(),
            renoisers,
            real: fresh(),
            halves: [fresh(), fresh()],
            frames_from: 0,
            frames_to: 0,
            steps: 0,
            step_clean: None,
            step_from: Vec::new(),
            step_to: Vec::new(),
            warnings,
        })
    }

    /// Keeps a burst of the current step at either ISO (with the step's clean image).
    pub(super) fn add_burst(
        &mut self,
        iso: u32,
        clean: impl FnOnce() -> StepClean,
        frames: Vec<(FrameMeta, Array2<u16>)>,
    ) {
        if iso != self.from && iso != self.to {
            return;
        }
        if self.step_clean.is_none() {
            self.step_clean = Some(clean());
        }
        if iso == self.from {
            self.step_from.extend(frames);
        } else {
            self.step_to.extend(frames);
        }
    }

    /// Scores the current step (when it had frames at both ISOs); its frames are numbered from
    /// `*frame_counter`, which moves past them.
    pub(super) fn end_step(&mut self, seeds: u32, frame_counter: &mut u64) -> anyhow::Result<()> {
        let from_frames = std::mem::take(&mut self.step_from);
        let to_frames = std::mem::take(&mut self.step_to);
        let Some(clean) = self.step_clean.take() else { return Ok(()) };
        if from_frames.is_empty() || to_frames.is_empty() {
            return Ok(());
        }
        self.steps += 1;
        self.frames_from += from_frames.len() as u64;
        self.frames_to += to_frames.len() as u64;
        for (k, (meta, img)) in to_frames.iter().enumerate() {
            clean.add_real(&mut self.real, meta, img);
            clean.add_real(&mut self.halves[k % 2], meta, img);
        }
        let base = *frame_counter;
        *frame_counter += (from_frames.len() + to_frames.len()) as u64;
        // One clean estimate per input frame (the built-in denoiser), shared by all methods. The
        // input is first brought to the pack's black level.
        let inputs: Vec<Array2<u16>> =
            from_frames.iter().map(|(meta, img)| clean.align_frame(meta, img).into_owned()).collect();
        let estimates: Vec<Array2<f32>> = inputs.par_iter().map(|img| self.renoisers[0].estimate(img.view())).collect();
        let clean_view = clean.view()?;
        let renoisers = &self.renoisers;
        let direct = &self.direct;
        let results: Vec<anyhow::Result<()>> = self
            .synth
            .par_iter_mut()
            .enumerate()
            .map(|(mi, per_seed)| {
                for s in 0..seeds {
                    if mi < renoisers.len() {
                        for (j, (img, est)) in inputs.iter().zip(&estimates).enumerate() {
                            let out = renoisers[mi]
                                .apply(img.view(), Some(est.view()), synth_seed(s, base + j as u64))
                                .with_context(|| format!("re-noising with {}", renoisers[mi].method()))?;
                            clean.add_synthetic(&mut per_seed[s as usize], &out.image);
                        }
                    } else {
                        for j in 0..to_frames.len() {
                            let out =
                                synthesize(direct, clean_view, synth_seed(s, base + (from_frames.len() + j) as u64));
                            clean.add_synthetic(&mut per_seed[s as usize], &out);
                        }
                    }
                }
                Ok(())
            })
            .collect();
        results.into_iter().collect()
    }

    /// The scores; an error when no step had frames at both ISOs.
    pub(super) fn finish(self, heldout: &Path) -> anyhow::Result<RenoiseEval> {
        if self.steps == 0 {
            bail!(
                "--renoise-from {} --to {}: no EV step of {} has frames at both ISO {} and ISO {}; capture both ISOs in the same steps",
                self.from,
                self.to,
                heldout.display(),
                self.from,
                self.to
            );
        }
        let n_real: u64 = (0..POSITIONS).map(|p| self.real.total(p)).sum();
        let mut methods = Vec::new();
        for (mi, per_seed) in self.synth.iter().enumerate() {
            let (name, label, origin) = match self.renoisers.get(mi) {
                Some(rn) => (
                    rn.method().name().to_string(),
                    label(rn.method()).to_string(),
                    format!("held-out ISO {} frames re-noised to ISO {}", self.from, self.to),
                ),
                None => (
                    "direct".to_string(),
                    format!("noisecal at ISO {} on the clean image (reference)", self.to),
                    "synthesized on the reference-burst clean image".into(),
                ),
            };
            methods.push(ModelScore::new(name, label, origin, score_seeds(&self.real, per_seed)));
        }
        Ok(RenoiseEval {
            from: self.from,
            to: self.to,
            frames_from: self.frames_from,
            frames_to: self.frames_to,
            steps: self.steps,
            methods,
            floor: Floor::measure(&self.halves[0], &self.halves[1], n_real).map(Into::into),
            warnings: self.warnings,
        })
    }
}

fn label(m: Method) -> &'static str {
    match m {
        Method::Bridge => "bridge: input + extra noise q (p_A ∗ q ≈ p_B)",
        Method::Quantile => "quantile: input noise mapped through CDF_A then CDF_B⁻¹",
        Method::Denoised => "denoised: clean estimate + ISO B noise",
        Method::Naive => "naive: input + ISO B noise",
    }
}
