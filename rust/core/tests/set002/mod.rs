//! EMVA 1288 set 002 for the core's integration tests: the pack calibrated from it
//! (`tests/data/emva002/ladder.pack`, README beside it), its fixed pattern's variance, and what
//! the sampler draws on flat images at one code.

use ndarray::Array2;
use noisecal_core::ModelPack;
use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::synthesize;

/// The pack calibrated from set 002 (README beside it).
const PACK: &[u8] = include_bytes!("../../../../tests/data/emva002/ladder.pack");

/// The set 002 pack and its fixed pattern's variance (mean over positions).
pub fn set002() -> (ModelPack, f64) {
    let pack = ModelPack::from_bytes(PACK).expect("the set 002 pack loads");
    let st = pack.structure_of(pack.isos[0].iso);
    let fpn = st.and_then(|s| s.fpn.as_ref()).expect("a fixed pattern from the dark burst");
    let pattern = (0..4).map(|p| fpn.variance(p)).sum::<f64>() / 4.0;
    (pack, pattern)
}

/// The samplers of the pack's ISO with the default components and with pixel noise alone.
pub fn default_and_pixel(pack: &ModelPack) -> (IsoSampler, IsoSampler) {
    let iso = pack.isos[0].iso;
    let model = pack.iso(iso).expect("its ISO");
    let st = pack.structure_of(iso);
    let at = |which| IsoSampler::with_structure(pack, model, st, which);
    (at(Components::ALL), at(Components::PIXEL))
}

/// `noisy − code` over `seeds` flat 200 × 512 images at `code`.
pub fn drawn_offsets(sampler: &IsoSampler, code: u16, seeds: u64) -> Vec<f64> {
    let mut v = Vec::new();
    for seed in 0..seeds {
        let clean = Array2::<u16>::from_elem((200, 512), code);
        v.extend(synthesize(sampler, clean.view(), seed).iter().map(|&x| f64::from(x) - f64::from(code)));
    }
    v
}

/// Mean and variance of `v`.
pub fn mean_var(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    (mean, v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n)
}
