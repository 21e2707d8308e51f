//! The dark end within a bin: where the noise law's variance changes across one bin by more than
//! a bin's PMF can stand for (near black on a sensor with a small read noise and wide bins), the
//! levels of that bin draw from the bin's PMF rescaled to the variance the law gives at their
//! own level, in groups of levels whose variance differs by at most [`GROUP_STEP`]
//! (method.md, *Synthesis*, "Within a bin near black").
//!
//! The variance at a level is the law `b + a·x` fitted on the bins' variances read at their
//! centres ([`crate::derive::noise_law::dark_law`]), `b` the variance at black measured by the
//! ISO's dark step (without one, nothing is split), never below what the data measured
//! ([`law_floor`]). A bin's shape and mean are kept; only its spread moves.

use std::borrow::Cow;

use crate::derive::black_rounding;
use crate::derive::noise_law::{DarkLaw, dark_law};
use crate::model::layout::{Binning, lut_at_reference_levels};
use crate::model::pack::{BinModel, IsoModel, ModelOrigin, ModelPack};
use crate::model::structure::IsoStructure;

/// A bin is split when the law's variance changes across it by more than this fraction of its
/// own variance (±2.5 % at its two ends). ±5 % was not enough: with the few per cent the PMFs
/// carry of the clean image's own error (method.md, *Selection by the clean image*), the ends of
/// the first whole bins read 1.10–1.13 on two random sensors of `tests/e2e/tests/dark_end.rs`.
pub const SPLIT_ABOVE: f64 = 0.05;

/// Levels share one rescaled PMF while their variances lie within one step of this ratio (4 %).
pub const GROUP_STEP: f64 = 1.04;

/// The clean image's rounding in [`variance_at_black`] (DN²): at most 1/12 (its fraction uniform
/// over the code), 0 where the pixels' means sit on whole codes (EMVA set 002's dark means).
pub const CLEAN_ROUNDING: f64 = 1.0 / 12.0;

/// The least variance the law may give a level (DN²), from the data: with a dark step, what its
/// frames measured at black without the clean image's rounding (the temporal variance, the frame
/// offsets and the pattern change: `at_black − CLEAN_ROUNDING`), since a sample at black holds
/// that plus a rounding of 0 to 1/12; without one (the fitted law of tests, as the sampler splits
/// nothing without a dark step), one rounding, 1/12. It was a fixed 1/6 DN²
/// (two independent roundings), an assumption a sub-DN sensor breaks: for noise of SD σ the
/// variance about a rounded clean level is below 1/6 up to σ ≈ 0.3 DN whatever the clean
/// level's fraction, and goes to 0 with σ (method.md, *Synthesis*, "Within a bin near black").
pub fn law_floor(at_black: Option<f64>) -> f64 {
    match at_black {
        Some(v) if v.is_finite() => (v - CLEAN_ROUNDING).max(f64::MIN_POSITIVE),
        _ => CLEAN_ROUNDING,
    }
}

/// Whether bin 0 (black's) of position `pos` holds one whole level, black's code: 1 DN bins and
/// black's fraction half a code or more (EMVA set 002, black 2.82–2.92, bin 0 = codes 0–3, the
/// levels under black's code below black); where it holds two (black 6.3: codes 6 and 7), no.
/// Such a bin's samples sit at black's level (dark frames, the dimmest lit steps): its PMF is
/// that level's own ([`fine_levels`] keeps it), and holds the fixed pattern a sub-DN pattern
/// cannot move the rounded clean level by (`synth/structure.rs`, `black_phase_set`).
pub fn black_bin_one_level(binning: &Binning, pos: usize) -> bool {
    let black = binning.black[pos] as f64;
    binning.bin_width <= 1 && (black + 1.0).ceil() - 1.0 < (black - 0.5).ceil() + 1.0
}

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
/// [`variance_at_black`]), or interpolated between two such ISOs ([`interpolated_at_black`]):
/// a plain histogram, the parametric models, an extrapolated ISO and an ISO without dark frames
/// keep one PMF per bin.
pub fn position_fine_levels(pack: &ModelPack, model: &IsoModel, pos: usize, bins: &[BinModel]) -> Option<FineLevels> {
    position_fine_levels_at(pack, model, pos, || Cow::Borrowed(bins), 1.0)
}

