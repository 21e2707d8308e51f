//! noisecal core: calibrated, non-parametric sensor noise models (the science; no file or OS I/O).
//!
//! Data flows one way: frames → [`session`] → [`pack`] → [`sampler`] → images ([`synth`]).

pub mod error;
pub mod frame;
pub mod layout;
pub mod meta;

pub use error::{Error, Result};
pub use frame::FrameView;
pub use layout::{Binning, CfaPattern, POSITIONS, SensorLayout};
pub use meta::FrameMeta;
