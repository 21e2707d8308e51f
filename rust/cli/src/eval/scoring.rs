//! Scoring the models at one ISO: each burst's real noise (and its halves, for the floor), and
//! every candidate's synthetic noise on the same clean image with as many frames.

use std::collections::BTreeSet;

use ndarray::Array2;
use noisecal_core::metrics::spatial::{
    SpatialFloor, SpatialSamples, compare_spatial, mean_comparison, row_offset_bin_width,
};
use noisecal_core::metrics::{Floor, NoiseSamples, score_seeds};
use noisecal_core::synth::synthesize;
use noisecal_core::{FrameMeta, POSITIONS};
use rayon::prelude::*;

use super::candidates::{Candidate, Candidates};
use super::noise::{StepClean, synth_seed};
use super::scores::{IsoEval, ModelScore, SpatialEval, SpatialModelScore};

/// What has been measured at one ISO so far.
pub(super) struct IsoScoring {
    iso: u32,
    origin: String,
    frames: u64,
    steps: BTreeSet<usize>,
    real: NoiseSamples,
    /// Alternate frames of each burst (a burst of one frame alternates across steps).
    halves: [NoiseSamples; 2],
    toggle: usize,
    candidates: Vec<Candidate>,
    /// Spatial statistics of the real frames and of their halves (the same split as `halves`).
    spatial: SpatialSamples,
    spatial_halves: [SpatialSamples; 2],
}

impl IsoScoring {
    pub(super) fn new(iso: u32, c: Candidates, fresh: &dyn Fn() -> NoiseSamples) -> Self {
        Self {
            iso,
            origin: c.origin,
            frames: 0,
            steps: BTreeSet::new(),
            real: fresh(),
            halves: [fresh(), fresh()],
            toggle: 0,
            candidates: c.list,
            spatial: SpatialSamples::new(),
            spatial_halves: [SpatialSamples::new(), SpatialSamples::new()],
        }
    }

    /// Scores one burst of step `step` on its clean image; its frames are numbered from
    /// `first_frame` (each synthetic frame gets its own seed stream).
    pub(super) fn add_burst(
        &mut self,
        step: usize,
        clean: &StepClean,
        frames: &[(FrameMeta, Array2<u16>)],
        first_frame: u64,
        seeds: u32,
    ) -> anyhow::Result<()> {
        self.steps.insert(step);
        for (k, (meta, img)) in frames.iter().enumerate() {
            clean.add_real(&mut self.real, meta, img);
            let half = if frames.len() >= 2 {
                k % 2
            } else {
                self.toggle ^= 1;
                self.toggle
            };
            clean.add_real(&mut self.halves[half], meta, img);
            clean.add_real_spatial(&mut self.spatial, meta, img);
            clean.add_real_spatial(&mut self.spatial_halves[half], meta, img);
            self.frames += 1;
        }
        self.spatial.end_burst();
        self.spatial_halves.iter_mut().for_each(SpatialSamples::end_burst);
        let view = clean.view()?;
        let n_frames = frames.len() as u64;
        self.candidates.par_iter_mut().for_each(|c| {
            for s in 0..seeds {
                for j in 0..n_frames {
                    let out = synthesize(&c.sampler, view, synth_seed(s, first_frame + j));
                    clean.add_synthetic(&mut c.synth[s as usize], &out);
                    clean.add_synthetic_spatial(&mut c.spatial[s as usize], &out);
                }
                c.spatial[s as usize].end_burst();
            }
        });
        Ok(())
    }

    /// The scores at this ISO.
    pub(super) fn finish(&self) -> IsoEval {
        let n_real: u64 = (0..POSITIONS).map(|p| self.real.total(p)).sum();
        IsoEval {
            iso: self.iso,
            origin: self.origin.clone(),
            frames: self.frames,
            steps: self.steps.len(),
            samples: std::array::from_fn(|p| self.real.total(p)),
            floor: Floor::measure(&self.halves[0], &self.halves[1], n_real).map(Into::into),
            models: self
                .candidates
                .iter()
                .map(|c| {
                    let s = score_seeds(&self.real, &c.synth);
                    ModelScore::new(c.kind.name().to_string(), c.label.clone(), c.origin.clone(), s)
                })
                .collect(),
            spatial: self.spatial_eval(),
        }
    }

    /// The spatial measures at this ISO (`None` before any frame).
    fn spatial_eval(&self) -> Option<SpatialEval> {
        let real = &self.spatial;
        if real.frames() == 0 {
            return None;
        }
        let h = row_offset_bin_width(real);
        let models = self
            .candidates
            .iter()
            .map(|c| {
                let per_seed: Vec<_> = c.spatial.iter().map(|s| compare_spatial(real, s, h)).collect();
                let mut pooled = SpatialSamples::new();
                c.spatial.iter().for_each(|s| pooled.merge(s));
                SpatialModelScore {
                    name: c.kind.name().to_string(),
                    scores: mean_comparison(&per_seed),
                    nps: std::array::from_fn(|p| pooled.nps(p)),
                }
            })
            .collect();
        let [a, b] = &self.spatial_halves;
        Some(SpatialEval {
            frames: real.frames(),
            row_var: real.row_var().map(|v| v.0),
            row_var_se: real.row_var().map(|v| v.1),
            col_var: real.col_var().map(|v| v.0),
            col_var_se: real.col_var().map(|v| v.1),
            row_offsets: real.row_offsets().len() as u64,
            row_offset_bin_width: h,
            frame_offset_var: std::array::from_fn(|p| real.frame_offset_var(p)),
            nps: std::array::from_fn(|p| real.nps(p)),
            floor: SpatialFloor::measure(a, b, real, h),
            models,
        })
    }
}
