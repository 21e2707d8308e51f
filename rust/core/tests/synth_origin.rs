//! A crop keeps the noise of its true CFA positions: `synthesize_at` with the crop's origin gives
//! each pixel the PMF of `position(row + y, column + x)`.

use ndarray::Array2;
use noisecal_core::model::layout::position;
mod support;

use noisecal_core::model::pack::{IsoModel, ModelPack};
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::{synthesize, synthesize_at};

/// A pack whose noise is a single value per CFA position: `+10·(p + 1)` DN at position `p`, so
/// every output pixel names the position whose PMF drew it.
fn tagged_pack() -> (ModelPack, IsoModel) {
    support::one_iso_pack((64, 64), 4, (1, 1), "tagged", |p| (10 * (p as i32 + 1), vec![1]))
}

#[test]
fn crops_at_every_origin_parity_get_their_true_positions() {
    let (pack, model) = tagged_pack();
    let sampler = IsoSampler::new(&pack, &model);
    let clean = Array2::from_elem((37, 41), 500u16);
    for origin in [(0, 0), (0, 1), (1, 0), (1, 1), (6, 9), (255, 1000)] {
        let out = synthesize_at(&sampler, clean.view(), 5, origin);
        for ((y, x), &v) in out.indexed_iter() {
            let p = position(y + origin.0, x + origin.1);
            assert_eq!(v as i32 - 500, 10 * (p as i32 + 1), "origin {origin:?} pixel ({y}, {x})");
        }
    }
}

#[test]
fn origin_zero_is_synthesize_byte_for_byte() {
    let (pack, mut model) = tagged_pack();
    // A spread PMF so the draws matter.
    for pm in &mut model.positions {
        for b in &mut pm.bins {
            b.first -= 3;
            b.counts = vec![1, 4, 9, 4, 1, 2, 1];
        }
    }
    let sampler = IsoSampler::new(&pack, &model);
    let clean = Array2::from_shape_fn((33, 47), |(y, x)| (64 + (y * 47 + x) % 900) as u16);
    assert_eq!(synthesize(&sampler, clean.view(), 11), synthesize_at(&sampler, clean.view(), 11, (0, 0)));
    assert_eq!(synthesize(&sampler, clean.view(), 11), synthesize_at(&sampler, clean.view(), 11, (2, 4)));
    assert_ne!(synthesize(&sampler, clean.view(), 11), synthesize_at(&sampler, clean.view(), 11, (0, 1)));
}
