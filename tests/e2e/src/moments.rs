//! Noise judged by its variance and tails, not only by a divergence: per held-out ISO and EV
//! step, the variance and the 0.1 % / 99.9 % quantiles of real noise (capture − clean) and of
//! synthetic noise (synthesized on the same clean image − clean) over the same flat pixels.
//! A JSD barely sees rare wide tails; a denoiser trained on them does.

use std::collections::BTreeMap;

use noisecal_core::ModelPack;
use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::synthesize;
use noisecal_sim::{SessionPlan, Simulator};

use crate::for_each_heldout_frame;

/// Moments of real and synthetic noise at one (ISO, EV step).
#[derive(Debug, Clone)]
pub struct Moments {
    pub iso: u32,
    pub step: i32,
    /// Samples on each side.
    pub samples: usize,
    /// Variance of real and synthetic noise (DN²).
    pub var: (f64, f64),
    /// `median − q(0.001)` of real and synthetic noise (DN).
    pub low_tail: (f64, f64),
    /// `q(0.999) − median` of real and synthetic noise (DN).
    pub high_tail: (f64, f64),
    /// Row-mean and column-mean variance of real and synthetic noise ([`line_mean_var`]; NaN
    /// with fewer than two frames).
    pub row_var: (f64, f64),
    pub col_var: (f64, f64),
}

impl Moments {
    /// Synthetic / real variance.
    pub fn var_ratio(&self) -> f64 {
        self.var.1 / self.var.0.max(1e-9)
    }

    /// Synthetic / real tail widths (low, high).
    pub fn tail_ratios(&self) -> (f64, f64) {
        (self.low_tail.1 / self.low_tail.0.max(0.5), self.high_tail.1 / self.high_tail.0.max(0.5))
    }

    /// Synthetic / real row-mean and column-mean variance.
    pub fn line_ratios(&self) -> (f64, f64) {
        (self.row_var.1 / self.row_var.0, self.col_var.1 / self.col_var.0)
    }

    /// Relative standard error of the variance ratio (both variances' sampling errors, from
    /// the fourth moment of a Gaussian; heavy tails make it larger, which `slack` covers).
    pub fn var_ratio_se(&self) -> f64 {
        (4.0 / self.samples.max(1) as f64).sqrt()
    }
}

/// Per frame, the real and the synthetic noise images.
type NoiseImages = (Vec<Vec<i32>>, Vec<Vec<i32>>);

/// Real and synthetic noise of a held-out set: per EV step of `plan` (frame indices shifted by
/// `index_offset`) the reference burst gives the clean image and flat mask, every target frame
/// gives real noise on the flat pixels, and the pack synthesizes the same number of frames on the
/// same clean image with `components` (the fixed pattern is in the clean image already: pass
/// [`Components::ON_OWN_CAPTURES`]).
pub fn heldout_moments(
    sim: &Simulator,
    plan: &SessionPlan,
    index_offset: u64,
    pack: &ModelPack,
    components: Components,
) -> Vec<Moments> {
    let layout = sim.layout();
    let (w, h) = (layout.width as usize, layout.height as usize);
    let samplers: BTreeMap<u32, IsoSampler> =
        pack.isos.iter().map(|m| (m.iso, IsoSampler::with_components(pack, m, components))).collect();
    let mut noise: BTreeMap<(u32, i32), (Vec<i32>, Vec<i32>)> = BTreeMap::new();
    // Per (ISO, step), per frame: the noise images (real, synthetic) as i32, for line means.
    let mut lines: BTreeMap<(u32, i32), NoiseImages> = BTreeMap::new();
    let mut masks: BTreeMap<i32, Vec<bool>> = BTreeMap::new();
    for_each_heldout_frame(sim, plan, index_offset, pack.bin_width, |(f, c16, mask, px)| {
        let Some(sampler) = samplers.get(&f.iso) else { return };
        let mask = mask.as_slice().expect("standard layout");
        let syn = synthesize(sampler, c16.view(), 0x5EED_0000 ^ (f.index + index_offset).wrapping_mul(0x9E37_79B9));
        let e = noise.entry((f.iso, f.step)).or_default();
        let (mut nr, mut ns) = (vec![0i32; w * h], vec![0i32; w * h]);
        for (i, ((&c, &r), &s)) in c16.iter().zip(px.iter()).zip(syn.iter()).enumerate() {
            if mask[i] {
                e.0.push(r as i32 - c as i32);
                e.1.push(s as i32 - c as i32);
                nr[i] = r as i32 - c as i32;
                ns[i] = s as i32 - c as i32;
            }
        }
        masks.insert(f.step, mask.to_vec());
        let l = lines.entry((f.iso, f.step)).or_default();
        l.0.push(nr);
        l.1.push(ns);
    });
    noise
        .into_iter()
        .map(|((iso, step), (mut real, mut syn))| {
            let (vr, lr, hr) = spread(&mut real);
            let (vs, ls, hs) = spread(&mut syn);
            let (fr, fs) = &lines[&(iso, step)];
            let mask = &masks[&step];
            let row_var = (line_mean_var(fr, mask, w, h, true), line_mean_var(fs, mask, w, h, true));
            let col_var = (line_mean_var(fr, mask, w, h, false), line_mean_var(fs, mask, w, h, false));
            Moments {
                iso,
                step,
                samples: real.len(),
                var: (vr, vs),
                low_tail: (lr, ls),
                high_tail: (hr, hs),
                row_var,
                col_var,
            }
        })
        .collect()
}

