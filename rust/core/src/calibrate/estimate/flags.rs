//! Which bins are flagged as clipped (method.md, "Estimation" 1): by the fraction of their
//! samples that may have reached either end, or, for sparse bins, by the noise law fitted on the
//! bins not flagged so far.

use crate::calibrate::estimate::clip::{CLIP_FRACTION, CLIP_SIGMAS, clip_fraction};
use crate::calibrate::estimate::law::Law;
use crate::calibrate::estimate::stat::Stat;
use crate::model::bin_levels::BinLevels;
use crate::model::histogram::NoiseHistogram;

/// Bins flagged as clipped, from all samples: more than [`CLIP_FRACTION`] of their samples may
/// have reached 0 or white from a level that surely occurs in the bin
/// ([`BinLevels::lowest_sure`]: bin 0's levels below black hold only the clean estimate's low
/// tail, and on a sensor with sub-DN noise at black a −1 DN sample at black would otherwise
/// flag it), or — for bins with too few samples to show a fraction that small —
/// their levels lie within [`CLIP_SIGMAS`] standard deviations of 0 or white by the noise law
/// fitted on the bins not flagged so far.
pub(super) fn clip_flags(hists: &[NoiseHistogram], levels: &BinLevels) -> Vec<bool> {
    let mut clipped: Vec<bool> = hists
        .iter()
        .enumerate()
        .map(|(b, h)| clip_fraction(h, levels.lowest_sure(b), levels.hi[b], levels.floor, levels.white) > CLIP_FRACTION)
        .collect();
    let stats: Vec<Stat> = hists.iter().map(Stat::of).collect();
    let law = Law::fit(&stats, &clipped, levels);
    for (b, c) in clipped.iter_mut().enumerate() {
        // A bin with enough samples shows its clipping itself.
        if stats[b].n as f64 * CLIP_FRACTION >= 1.0 {
            continue;
        }
        let sd = law.var[b].sqrt();
        let to_white = (levels.white - levels.hi[b]) as f64 - law.mean[b];
        let to_zero = (levels.lowest_sure(b) - levels.floor) as f64 + law.mean[b];
        if to_white < CLIP_SIGMAS * sd || to_zero < CLIP_SIGMAS * sd {
            *c = true;
        }
    }
    clipped
}
