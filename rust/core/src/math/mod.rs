//! Small numerics shared by both flows: non-negative polynomial fits ([`fit`]), the variance of
//! a normal clamped at a floor ([`censored`]), non-negative
//! deconvolution on the simplex ([`deconv`]), special functions ([`special`]), robust statistics
//! ([`stats`]) and rounding for per-pixel loops ([`round`]).

pub mod censored;
pub(crate) mod deconv;
pub(crate) mod fit;
pub mod round;
pub mod special;
pub mod stats;