/// [`position_fine_levels`] for clean images at the target ISO's brightness: the table of clean
/// level `c` is the one of the reference level `x = black + (c − black)/gain` (`gain` the gain
/// ratio the sampler divides by for `CleanAt::Target`), at the law's variance at
/// `x` itself rather than at `x` rounded to a whole level (near black on a steep law a whole
/// level is a large step: with the rounded level random sensor 62 of `tests/e2e/tests/dark_end.rs`
/// read up to 1.14× the real variance, now 1.08). `lut` is then indexed by the target's levels.
/// `bins` makes the PMFs the sampler draws from, asked for only where the position has tables
/// to build (for a structured model they are deconvolved: no work where nothing is split).
pub fn target_fine_levels<'b>(
    pack: &ModelPack,
    model: &IsoModel,
    pos: usize,
    bins: impl FnOnce() -> Cow<'b, [BinModel]>,
    gain: f64,
) -> Option<FineLevels> {
    (gain.is_finite() && gain > 0.0).then(|| position_fine_levels_at(pack, model, pos, bins, gain)).flatten()
}

fn position_fine_levels_at<'b>(
    pack: &ModelPack,
    model: &IsoModel,
    pos: usize,
    bins: impl FnOnce() -> Cow<'b, [BinModel]>,
    gain: f64,
) -> Option<FineLevels> {
    // Without a dark step the variance at black is the fitted intercept, which a chart whose
    // darkest patch is well above black cannot pin: splitting on it made the random family's
    // pack lose to the plain histogram (median pack / plain 0.917 → 0.959, worst 1.00 → 1.76).
    let at_black = match &model.origin {
        ModelOrigin::Calibrated if model.positions[pos].is_estimated() => {
            variance_at_black(pack.structure_of(model.iso), pos, pack.layout.black[pos] as f64)?
        }
        ModelOrigin::Interpolated { from } => interpolated_at_black(pack, model, pos, from)?,
        _ => return None,
    };
    fine_levels_at(&pack.binning(), pos, &bins(), &model.positions[pos].bins, Some(at_black), gain)
}

/// The variance at black of an ISO interpolated between calibrated ones (`from`), when the two
/// that bracket it are estimated at `pos` and both have a dark step: read noise before the gain
/// grows with the square of the gain and what follows it does not, so the variance at black is
/// `c₀ + c₂·G²` through the two, `G` the ISO times its gain ratio (exact where the dark frames
/// hold only those two parts); `c₀` held at 0 where the two would make it negative, and `ln v`
/// linear in `ln G` where the variance at black does not grow with the gain.
pub fn interpolated_at_black(pack: &ModelPack, model: &IsoModel, pos: usize, from: &[u32]) -> Option<f64> {
    let below = from.iter().copied().filter(|&k| k < model.iso).max()?;
    let above = from.iter().copied().filter(|&k| k > model.iso).min()?;
    let side = |k: u32| -> Option<(f64, f64)> {
        let m = pack.iso(k).filter(|m| m.is_calibrated() && m.positions[pos].is_estimated())?;
        let v = variance_at_black(pack.structure_of(k), pos, pack.layout.black[pos] as f64)?;
        Some((k as f64 * m.gain_ratio[pos], v))
    };
    let ((g0, v0), (g1, v1)) = (side(below)?, side(above)?);
    let g = model.iso as f64 * model.gain_ratio[pos];
    if !(g0 > 0.0 && g1 > g0 && g.is_finite()) {
        return None;
    }
    let v = if v1 <= v0 {
        let t = (g / g0).ln() / (g1 / g0).ln();
        (v0.ln() + t * (v1.ln() - v0.ln())).exp()
    } else {
        let c2 = (v1 - v0) / (g1 * g1 - g0 * g0);
        let c0 = v0 - c2 * g0 * g0;
        if c0 >= 0.0 { c0 + c2 * g * g } else { g * g * (v0 * g0 * g0 + v1 * g1 * g1) / (g0.powi(4) + g1.powi(4)) }
    };
    v.is_finite().then_some(v)
}