/// Variance, `median − q(0.001)` and `q(0.999) − median` of integer samples (sorted in place).
fn spread(v: &mut [i32]) -> (f64, f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    let n = v.len() as f64;
    let mean = v.iter().map(|&x| x as f64).sum::<f64>() / n;
    let var = v.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    v.sort_unstable();
    let q = |p: f64| {
        // Linear interpolation between order statistics.
        let t = p * (v.len() - 1) as f64;
        let (i, f) = (t.floor() as usize, t.fract());
        let a = v[i] as f64;
        let b = v[(i + 1).min(v.len() - 1)] as f64;
        a + f * (b - a)
    };
    let med = q(0.5);
    (var, med - q(0.001), q(0.999) - med)
}

/// Row-mean (`rows`) or column-mean variance of noise images over flat pixels: per frame and
/// line (≥ 16 flat pixels of one parity), the line's mean noise, centred twice — minus that
/// line's mean over the frames (the clean image's own line error cancels) and minus the frame's
/// mean over its lines (a frame offset is not line noise) — with the degrees of freedom the
/// centring took. Per line parity, averaged. NaN with fewer than two frames.
pub fn line_mean_var(frames: &[Vec<i32>], flat: &[bool], w: usize, h: usize, rows: bool) -> f64 {
    let k = frames.len();
    if k < 2 {
        return f64::NAN;
    }
    let (lines, along) = if rows { (h, w) } else { (w, h) };
    let at = |line: usize, i: usize| if rows { line * w + i } else { i * w + line };
    let mut total = 0.0;
    let mut parities = 0;
    for parity in 0..2 {
        let mut m: Vec<Vec<f64>> = Vec::new();
        for line in (parity..lines).step_by(2) {
            let idx: Vec<usize> = (0..along).map(|i| at(line, i)).filter(|&j| flat[j]).collect();
            if idx.len() < 16 {
                continue;
            }
            m.push(frames.iter().map(|f| idx.iter().map(|&j| f[j] as f64).sum::<f64>() / idx.len() as f64).collect());
        }
        let r = m.len();
        if r < 2 {
            continue;
        }
        let line_mean: Vec<f64> = m.iter().map(|v| v.iter().sum::<f64>() / k as f64).collect();
        let frame_mean: Vec<f64> = (0..k).map(|f| m.iter().map(|v| v[f]).sum::<f64>() / r as f64).collect();
        let grand = line_mean.iter().sum::<f64>() / r as f64;
        let mut acc = 0.0;
        for (i, v) in m.iter().enumerate() {
            for (f, x) in v.iter().enumerate() {
                acc += (x - line_mean[i] - frame_mean[f] + grand).powi(2);
            }
        }
        total += acc / ((r - 1) * (k - 1)) as f64;
        parities += 1;
    }
    if parities == 0 { f64::NAN } else { total / parities as f64 }
}
