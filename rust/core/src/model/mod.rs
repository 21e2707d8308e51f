//! What a pack is made of: the sensor's layout and binning, noise histograms and PMFs, the
//! codes a sensor writes, the pack itself and its self-check.

pub mod bin_width;
pub mod check;
pub mod codes;
pub mod histogram;
pub mod layout;
pub mod pack;
pub mod pmf;
pub mod structure;

pub use pack::{BinModel, BinSource, IsoModel, ModelOrigin, ModelPack, NoiseProfile, PositionModel};
