//! Where a bin's PMF comes from: its own samples, pooled with its neighbours', or filled.

use serde::{Deserialize, Serialize};

/// Where a bin's PMF comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum BinSource {
    /// The bin's own samples only.
    Measured,
    /// Its own samples pooled with neighbouring bins' (moved onto it by the noise law).
    Pooled,
    /// Without samples of its own (or clipped, in law mode): neighbours moved by the law,
    /// or an interpolated or parametric PMF.
    Filled,
}
