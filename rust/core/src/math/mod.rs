//! Small numerics shared by both flows: non-negative polynomial fits ([`fit`]), non-negative
//! deconvolution on the simplex ([`deconv`]), special functions ([`special`]) and robust
//! statistics ([`stats`]).

pub(crate) mod deconv;
pub(crate) mod fit;
pub mod special;
pub mod stats;
