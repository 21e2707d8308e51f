//! The dark end within a bin: where the noise law's variance changes across one bin by more than
//! a bin's PMF can stand for (near black on a sensor with a small read noise and wide bins), the
//! levels of that bin draw from the bin's PMF rescaled to the variance the law gives at their
//! own level, in groups of levels whose variance differs by at most [`GROUP_STEP`]
//! (method.md, *Synthesis*, "Within a bin near black").
//!
//! The variance at a level is the law `b + a·x` fitted on the bins' variances read at their
//! centres ([`crate::derive::noise_law::dark_law`]), `b` the variance at black measured by the
//! ISO's dark step (without one, nothing is split), never below [`MIN_VARIANCE`]. A bin's shape and mean
//! are kept; only its spread moves.

use crate::derive::noise_law::{DarkLaw, dark_law};
use crate::model::layout::Binning;
use crate::model::pack::{BinModel, IsoModel, ModelPack};
use crate::model::structure::IsoStructure;

/// A bin is split when the law's variance changes across it by more than this fraction of its
/// own variance (±2.5 % at its two ends). ±5 % was not enough: with the few per cent the PMFs
/// carry of the clean image's own error (method.md, *Selection by the clean image*), the ends of
/// the first whole bins read 1.10–1.13 on two random sensors of `tests/e2e/tests/dark_end.rs`.
pub const SPLIT_ABOVE: f64 = 0.05;

/// Levels share one rescaled PMF while their variances lie within one step of this ratio (4 %).
pub const GROUP_STEP: f64 = 1.04;

/// The least variance a level is given (DN²): the two roundings a sample carries, the sensor's
/// and the clean image's (1/12 each).
pub const MIN_VARIANCE: f64 = 1.0 / 6.0;

/// Bins read for the first law, which decides which bins to split.
const FIRST_LAW_BINS: usize = 6;

/// The tables of one CFA position: which PMF each clean level draws from, and the PMFs added
/// for the split bins' levels (indexed after the bins: `lut[level] − bins.len()`).
#[derive(Debug, Clone, PartialEq)]
pub struct FineLevels {
    pub lut: Vec<u16>,
    pub extra: Vec<BinModel>,
}

/// The tables of position `pos` of `model` (an ISO of `pack`) whose bins are too wide near
/// black ([`fine_levels`]), `bins` the PMFs the sampler draws from. Only for a model the
/// estimator made, at an ISO with a dark step (the variance at black measured,
/// [`variance_at_black`]): a plain histogram, the parametric models and an ISO without dark
/// frames keep one PMF per bin.
pub fn position_fine_levels(pack: &ModelPack, model: &IsoModel, pos: usize, bins: &[BinModel]) -> Option<FineLevels> {
    let own = &model.positions[pos];
    if !own.is_estimated() {
        return None;
    }
    // Without a dark step the variance at black is the fitted intercept, which a chart whose
    // darkest patch is well above black cannot pin: splitting on it made the random family's
    // pack lose to the plain histogram (median pack / plain 0.917 → 0.959, worst 1.00 → 1.76).
    let at_black = variance_at_black(pack.structure_of(model.iso), pos)?;
    fine_levels(&pack.binning(), pos, bins, &own.bins, Some(at_black))
}

/// The variance of the pack's pixel PMFs at black at one position when its ISO has a dark
/// step (`None` otherwise): the dark frames' temporal variance, what the PMFs hold besides
/// (the frame offsets, the change of the fixed pattern from the reference ISO) and the clean
/// image's rounding (1/12), as the PMFs above black carry it.
pub fn variance_at_black(structure: Option<&IsoStructure>, pos: usize) -> Option<f64> {
    let st = structure?;
    let fpn = st.fpn.as_ref()?;
    let frames = st.frames.as_ref().map_or(0.0, |f| f.variance(pos));
    let v = fpn.temporal_var[pos] + frames + fpn.in_pixel_noise[pos].variance() + 1.0 / 12.0;
    (v.is_finite() && fpn.temporal_var[pos] > 0.0).then_some(v)
}

