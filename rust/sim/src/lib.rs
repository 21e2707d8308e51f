//! A simulated phone raw sensor looking at a colour chart, for noisecal's end-to-end tests,
//! statistical tests, benchmarks and `noisecal demo`.
//!
//! - [`SensorModel`]: every parameter of the signal chain (shot noise, heavy-tailed read noise
//!   before and after the gain (Gaussian, Student-t or Tukey-lambda), row noise (any
//!   [`OffsetShape`]), per-frame black-level errors, column noise and pattern, bias, PRNU, DSNU,
//!   gain non-proportional to ISO, digital gain, dual conversion gain, clipping, quantisation,
//!   flicker, misalignment), with presets ([`SensorModel::with_structured_noise`] adds
//!   phone-like row noise, frame offsets and DSNU to any).
//! - [`Chart`]: the scene, a ColorChecker-like grid of patches with blurred edges.
//! - [`Simulator`]: deterministic frames, the noiseless mean, the analytic variance and samples
//!   of the same noise process at a given level.
//! - [`SessionPlan`]: the capture order of a calibration session (whole-stop or dense
//!   fractional EV sweeps).
//! - [`StructuredTruth`]: the true row, column, frame-offset and DSNU laws at an ISO, with
//!   samplers ([`Simulator::structured_truth`]; the offsets of one frame:
//!   [`Simulator::row_offsets`], [`Simulator::frame_offsets`], [`Simulator::column_offsets`]).
//! - [`SensorModel::dark_14bit`], [`random_dark_sensor`]: sensors whose noise at black is small
//!   against the noise at the darkest level a chart session measures.
//! - [`random_sensor`], [`random_session`]: a seeded family of random sensors and sessions
//!   drawn from wide parameter ranges, for testing on sensors nobody tuned the estimators on.
//! - [`to_padded_le_bytes`]: a frame as a Camera2 `RAW_SENSOR` plane.

mod bytes;
mod chart;
mod dark_end;
mod error;
mod family;
mod model;
mod noise;
mod plan;
mod sim;
mod truth;

pub use bytes::{to_padded_le_bytes, try_to_padded_le_bytes};
pub use chart::{Chart, PatchRect, Texture};
pub use dark_end::random_dark_sensor;
pub use error::SimError;
pub use family::{
    FAMILY_MAX_ISO_FACTOR, HeldOutSpec, MovingScene, RandomSensor, SessionScale, SessionSpec, random_moving_scene,
    random_sensor, random_sensor_structured, random_session, random_session_scaled,
};
pub use model::{DualGain, Flicker, IsoSettings, MOTION_BLOCK, Motion, OffsetShape, ReadNoiseShape, SensorModel};
pub use plan::{PlannedFrame, SessionPlan};
pub use sim::{FrameEffects, MID_RANGE_FRACTION, Simulator};
pub use truth::StructuredTruth;

#[cfg(test)]
mod tests;
