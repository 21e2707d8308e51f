//! noisecal core: calibrated, non-parametric sensor noise models (the science; no file or OS I/O).
//!
//! Data flows one way: frames → [`session`] → [`pack`] → [`sampler`] → images ([`synth`]).

pub mod error;
pub mod frame;
pub mod lattice;
pub mod layout;
pub mod meta;

pub use error::{Error, Result};
pub use frame::FrameView;
pub use layout::{Binning, CfaPattern, POSITIONS, SensorLayout};
pub use meta::FrameMeta;
pub mod check;
pub mod codec;
pub mod deselect;
pub mod drift;
pub mod estimate;
pub mod fit;
pub mod flat;
pub mod histogram;
pub mod pack;
pub mod pack_v1;
pub mod pmf;
pub mod recording;
pub mod sampler;
pub mod session;
pub mod synth;

pub use pack::ModelPack;
pub use session::{CalibrationSession, SessionConfig};
// Issue 3: ISO interpolation, parametric baselines, fidelity metrics.
pub mod baselines;
pub mod interp;
pub mod metrics;
// Issue 4: noise on noise.
pub mod bridge;
pub mod denoise;
pub mod renoise;
