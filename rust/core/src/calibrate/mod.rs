//! Calibration: frames → session → pack (method.md, "Calibration" and "Estimation").
//!
//! - [`frame`] / [`meta`]: a raw frame as the camera handed it over, and what it reported.
//! - [`session`]: the session's state machine — EV steps, reference bursts, target frames,
//!   progress, checkpoints, and the pack at the end.
//! - [`reference`](mod@reference): one reference burst, summed into the clean image and its flat mask.
//! - [`accumulate`]: target frames folded into the per-bin histograms; [`line_sums`]: a target
//!   row's noise and its line sums.
//! - [`line_base`]: the clean image's half of the target frames' line sums; [`flat_levels`]: the
//!   clean levels its flat pixels have.
//! - [`step`]: which EV step a frame belongs to (the step tolerance).
//! - [`flat`], [`drift`], [`deselect`]: the flat test, frame brightness, and the clean image's
//!   own error; [`flat_neighbours`]: the flat test's neighbour comparison on the burst's sums;
//!   [`flat_spread`]: its check of a pixel's own spread over the burst, on the integers;
//!   [`half_code`]: at sub-DN noise, the pixels whose rounded mean is most likely the wrong code, at the codes they would bias.
//! - [`structure`]: row, column and frame offsets from the target bursts; [`flicker`]: a frame's
//!   brightness (the lamp) parted from its black-level offset there.
//! - [`motion`]: each target frame registered on its clean image; the flat pixels its motion
//!   changes are left out of that frame.
//! - [`estimate`]: histograms → per-bin PMFs; [`codes`]: the codes a sensor writes.
//! - [`dark`]: dark (lens-covered) frames → the fixed pattern per ISO.

pub(crate) mod accumulate;
mod assemble;
pub(crate) mod codes;
pub mod dark;
pub(crate) mod deselect;
pub(crate) mod drift;
pub mod estimate;
pub mod event;
pub mod flat;
mod flat_levels;
mod flat_neighbours;
mod flat_spread;
mod flicker;
pub mod frame;
pub(crate) mod half_code;
mod line_base;
mod line_sums;
pub mod meta;
pub mod motion;
pub mod reference;
pub(crate) mod saturated;
pub mod session;
pub mod step;
pub(crate) mod structure;
#[cfg(test)]
mod tests_frame_offsets;
#[cfg(test)]
mod tests_structure;
mod window_counts;

pub use event::SessionRecord;
pub use flat::{NOT_FLAT, Roi};
pub use frame::FrameView;
pub use meta::FrameMeta;
pub use reference::{CleanImage, ReferenceBurst};
pub use session::{CalibrationSession, FrameKind, FrameReport, IsoProgress, Progress, SessionConfig};
pub use step::{STEP_TOLERANCE, StepKey};
