//! The `noisecal` command's library: DNG and recording I/O, capture grouping, reports. The
//! science is in `noisecal-core`.

pub mod calibrate;
pub mod cmd;
pub mod dng;
pub mod eval;
pub mod input;
pub mod models;
pub mod output;
pub mod report;
pub mod simulate;
