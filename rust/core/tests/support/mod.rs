//! Hand-built packs for the core's integration tests: one calibrated ISO of a 10-bit RGGB sensor
//! whose every bin at a CFA position draws the same PMF, so a test states only the PMF it needs.

use noisecal_core::model::pack::{BinModel, BinSource, IsoModel, ModelOrigin, ModelPack, PositionModel};
use noisecal_core::{CfaPattern, POSITIONS, SensorLayout};

/// A pack of one ISO (100) on a `width × height` 10-bit RGGB sensor (black 64, white 1023) with
/// bins `bin_width` DN wide; every bin at position `p` holds `pmf(p)`: its first offset and its
/// weights, from `samples` samples over `frames` frames.
pub fn one_iso_pack(
    (width, height): (u32, u32),
    bin_width: u16,
    (frames, samples): (u64, u64),
    name: &str,
    pmf: impl Fn(usize) -> (i32, Vec<u64>),
) -> (ModelPack, IsoModel) {
    let layout = SensorLayout { width, height, cfa: CfaPattern::Rggb, black: [64.0; POSITIONS], white: 1023 };
    let bins = ((1023.0 - 64.0) / bin_width as f32).floor() as usize + 1;
    let positions = (0..POSITIONS)
        .map(|p| {
            let (first, counts) = pmf(p);
            let bin = BinModel {
                first,
                counts,
                samples,
                source: BinSource::Measured,
                measured: None,
                clipped: false,
                grid_step: 0,
            };
            PositionModel::new(vec![bin; bins])
        })
        .collect();
    let model = IsoModel {
        iso: 100,
        origin: ModelOrigin::Calibrated,
        frames,
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
        model: name.into(),
        bin_width,
        reference_iso: 100,
        pooling: None,
        isos: vec![model.clone()],
        warnings: vec![],
        structure: vec![],
    };
    (pack, model)
}
