//! The `noisecal` command's library: a thin orchestrator over `noisecal-core`, which holds the
//! science, and `noisecal-input`, which reads captures and writes files (DNG I/O, grouping, the
//! record source, the clean image, the calibrate driver, pack and output files). Both are shared
//! with the Python package; what is here is the command line's own:
//!
//! - **Work:** [`eval`] scores a pack on held-out captures (one file per job); [`models`] parses
//!   `--model` and says on stderr which model a command uses and how an input's black level is
//!   carried; [`simulate`] writes simulated sessions, and
//!   [`truth_profile`] the NoiseProfile their DNGs may carry.
//! - **Out:** [`report`] renders the HTML report; [`support`] holds what every command shares
//!   (progress, stdout, error text); [`seeds`] the seed of each file of a folder run (the rule the
//!   Python package shares).
//! - [`cmd`]: one module per subcommand, its arguments and its `run`.

pub mod cmd;
pub mod eval;
pub mod models;
pub mod report;
pub mod seeds;
pub mod simulate;
pub mod support;
pub mod truth_profile;
