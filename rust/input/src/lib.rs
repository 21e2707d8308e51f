//! noisecal's input side, one library under every front-end (the `noisecal` command, the Python
//! package, the fuzzer): captures come in through one stream, packs and DNGs go out as files.
//! Nothing here prints or draws progress; a front-end reports what it is given back.
//!
//! - [`dng`] reads, edits and writes raw DNGs (one TIFF structure walker, [`dng::tiff`]'s field
//!   types; which tags a derived DNG keeps is `dng/edit.rs`).
//! - [`grouping`] groups a DNG folder into EV steps by its metadata.
//! - [`source`] turns a DNG folder or a recording into one stream of records (steps, frames with
//!   their metadata, in capture order).
//! - [`clean`] sums a reference burst into a clean image with the core's `ReferenceBurst`.
//! - [`dim_steps`] tells a folder's dim lit EV steps from a covered lens.
//! - [`calibrate`] feeds the stream to a calibration session: the one calibrate driver.
//! - [`files`]: reading a pack file, writing any output atomically, and refusing to write over
//!   an input.

pub mod calibrate;
pub mod clean;
pub mod dim_steps;
pub mod dng;
pub mod files;
pub mod grouping;
pub mod source;
