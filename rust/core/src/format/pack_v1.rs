//! Model packs of format version 1, read and migrated to the current structs. Version 1 knew a
//! bin only as measured or filled; the migration keeps every PMF as it was, records measured
//! bins' moments, and flags bins as clipped by their noise reaching 0 or white — by the rule
//! version 1 packs were read with ([`CLIP_FRACTION_V1`], [`clip_fraction_v1`]), frozen here so
//! that a change to today's clip rule cannot change how a version 1 pack reads.

use serde::{Deserialize, Serialize};

use crate::model::bin_levels::BinLevels;
use crate::model::layout::{Binning, POSITIONS, SensorLayout};
use crate::model::pack::{BinModel, BinSource, IsoModel, ModelOrigin, ModelPack, NoiseProfile, PositionModel};

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ModelPackV1 {
    layout: SensorLayout,
    make: String,
    model: String,
    bin_width: u16,
    reference_iso: u32,
    min_samples: u64,
    isos: Vec<IsoModelV1>,
    warnings: Vec<String>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct IsoModelV1 {
    iso: u32,
    origin: ModelOrigin,
    frames: u64,
    drift_frames: u64,
    gain_ratio: [f64; POSITIONS],
    noise_profile: Option<NoiseProfile>,
    positions: Vec<PositionModelV1>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct PositionModelV1 {
    bins: Vec<BinModelV1>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct BinModelV1 {
    first: i32,
    counts: Vec<u64>,
    samples: u64,
    filled: bool,
}

impl ModelPackV1 {
    /// The same pack in the current structs.
    pub fn migrate(self) -> ModelPack {
        let binning = Binning::new(&self.layout, self.bin_width);
        let levels: Vec<BinLevels> = (0..POSITIONS).map(|p| BinLevels::new(&binning, p)).collect();
        let isos = self
            .isos
            .into_iter()
            .map(|m| IsoModel {
                iso: m.iso,
                origin: m.origin,
                frames: m.frames,
                drift_frames: m.drift_frames,
                gain_ratio: m.gain_ratio,
                noise_profile: m.noise_profile,
                range: [[0, self.layout.white]; POSITIONS],
                lattice: [None; POSITIONS],
                positions: m
                    .positions
                    .into_iter()
                    .enumerate()
                    .map(|(pos, pm)| {
                        PositionModel::new(
                            pm.bins
                                .into_iter()
                                .enumerate()
                                .map(|(b, bm)| migrate_bin(bm, levels.get(pos & 3), b))
                                .collect(),
                        )
                    })
                    .collect(),
            })
            .collect();
        let mut warnings = self.warnings;
        warnings.push(format!(
            "pack format version 1 (bins filled below {} samples, without clipping rules): recalibrate for held-out-validated pooling",
            self.min_samples
        ));
        ModelPack {
            layout: self.layout,
            make: self.make,
            model: self.model,
            bin_width: self.bin_width,
            reference_iso: self.reference_iso,
            pooling: Some(self.min_samples),
            isos,
            warnings,
            structure: Vec::new(),
        }
    }
}

/// A version 1 bin is clipped when more than this fraction of its samples may have reached 0 or
/// white (the estimator's threshold when version 2 replaced version 1).
pub const CLIP_FRACTION_V1: f64 = 1e-4;

/// Fraction of a histogram's samples (counts over `first ..`) that may have reached 0 or white
/// for some integer level `lo ..= hi` of the bin: `n ≥ white − hi` or `n ≤ −lo` (version 1 packs
/// knew no output range: the sensor's codes were `0 ..= white`).
pub fn clip_fraction_v1(first: i32, counts: &[u64], lo: i32, hi: i32, white: i32) -> f64 {
    let total: u64 = counts.iter().sum();
    if total == 0 {
        return 0.0;
    }
    let c: u64 = counts
        .iter()
        .enumerate()
        .filter(|(i, _)| {
            let n = first + *i as i32;
            n >= white - hi || n <= -lo
        })
        .map(|(_, &k)| k)
        .sum();
    c as f64 / total as f64
}

fn migrate_bin(bm: BinModelV1, levels: Option<&BinLevels>, b: usize) -> BinModel {
    let moments = crate::model::histogram::moments(bm.first, bm.counts.iter().map(|&c| c as f64));
    let clipped = levels.is_some_and(|l| {
        b < l.len() && clip_fraction_v1(bm.first, &bm.counts, l.lo[b], l.hi[b], l.white) > CLIP_FRACTION_V1
    });
    BinModel {
        first: bm.first,
        counts: bm.counts,
        samples: bm.samples,
        source: if bm.filled { BinSource::Filled } else { BinSource::Measured },
        measured: (!bm.filled && bm.samples > 0).then_some([moments.0, moments.1]),
        clipped,
        grid_step: 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::codec;
    use crate::format::pack_file::{PACK_MAGIC, PACK_MAGIC_TEXT, PACK_VERSION};
    use crate::model::layout::CfaPattern;

    #[test]
    fn version_1_packs_load_and_keep_their_pmfs() {
        let layout = SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 };
        let binning = Binning::new(&layout, 4);
        let bins = |pos: usize| PositionModelV1 {
            bins: (0..binning.bins(pos))
                .map(|b| BinModelV1 {
                    first: -2,
                    counts: if b + 1 == binning.bins(pos) { vec![0, 0, 5, 0, 995] } else { vec![1, 4, 6, 4, 1] },
                    samples: if b % 2 == 0 { 16 } else { 0 },
                    filled: b % 2 == 1,
                })
                .collect(),
        };
        let v1 = ModelPackV1 {
            layout: layout.clone(),
            make: "m".into(),
            model: "p".into(),
            bin_width: 4,
            reference_iso: 100,
            min_samples: 1000,
            isos: vec![IsoModelV1 {
                iso: 400,
                origin: ModelOrigin::Calibrated,
                frames: 3,
                drift_frames: 0,
                gain_ratio: [1.0; POSITIONS],
                noise_profile: None,
                positions: (0..POSITIONS).map(bins).collect(),
            }],
            warnings: vec![],
        };
        let bytes = codec::encode("model pack", PACK_MAGIC, 1, &v1).expect("encode");
        let p = ModelPack::from_bytes(&bytes).expect("a version 1 pack loads");
        assert_eq!(p.pooling, Some(1000));
        let m = &p.isos[0];
        let b0 = &m.positions[0].bins[0];
        assert_eq!((b0.first, b0.counts.as_slice()), (-2, &[1u64, 4, 6, 4, 1][..]));
        assert_eq!(b0.source, BinSource::Measured);
        let [mean, var] = b0.measured.expect("measured moments");
        assert!(mean.abs() < 1e-12 && (var - 1.0).abs() < 1e-12, "{mean} {var}");
        assert!(m.positions[0].bins[1].filled());
        let last = m.positions[0].bins.last().expect("bins");
        assert!(last.clipped, "the top bin's noise reaches white");
        assert!(!b0.clipped);
        assert!(p.warnings.iter().any(|w| w.contains("version 1")));
        // Refused: a version newer than this build.
        let newer = codec::encode("model pack", PACK_MAGIC, PACK_VERSION + 1, &v1).expect("encode");
        let e = ModelPack::from_bytes(&newer).expect_err("newer is refused").to_string();
        assert!(e.contains("newer"), "{e}");
        let _ = PACK_MAGIC_TEXT;
    }
}