/// The variance of the pack's pixel PMFs at black at one position when its ISO has a dark
/// step (`None` otherwise), `black` the position's black level: the dark frames' temporal
/// variance, what the PMFs hold besides (the frame offsets, the change of the fixed pattern from
/// the reference ISO) and the clean image's rounding at black
/// ([`black_rounding::rounding_at_black`]: 1/12 where the dark pixels' levels spread over a DN
/// or more, less where a sub-DN pattern keeps them near one place in their code). It counted
/// 1/12 everywhere: on EMVA set 002 (black 2.82–2.92, a 0.12 DN pattern) `T + 1/12` read
/// 0.20 DN² where a dark frame less its rounded leave-one-out mean holds 0.14
/// (`rust/core/tests/variance_at_black_set002.rs`).
pub fn variance_at_black(structure: Option<&IsoStructure>, pos: usize, black: f64) -> Option<f64> {
    let st = structure?;
    let fpn = st.fpn.as_ref()?;
    let frames = st.frames.as_ref().map_or(0.0, |f| f.variance(pos));
    let rounding = black_rounding::rounding_at_black(fpn, pos, black);
    let v = fpn.temporal_var[pos] + frames + fpn.in_pixel_noise[pos].variance() + rounding;
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
    fine_levels_at(binning, pos, bins, pack_bins, at_black, 1.0)
}

