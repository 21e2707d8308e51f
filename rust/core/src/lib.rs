//! noisecal core: calibrated, non-parametric sensor noise models — the science, no file or OS I/O.
//!
//! Two flows run through the crate (method: `docs/method.md`):
//!
//! - **Calibration** — frames → session → pack. [`calibrate::CalibrationSession`] takes raw
//!   frames ([`FrameView`] with their [`FrameMeta`]) one at a time: per EV step a
//!   [`calibrate::ReferenceBurst`] becomes the clean image and its flat mask, and every target
//!   frame folds `noisy − clean` into per-(ISO, CFA position, level bin) histograms. At
//!   [`finish`](calibrate::CalibrationSession::finish) the estimator
//!   ([`calibrate::estimate`]) turns the histograms into PMFs and the result is a
//!   [`ModelPack`] ([`model`]), written and read by [`format`](mod@format).
//! - **Derivation** — pack → images. A pack's ISO models, or ones derived from it
//!   ([`derive`](mod@derive): ISO interpolation, parametric baselines), feed a sampler ([`synth`]) that adds
//!   noise to clean images; [`renoise`] adds the difference between two ISOs to noisy captures
//!   (bridge models); [`metrics`] says how close synthetic noise is to real.
//!
//! [`math`] holds the small numerics both flows share; [`resolve`] is which model a front-end
//! synthesizes with (names, the model of an ISO, components, black alignment), one answer for
//! the CLI, Python and the app.
//!
//! The module docs link to internal modules too (`cargo doc --document-private-items` renders
//! them): they are the map a reader of the method needs.
#![allow(rustdoc::private_intra_doc_links)]

pub mod calibrate;
pub mod derive;
pub mod error;
pub mod format;
pub mod math;
pub mod metrics;
pub mod model;
pub mod renoise;
pub mod resolve;
pub mod synth;

pub use calibrate::drift::DriftPolicy;
pub use calibrate::{CalibrationSession, FrameMeta, FrameView, SessionConfig};
pub use error::{Error, Result};
pub use model::layout::{Binning, BlackAlignment, CfaPattern, POSITIONS, SensorLayout, position};
pub use model::pack::ModelPack;
