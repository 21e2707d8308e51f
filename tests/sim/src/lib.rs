//! A simulated phone raw sensor looking at a colour chart, for noisecal's end-to-end tests,
//! statistical tests, benchmarks and `noisecal demo`.
//!
//! - [`SensorModel`]: every parameter of the signal chain (shot noise, heavy-tailed read noise
//!   before and after the gain, row noise, bias, PRNU, non-proportional and digital gain, dual
//!   conversion gain, clipping, quantisation, flicker, misalignment), with presets.
//! - [`Chart`]: the scene, a ColorChecker-like grid of patches with blurred edges.
//! - [`Simulator`]: deterministic frames, the noiseless mean, the analytic variance and samples
//!   of the same noise process at a given level.
//! - [`SessionPlan`]: the capture order of a calibration session.
//! - [`to_padded_le_bytes`]: a frame as a Camera2 `RAW_SENSOR` plane.

mod bytes;
mod chart;
mod error;
mod model;
mod noise;
mod plan;
mod sim;

pub use bytes::{to_padded_le_bytes, try_to_padded_le_bytes};
pub use chart::{Chart, PatchRect};
pub use error::SimError;
pub use model::{DualGain, Flicker, IsoSettings, SensorModel};
pub use plan::{PlannedFrame, SessionPlan};
pub use sim::{FrameEffects, MID_RANGE_FRACTION, Simulator};

#[cfg(test)]
mod tests;