/// The levels of position `pos` whose bin is too wide for the noise there, each mapped to its
/// bin's PMF at the law's variance for the level; `None` when no bin needs it (or the law
/// cannot be fitted). Clipped bins are left as they are (their PMF holds a clamp's pile that a
/// rescale would move). `bins` are the PMFs the sampler draws from (deconvolved when it adds
/// structured components), `pack_bins` the pack's own; `at_black` the pack's variance at black
/// measured by dark frames ([`variance_at_black`]), which the law then starts from (only its
/// slope fitted), instead of the intercept fitted on the bins.
///
/// The bin holding the darkest calibrated level is read at no level: its samples sit where the
/// session's darkest patches are, anywhere in it, not at its centre (on the named sensor of
/// `tests/e2e/tests/dark_end.rs` its variance is that of 40 DN, at 32 DN of a 64 DN bin), so
/// the law is read from the bins above it (its PMF's shape is kept). The split levels follow
/// one line, fitted on every bin read up to one past the last split bin: read at its centre, a
/// single bin's variance is off by where its samples sit (13 % on a 64 DN bin of that sensor).
pub fn fine_levels(
    binning: &Binning,
    pos: usize,
    bins: &[BinModel],
    pack_bins: &[BinModel],
    at_black: Option<f64>,
) -> Option<FineLevels> {
    let w = binning.bin_width as f64;
    let black = binning.black[pos] as f64;
    let vars: Vec<Option<f64>> =
        bins.iter().map(|b| Some(b.moments().1).filter(|v| !b.clipped && v.is_finite() && *v > 0.0)).collect();
    let mut read: Vec<Option<f64>> = vars.clone();
    if let Some(lowest) = pack_bins.iter().position(|b| b.samples > 0)
        && read.iter().skip(lowest + 1).flatten().count() >= 2
    {
        read[lowest] = None;
    }
    // What the tables hold besides the pixel noise the dark frames measured (the structured
    // components a deconvolved table leaves out), read at the first bin read.
    let at_black = match (at_black, read.iter().position(Option::is_some)) {
        (Some(v), Some(b)) => Some((v - (pack_bins[b].moments().1 - vars[b].unwrap_or(0.0))).max(MIN_VARIANCE)),
        _ => None,
    };
    // Which bins to split: by the law over the darkest bins read (its intercept the measured
    // variance at black where there is one).
    let first = dark_law(&read, w, FIRST_LAW_BINS, None)?;
    let first = at_black.map_or(first, |v| DarkLaw { intercept: v, slope: first.slope });
    let needs = |b: usize| vars[b].is_some() && first.slope * w > SPLIT_ABOVE * first.variance((b as f64 + 0.5) * w);
    let last = (0..bins.len()).rev().find(|&b| needs(b))?;
    // The law the split levels follow: fitted on every bin read up to one past the last split
    // bin (a bin's samples sit anywhere in it; over several bins their offsets average out).
    let count = read.iter().take(last + 2).flatten().count().max(2);
    let law = dark_law(&read, w, count, at_black)?;
    let variance_at = |x: f64| law.variance(x).max(MIN_VARIANCE);
    let mut lut = binning.lut(pos);
    let mut extra = Vec::new();
    let step = GROUP_STEP.ln();
    // (bin, group key) of the run being built, its levels and summed variance.
    let mut run: Option<(usize, i64, Vec<usize>, f64)> = None;
    let flush = |run: &mut Option<(usize, i64, Vec<usize>, f64)>, lut: &mut Vec<u16>, extra: &mut Vec<BinModel>| {
        if let Some((b, _, levels, sum)) = run.take() {
            let bin: &BinModel = &bins[b];
            let (mean, _) = bin.moments();
            let v = sum / levels.len() as f64;
            let mut m = BinModel::from_pmf(&bin.pmf().rescaled(mean, v), bin.samples, bin.filled());
            m.source = bin.source;
            let index = (bins.len() + extra.len()) as u16;
            extra.push(m);
            for l in levels {
                lut[l] = index;
            }
        }
    };
    for level in 0..lut.len() {
        let b = lut[level] as usize;
        if !needs(b) {
            flush(&mut run, &mut lut, &mut extra);
            continue;
        }
        let v = variance_at(level as f64 - black);
        let key = (v.ln() / step).floor() as i64;
        match &mut run {
            Some((rb, rk, levels, sum)) if *rb == b && *rk == key => {
                levels.push(level);
                *sum += v;
            }
            _ => {
                flush(&mut run, &mut lut, &mut extra);
                run = Some((b, key, vec![level], v));
            }
        }
    }
    flush(&mut run, &mut lut, &mut extra);
    // The tables are indexed in 16 bits: a position that would need more keeps its bins.
    (bins.len() + extra.len() <= u16::MAX as usize + 1).then_some(FineLevels { lut, extra })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::layout::{CfaPattern, SensorLayout};
    use crate::model::pmf::Pmf;

    fn gaussian(var: f64) -> BinModel {
        let sd = var.sqrt();
        let r = (8.0 * sd).ceil() as i32 + 1;
        let p = Pmf::from_weights(-r, (-r..=r).map(|n| (-(n as f64).powi(2) / (2.0 * var)).exp())).expect("pmf");
        let mut b = BinModel::from_pmf(&p, 10_000, false);
        b.source = crate::model::bin_source::BinSource::Measured;
        b
    }

    fn binning(width: u16) -> Binning {
        let layout = SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [1024.0; 4], white: 16383 };
        Binning::new(&layout, width)
    }

    /// Bins holding a linear law `b + a·x` at their centres.
    fn law_bins(binning: &Binning, a: f64, b: f64) -> Vec<BinModel> {
        let w = binning.bin_width as f64;
        (0..binning.bins(0)).map(|k| gaussian(b + a * (k as f64 + 0.5) * w)).collect()
    }

    #[test]
    fn levels_near_black_follow_the_law_within_their_bin() {
        let bn = binning(64);
        let (a, b) = (3.3, 4.8);
        let bins = law_bins(&bn, a, b);
        let fine = fine_levels(&bn, 0, &bins, &bins, None).expect("the first bins need splitting");
        let all: Vec<BinModel> = bins.iter().chain(&fine.extra).cloned().collect();
        let mut worst: f64 = 1.0;
        for x in 0..1024usize {
            let v = all[fine.lut[1024 + x] as usize].moments().1;
            let truth = b + a * x as f64;
            worst = worst.max((v / truth).max(truth / v));
        }
        // Group steps of 4 % and the rescale's discreteness; the bins alone read 23× at black.
        assert!(worst < 1.06, "{worst}");
        let held = bins[0].moments().1 / b;
        assert!(held > 20.0, "{held}");
        // Bins far above black are whole (the law hardly changes across them).
        assert_eq!(fine.lut[1024 + 64 * 40], 40);
        assert!(fine.extra.len() < 400, "{}", fine.extra.len());
    }

    #[test]
    fn a_bin_the_law_hardly_changes_across_is_left_alone() {
        // 4 DN bins and a read noise of 30 DN²: ±2 % across the first bin.
        let bn = binning(4);
        assert_eq!(fine_levels(&bn, 0, &law_bins(&bn, 0.3, 30.0), &law_bins(&bn, 0.3, 30.0), None), None);
    }

    #[test]
    fn clipped_bins_keep_their_pmf() {
        let bn = binning(64);
        let mut bins = law_bins(&bn, 3.3, 4.8);
        bins[0].clipped = true;
        let fine = fine_levels(&bn, 0, &bins, &bins, None).expect("bin 1 still needs it");
        assert!((0..1088).all(|l| fine.lut[l] == 0), "bin 0 draws from itself");
        assert!(fine.lut[1088] as usize >= bins.len());
    }

    #[test]
    fn dark_frames_set_the_variance_at_black() {
        // The law's slope from the bins, its intercept off: the bins say 20 DN² at black where
        // the dark frames measured 4.8.
        let bn = binning(64);
        let w = 64.0;
        let bins: Vec<BinModel> = (0..bn.bins(0)).map(|k| gaussian(20.0 + 3.3 * (k as f64 + 0.5) * w)).collect();
        let along_law = fine_levels(&bn, 0, &bins, &bins, None).expect("split");
        let at_black = |f: &FineLevels| {
            let all: Vec<BinModel> = bins.iter().chain(&f.extra).cloned().collect();
            all[f.lut[1024] as usize].moments().1
        };
        assert!((at_black(&along_law) / 20.0 - 1.0).abs() < 0.05, "{}", at_black(&along_law));
        let measured = fine_levels(&bn, 0, &bins, &bins, Some(4.8)).expect("split");
        assert!((at_black(&measured) / 4.8 - 1.0).abs() < 0.05, "{}", at_black(&measured));
    }
}
