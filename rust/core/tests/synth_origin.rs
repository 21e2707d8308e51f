//! A crop keeps the noise of its true CFA positions: `synthesize_at` with the crop's origin gives
//! each pixel the PMF of `position(row + y, column + x)`.

use ndarray::Array2;
use noisecal_core::model::layout::position;
use noisecal_core::model::pack::{BinModel, BinSource, IsoModel, ModelOrigin, ModelPack, PositionModel};
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::{synthesize, synthesize_at};
use noisecal_core::{CfaPattern, POSITIONS, SensorLayout};

/// A pack whose noise is a single value per CFA position: `+10·(p + 1)` DN at position `p`, so
/// every output pixel names the position whose PMF drew it.
fn tagged_pack() -> (ModelPack, IsoModel) {
    let layout = SensorLayout { width: 64, height: 64, cfa: CfaPattern::Rggb, black: [64.0; POSITIONS], white: 1023 };
    let bin_width = 4u16;
    let bins = ((1023.0 - 64.0) / bin_width as f32).floor() as usize + 1;
    let positions = (0..POSITIONS)
        .map(|p| {
            PositionModel::new(
                (0..bins)
                    .map(|_| BinModel {
                        first: 10 * (p as i32 + 1),
                        counts: vec![1],
                        samples: 1,
                        source: BinSource::Measured,
                        measured: None,
                        clipped: false,
                    })
                    .collect(),
            )
        })
        .collect();
    let model = IsoModel {
        iso: 100,
        origin: ModelOrigin::Calibrated,
        frames: 1,
        drift_frames: 0,
        gain_ratio: [1.0; POSITIONS],
        noise_profile: None,
        range: [[0, 1023]; POSITIONS],
        lattice: [None; POSITIONS],
        positions,
    };
    let pack = ModelPack {
        layout,
        make: "test".into(),
        model: "tagged".into(),
        bin_width,
        reference_iso: 100,
        pooling: None,
        isos: vec![model.clone()],
        warnings: vec![],
        structure: vec![],
    };
    (pack, model)
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