/// [`fine_levels`] with clean level `c` standing for the reference level `black + (c −
/// black)/gain` (its bin that of the rounded level, as the sampler for `CleanAt::Target` picks
/// it, its variance the law's at the level itself); `gain` 1: the reference levels.
fn fine_levels_at(
    binning: &Binning,
    pos: usize,
    bins: &[BinModel],
    pack_bins: &[BinModel],
    at_black: Option<f64>,
    gain: f64,
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
    let floor = law_floor(at_black);
    let at_black = match (at_black, read.iter().position(Option::is_some)) {
        (Some(v), Some(b)) => Some((v - (pack_bins[b].moments().1 - vars[b].unwrap_or(0.0))).max(floor)),
        _ => None,
    };
    // Which bins to split: by the law over the darkest bins read (its intercept the measured
    // variance at black where there is one).
    let first = dark_law(&read, w, FIRST_LAW_BINS, None)?;
    let first = at_black.map_or(first, |v| DarkLaw { intercept: v, slope: first.slope });
    // Bins one level wide (an 8-bit sensor's): above bin 0 a bin holds one whole level, its PMF
    // is that level's own, and the law would only replace what the level measured (on EMVA set
    // 002 the levels 1–12 DN above black lost 10–40 % of their variance to it).
    //
    // Bin 0 too where it holds one whole level from half a code below black up (black's code,
    // when black's fraction is half a code or more: EMVA set 002, black 2.82–2.92, bin 0 = codes
    // 0–3), the levels under it below black: asked to widen that code's PMF (0.083–0.104 DN²
    // measured, the held-out frames 0.092) to the dark frames' `T + 1/12` = 0.18–0.23, the
    // piecewise-uniform rescale (`Pmf::rescaled`, Sheppard's 1/12 for unit cells of a smooth
    // density, which a sub-DN PMF is not) narrowed it to 0.071–0.098. The variance at black now
    // counts the clean image's rounding as it is (0.11–0.17 by position there, `black_rounding`);
    // the level's own histogram is still the closer one (0.092 held out). The split levels keep
    // `Pmf::rescaled` (with `Pmf::rescaled_to`, which meets its target, `sub_dn_pattern`'s codes
    // 6 / 7 read 1.38 / 1.22 against 1.17 / 0.94: method.md). Where bin 0 holds two (black 6.3:
    // codes 6 and 7) it is split as before.
    let one_level = |b: usize| binning.bin_width <= 1 && (b > 0 || black_bin_one_level(binning, pos));
    let needs = |b: usize| {
        !one_level(b) && vars[b].is_some() && first.slope * w > SPLIT_ABOVE * first.variance((b as f64 + 0.5) * w)
    };
    let last = (0..bins.len()).rev().find(|&b| needs(b))?;
    // The law the split levels follow: fitted on every bin read up to one past the last split
    // bin (a bin's samples sit anywhere in it; over several bins their offsets average out).
    let count = read.iter().take(last + 2).flatten().count().max(2);
    let law = dark_law(&read, w, count, at_black)?;
    let variance_at = |x: f64| law.variance(x).max(floor);
    // Level → bin: the reference level's own, or the bin of the rounded reference level the
    // level stands for (the sampler's map for clean images at the target brightness).
    let reference = binning.lut(pos);
    let mut lut = if gain == 1.0 { reference } else { lut_at_reference_levels(&reference, black, gain) };
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
        let v = variance_at((level as f64 - black) / gain);
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
    fn target_levels_follow_the_law_at_their_own_reference_level() {
        // A gain ratio of 1.6 (a gain not ∝ ISO): target level `c` stands for the reference
        // level `(c − black)/1.6` above black, whose variance the table must have, not that of
        // the reference level rounded (up to ±0.5 DN there: ±1.65 DN² against 4.8 at black).
        let bn = binning(64);
        let (a, b, g) = (3.3, 4.8, 1.6);
        let bins = law_bins(&bn, a, b);
        let var_of = |f: &FineLevels, level: usize| {
            let k = f.lut[level] as usize;
            if k < bins.len() { bins[k].moments().1 } else { f.extra[k - bins.len()].moments().1 }
        };
        let target = fine_levels_at(&bn, 0, &bins, &bins, None, g).expect("split");
        let reference = fine_levels(&bn, 0, &bins, &bins, None).expect("split");
        let (mut worst, mut rounded): (f64, f64) = (1.0, 1.0);
        for x in 0..1024usize {
            let truth = b + a * x as f64 / g;
            let v = var_of(&target, 1024 + x);
            worst = worst.max((v / truth).max(truth / v));
            // What picking the rounded reference level's table gives.
            let r = var_of(&reference, (1024.0 + x as f64 / g).round() as usize);
            rounded = rounded.max((r / truth).max(truth / r));
        }
        assert!(worst < 1.06, "{worst}");
        // The rounded level's table is beyond the issue's ×1.10 just above black.
        assert!(rounded > 1.15, "{rounded}");
        // Far above black the target levels draw from the bin of their reference level.
        assert_eq!(target.lut[1024 + 64 * 40], ((64.0 * 40.0 / g) / 64.0) as u16);
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
    fn one_level_bins_keep_their_own_variance() {
        // An 8-bit sensor (1 DN bins, black 2.87) with sub-DN noise: what each level measured,
        // set 002's per-code variances (they follow no line: the codes' fractions differ), and
        // 0.20 DN² at black from dark frames. Above bin 0 every bin is one whole level, so its
        // table is its own PMF. Main rescaled the levels near black to the law fitted through
        // the bins, a line these variances do not follow: worst 1.449× off the level's own.
        let layout = SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [2.87; 4], white: 255 };
        let bn = Binning::new(&layout, 1);
        let measured = [0.16, 0.26, 0.22, 0.31, 0.29, 0.30, 0.37, 0.36, 0.43, 0.46, 0.45, 0.50];
        let bins: Vec<BinModel> =
            (0..bn.bins(0)).map(|k| gaussian(measured.get(k).copied().unwrap_or(0.5 + 0.02 * k as f64))).collect();
        let own = |f: &Option<FineLevels>, level: usize| {
            let k = f.as_ref().map_or(bn.lut(0)[level], |f| f.lut[level]) as usize;
            match f {
                Some(f) if k >= bins.len() => f.extra[k - bins.len()].moments().1,
                _ => bins[k].moments().1,
            }
        };
        let fine = fine_levels(&bn, 0, &bins, &bins, Some(0.20));
        let mut worst: f64 = 1.0;
        for level in 4..40usize {
            let b = bn.lut(0)[level] as usize;
            let (v, m) = (own(&fine, level), bins[b].moments().1);
            worst = worst.max((v / m).max(m / v));
        }
        assert!(worst < 1.000_001, "a one-level bin's table is {worst}× off its own variance");
    }

    /// A three-point PMF: `p₋` at −1, `p₊` at +1, the rest at 0.
    fn three_point(minus: f64, plus: f64) -> BinModel {
        let p = Pmf::from_weights(-1, [minus, 1.0 - minus - plus, plus]).expect("pmf");
        let mut b = BinModel::from_pmf(&p, 130_000, false);
        b.source = crate::model::bin_source::BinSource::Measured;
        b
    }

    #[test]
    fn a_one_level_bin_at_black_keeps_its_own_pmf() {
        // EMVA set 002's bin 0 at position 2 (8 bits, 1 DN bins, black 2.87: bin 0 holds black's
        // code 3 and the codes below): 0.083 DN² measured, the shares at −1 / +1 DN its held-out
        // frames show. The dark frames put the law at 0.18 DN² at black (`T + 1/12` then); asked
        // for that, the piecewise-uniform rescale narrowed the PMF (0.071 DN², 0.86 of the bin's
        // own), which the sampler drew before. Bin 0 holds one whole level at or above black here
        // (code 3), so it keeps its PMF, as every one-level bin does: the level's own histogram,
        // not the law through the bins (`Pmf::rescaled_to` meets 0.18, which would be 2× the
        // held-out frames' 0.092).
        let layout = SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [2.87; 4], white: 255 };
        let bn = Binning::new(&layout, 1);
        let mut bins = vec![three_point(0.046, 0.042)];
        bins.extend((1..bn.bins(0)).map(|k| gaussian(0.26 + 0.01 * k as f64)));
        let fine = fine_levels(&bn, 0, &bins, &bins, Some(0.18));
        let lut = fine.as_ref().map_or(bn.lut(0), |f| f.lut.clone());
        for level in 0..4 {
            assert_eq!(lut[level], 0, "level {level} draws from bin 0's own PMF");
        }
        // Black at 2.3 (a fraction under half a code): bin 0 holds codes 2 (−0.3) and 3 (+0.7),
        // two levels the law tells apart, and is split as before.
        let layout = SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [2.3; 4], white: 255 };
        let bn = Binning::new(&layout, 1);
        let split = fine_levels(&bn, 0, &bins, &bins, Some(0.18)).expect("bin 0 split");
        assert!((2..4).any(|l| split.lut[l] as usize >= bins.len()), "{:?}", &split.lut[..5]);
    }

    #[test]
    fn the_law_may_reach_what_the_dark_frames_measured() {
        // With a dark step the floor is the measured variance less the clean image's rounding
        // (0 to 1/12): a sensor of 0.2 DN at black has T = 0.04 and `T + 1/12` = 0.123 DN², which
        // the old floor of 1/6 lifted by 35 %. Without a dark step, one rounding.
        assert!((law_floor(Some(0.04 + CLEAN_ROUNDING)) - 0.04).abs() < 1e-12);
        assert_eq!(law_floor(None), CLEAN_ROUNDING);
        assert!(law_floor(Some(0.01)) > 0.0, "a floor is positive");
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
