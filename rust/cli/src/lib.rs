//! The `noisecal` command's library: a thin orchestrator over `noisecal-core`, which holds the
//! science. Captures come in through one stream and results go out as files and text:
//!
//! - **In:** [`dng`] reads and writes raw DNGs; [`grouping`] groups a DNG folder into EV steps by
//!   its metadata; [`source`] turns a DNG folder or a recording into one stream of records
//!   (steps, frames with their metadata, in capture order); [`clean`] sums a reference burst
//!   into a clean image with the core's `ReferenceBurst`.
//! - **Work:** [`calibrate`] feeds the stream to a calibration session; [`eval`] scores a pack
//!   on held-out captures (one file per job); [`models`] picks the model a command uses and
//!   aligns inputs to the pack's black level; [`simulate`] writes simulated sessions.
//! - **Out:** [`report`] renders the HTML report; [`output`] writes files atomically;
//!   [`support`] holds what every command shares (loading a pack, progress, stdout); [`seeds`]
//!   the seed of each file of a folder run (the rule the Python package shares).
//! - [`cmd`]: one module per subcommand, its arguments and its `run`.

pub mod calibrate;
pub mod clean;
pub mod cmd;
pub mod dng;
pub mod eval;
pub mod grouping;
pub mod models;
pub mod output;
pub mod report;
pub mod seeds;
pub mod simulate;
pub mod source;
pub mod support;
