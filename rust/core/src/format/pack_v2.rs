//! Model packs of format version 2, read and migrated: version 3 only added the structured
//! components ([`crate::model::structure`]), which a version 2 pack has none of — it
//! synthesizes exactly as before.

use serde::{Deserialize, Serialize};

use crate::model::layout::SensorLayout;
use crate::model::pack::{IsoModel, ModelPack};

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ModelPackV2 {
    layout: SensorLayout,
    make: String,
    model: String,
    bin_width: u16,
    reference_iso: u32,
    pooling: Option<u64>,
    isos: Vec<IsoModel>,
    warnings: Vec<String>,
}

impl ModelPackV2 {
    /// The same pack in the current structs, without structured components.
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
            structure: Vec::new(),
        }
    }
}
