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

/// The variance (DN²) of the held-out frames at black as `noisy − level` (`level` the exposure's
/// clean image's mean per position: the pattern kept in the residual, as a clean image without
/// the pattern calls for), at the exposures 0 and 0.1 DN above black
/// (`tests/bench/emva1288_black.py`, table (b); 262 144 pixels each): what the default
/// components onto a flat image at black's code are compared with.
pub const REAL_LESS_LEVEL_AT_BLACK: [f64; 2] = [0.0944, 0.0907];

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
    (sampler(pack, Components::ALL), sampler(pack, Components::PIXEL))
}

/// The sampler of the pack's ISO with every component but the fixed pattern
/// ([`Components::ON_OWN_CAPTURES`]): what the real figures of these tests are compared with.
/// Their clean images (the flat field's mean: the dark burst's mean plus the mean signal times
/// the flat field's shape) carry the sensor's pattern, so `frame − round(clean)` holds none of
/// it, and a synthetic image that adds the pattern again reads above it by the pattern's variance.
pub fn own(pack: &ModelPack) -> IsoSampler {
    sampler(pack, Components::ON_OWN_CAPTURES)
}

fn sampler(pack: &ModelPack, which: Components) -> IsoSampler {
    let iso = pack.isos[0].iso;
    let model = pack.iso(iso).expect("its ISO");
    IsoSampler::with_structure(pack, model, pack.structure_of(iso), which)
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
