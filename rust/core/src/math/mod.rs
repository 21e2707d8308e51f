//! Small numerics shared by both flows: non-negative polynomial fits ([`fit`]), non-negative
//! deconvolution on the simplex ([`deconv`]), special functions ([`special`]), robust statistics
//! ([`stats`]) and rounding for per-pixel loops ([`round`]).

pub(crate) mod deconv;
pub(crate) mod fit;
pub mod round;
pub mod special;
pub mod stats;
