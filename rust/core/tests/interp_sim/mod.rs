//! Model packs built directly from the simulated sensor's noise process (no capture session):
//! per ISO, CFA position and bin, noise samples drawn at integer clean levels spread over the
//! bin, exactly what a calibration would histogram for that bin on a flat chart.
#![allow(dead_code)]

use noisecal_core::derive::baselines::bin_levels;
use noisecal_core::model::histogram::NoiseHistogram;
use noisecal_core::model::pack::{BinModel, IsoModel, ModelOrigin, ModelPack, PositionModel};
use noisecal_core::{Binning, POSITIONS};
use noisecal_sim::{Chart, SensorModel, Simulator};
use rand::SeedableRng;
use rayon::prelude::*;

pub fn simulator(model: SensorModel, seed: u64) -> Simulator {
    let chart = Chart::flat(64, 64, [0.5, 0.5, 0.5]).expect("flat chart");
    Simulator::new(model, chart, seed).expect("valid sensor")
}

/// Histograms of `samples` noise values per bin, for every position and bin of one ISO.
pub fn sample_iso(sim: &Simulator, binning: &Binning, iso: u32, samples: usize, seed: u64) -> Vec<Vec<NoiseHistogram>> {
    sample_iso_with(sim, binning, iso, &|_, _| samples, seed)
}

/// As [`sample_iso`] with a sample count per (position, bin) (0 leaves the bin empty).
pub fn sample_iso_with(
    sim: &Simulator,
    binning: &Binning,
    iso: u32,
    samples: &(dyn Fn(usize, usize) -> usize + Sync),
    seed: u64,
) -> Vec<Vec<NoiseHistogram>> {
    (0..POSITIONS)
        .into_par_iter()
        .map(|pos| {
            (0..binning.bins(pos))
                .map(|bin| {
                    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
                        seed ^ (iso as u64) << 32 ^ (pos as u64) << 24 ^ bin as u64,
                    );
                    let levels = bin_levels(binning, pos, bin);
                    let per = samples(pos, bin).div_ceil(levels.len());
                    let mut h = NoiseHistogram::default();
                    for &l in &levels {
                        for n in sim.sample_noise_at_level(iso, l as f32, pos, per, &mut rng).expect("level") {
                            h.add(n);
                        }
                    }
                    h.trimmed()
                })
                .collect()
        })
        .collect()
}

pub fn iso_model(iso: u32, white: u16, hists: &[Vec<NoiseHistogram>]) -> IsoModel {
    IsoModel {
        iso,
        origin: ModelOrigin::Calibrated,
        frames: 10,
        drift_frames: 0,
        gain_ratio: [1.0; POSITIONS],
        noise_profile: None,
        range: [[0, white]; POSITIONS],
        lattice: [None; POSITIONS],
        positions: hists
            .iter()
            .map(|bins| PositionModel::new(bins.iter().map(BinModel::from_histogram).collect()))
            .collect(),
    }
}

/// A pack of calibrated ISOs sampled from the simulator.
pub fn sim_pack(sim: &Simulator, isos: &[u32], bin_width: u16, samples: usize, seed: u64) -> ModelPack {
    sim_pack_with(sim, isos, bin_width, &|_, _| samples, seed)
}

/// As [`sim_pack`] with a sample count per (position, bin).
pub fn sim_pack_with(
    sim: &Simulator,
    isos: &[u32],
    bin_width: u16,
    samples: &(dyn Fn(usize, usize) -> usize + Sync),
    seed: u64,
) -> ModelPack {
    let layout = sim.layout();
    let binning = Binning::new(&layout, bin_width);
    let mut pack = ModelPack {
        layout,
        make: "sim".into(),
        model: "sim".into(),
        bin_width,
        reference_iso: sim.model().base_iso,
        pooling: None,
        isos: Vec::new(),
        warnings: Vec::new(),
        structure: Vec::new(),
    };
    for &iso in isos {
        pack.insert(iso_model(iso, pack.layout.white, &sample_iso_with(sim, &binning, iso, samples, seed)));
    }
    pack
}
