//! Model packs of format version 3, read and migrated: version 4 only added the fixed pattern
//! (dark frames) to each ISO's structured components, which a version 3 pack has none of — it
//! synthesizes exactly as before.

use serde::{Deserialize, Serialize};

use crate::model::layout::SensorLayout;
use crate::model::pack::{IsoModel, ModelPack};
use crate::model::structure::{FrameOffsets, IsoStructure, OffsetDistribution};

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ModelPackV3 {
    layout: SensorLayout,
    make: String,
    model: String,
    bin_width: u16,
    reference_iso: u32,
    pooling: Option<u64>,
    isos: Vec<IsoModel>,
    warnings: Vec<String>,
    structure: Vec<IsoStructureV3>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct IsoStructureV3 {
    iso: u32,
    rows: [Option<OffsetDistribution>; 2],
    columns: [Option<OffsetDistribution>; 2],
    frames: Option<FrameOffsets>,
    frames_used: u64,
}

impl ModelPackV3 {
    /// The same pack in the current structs, without a fixed pattern.
    pub fn migrate(self) -> ModelPack {
        ModelPack {
            layout: self.layout,
            make: self.make,
            model: self.model,
            bin_width: self.bin_width,
            reference_iso: self.reference_iso,
            pooling: self.pooling,
            isos: self.isos,
            warnings: self.warnings,
            structure: self
                .structure
                .into_iter()
                .map(|s| IsoStructure {
                    iso: s.iso,
                    rows: s.rows,
                    columns: s.columns,
                    frames: s.frames,
                    frames_used: s.frames_used,
                    fpn: None,
                })
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::calibrate::{CalibrationSession, FrameMeta, FrameView, SessionConfig};
    use crate::format::codec;
    use crate::format::pack_file::PACK_MAGIC;
    use crate::model::layout::CfaPattern;

    /// A small real pack: a flat grey field, 4 reference and 4 target frames.
    fn pack() -> ModelPack {
        let (w, h) = (48usize, 32usize);
        let layout =
            SensorLayout { width: w as u32, height: h as u32, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 };
        let mut s = CalibrationSession::new(layout, SessionConfig::new(100)).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        s.begin_step(1_000_000).unwrap();
        for (iso, exp) in [(100, 1_000_000u64); 4].into_iter().chain([(200, 500_000u64); 4]) {
            let sd = if iso == 100 { 3.0 } else { 5.0 };
            let px: Vec<u16> = (0..w * h)
                .map(|i| {
                    let level = 200.0 + 100.0 * ((i % w) / 12) as f64;
                    let u: f64 = rng.random::<f64>() + rng.random::<f64>() + rng.random::<f64>() - 1.5;
                    (level + 2.0 * sd * u).round() as u16
                })
                .collect();
            s.push_frame(&FrameView::from_u16(&px, w, h, w).unwrap(), &FrameMeta::new(iso, exp)).unwrap();
        }
        s.finish().unwrap()
    }

    /// A version 3 pack (structured components without a fixed pattern) loads as it was.
    #[test]
    fn version_3_packs_load_unchanged() {
        let p = pack();
        assert!(!p.structure.is_empty(), "the pack has structured components to migrate");
        assert!(p.structure.iter().all(|s| s.fpn.is_none()));
        let v3 = ModelPackV3 {
            layout: p.layout.clone(),
            make: p.make.clone(),
            model: p.model.clone(),
            bin_width: p.bin_width,
            reference_iso: p.reference_iso,
            pooling: p.pooling,
            isos: p.isos.clone(),
            warnings: p.warnings.clone(),
            structure: p
                .structure
                .iter()
                .map(|s| IsoStructureV3 {
                    iso: s.iso,
                    rows: s.rows.clone(),
                    columns: s.columns.clone(),
                    frames: s.frames.clone(),
                    frames_used: s.frames_used,
                })
                .collect(),
        };
        let bytes = codec::encode("model pack", PACK_MAGIC, 3, &v3).unwrap();
        assert_eq!(ModelPack::from_bytes(&bytes).unwrap(), p);
        // And the current version round-trips.
        assert_eq!(ModelPack::from_bytes(&p.to_bytes().unwrap()).unwrap(), p);
    }
}
