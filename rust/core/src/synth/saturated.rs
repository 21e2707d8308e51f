//! Clean levels at the ceiling (method.md, *Synthesis*, "A clean level at the ceiling"): a clean
//! level is a reference burst's mean, and a mean at the ceiling (white, or the level where the
//! reference ISO's output piles up below it) means every reference frame read the ceiling: a
//! saturated pixel, whose true brightness is anywhere above it. Its output is the ceiling. Drawn
//! from the noise law there, as the bins near white are, the demo's phone put 42 % of such pixels
//! below white at ISO 100 (mean 1 016 DN) where the sensor writes 1 023 for nearly all of them.

use crate::model::pack::{BinModel, BinSource, ModelPack};

/// The lowest clean level at position `pos` that stands for a saturated pixel: the top of the
/// reference ISO's output range where the pack holds that ISO (its pile-up below white, or
/// white), else white.
pub fn saturated_from(pack: &ModelPack, pos: usize) -> u16 {
    let white = pack.layout.white;
    pack.isos.iter().find(|m| m.iso == pack.reference_iso).map_or(white, |m| m.range[pos][1].min(white))
}

/// The noise of a saturated clean level: one value, `white` DN, which takes any level at or
/// below white, plus any structured offset (each is far smaller than the range), to the
/// sampler's ceiling, where synthesis clamps it.
pub fn at_the_ceiling(white: u16) -> BinModel {
    BinModel {
        first: i32::from(white),
        counts: vec![1],
        samples: 0,
        source: BinSource::Filled,
        measured: None,
        clipped: true,
        grid_step: 0,
    }
}
