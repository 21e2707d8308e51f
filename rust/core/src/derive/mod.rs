//! Models derived from a pack: ISO interpolation ([`interp`], never across a conversion-gain
//! switch, [`gain_switch`]), the parametric baselines ([`baselines`]) and the variance law they
//! share ([`noise_law`]), the levels near black a bin is too wide for ([`fine_levels`]), and the structured components at ISOs the pack has none for
//! ([`structure`](mod@structure)).

pub mod baselines;
pub mod black_rounding;
pub mod fine_levels;
pub mod gain_switch;
pub mod interp;
pub mod noise_law;
pub mod structure;
