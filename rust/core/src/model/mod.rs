//! What a pack is made of: the sensor's layout and binning, noise histograms and PMFs, the
//! codes a sensor writes, what the estimator decided, the pack itself, how precisely a pack file
//! keeps it, and its self-check.

pub mod bin_levels;
pub mod bin_source;
pub mod bin_width;
pub mod check;
pub mod coarse_grid;
pub mod codes;
pub mod estimate_report;
pub mod histogram;
pub mod lattice_moments;
pub mod layout;
pub mod pack;
pub mod pmf;
pub mod precision;
pub mod rebin;
pub mod structure;

pub use pack::{BinModel, BinSource, IsoModel, ModelOrigin, ModelPack, NoiseProfile, PositionModel};
