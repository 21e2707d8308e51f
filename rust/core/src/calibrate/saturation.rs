//! Reference pixels at the sensor's ceiling (method.md, Calibration 2): where the reference burst
//! saturated — the ADC's white code, or a full well that fills below it — a pixel's clean level
//! is the ceiling, not its brightness, and the target frames at other gains and exposures do not
//! share that ceiling. Such a pixel is left out of the flat set.
//!
//! The ceiling shows in the burst's own frame-to-frame noise: the per-frame variance rises with
//! the level (shot noise), and at saturation it collapses (to the read noise behind a full well,
//! to nothing at white). Per position, level groups are scanned upwards against the line fitted
//! (count-weighted) to the groups below; the first whose variance is below [`COLLAPSE`] of that
//! line's value has saturated. Pixels at or above that group, and those within
//! [`MARGIN_SIGMAS`] standard deviations below it (their mean is pulled down by the frames that
//! reached the ceiling), are not flat.

use crate::calibrate::flat::{FlatReport, GROUPS, Groups, NOT_FLAT, TemporalStats};
use crate::math::fit::{nn_poly_fit, poly_eval};
use crate::model::layout::{POSITIONS, position};

/// A level group whose per-frame variance is below this fraction of the variance the groups
/// below it predict has saturated. A full well collapses the variance to the read noise's, a
/// factor `1 + full well · gain² / read²` (hundreds on any sensor at its base ISO); sampling
/// noise of a group's variance (≥ 64 differences: ±18 %) and edges that moved (which inflate a
/// group) do not come near it.
const COLLAPSE: f64 = 0.25;
/// Groups below a candidate needed to predict its variance.
const MIN_BELOW: usize = 3;
/// Differences a group needs to count (as [`TemporalStats::variance_fits`] asks).
const MIN_DIFFERENCES: f64 = 64.0;
/// Levels this many standard deviations (of the per-frame noise just below the ceiling) under
/// it are left out too: a level `k` SD under a ceiling has its mean pulled down by
/// `E[(Z − k)⁺]` SD, 0.4 at the ceiling, 0.0085 at 2.
const MARGIN_SIGMAS: f64 = 2.0;

/// Per position, the lowest clean level (DN) the reference burst's saturation reaches, margin
/// included; `None` where no level group collapsed (or the burst has one frame).
pub(crate) fn ceilings(temporal: &TemporalStats, groups: &Groups) -> [Option<f64>; POSITIONS] {
    std::array::from_fn(|pos| {
        let span = (groups.white as f64 - groups.black[pos] as f64).max(1.0);
        // (group, level above black, per-frame variance, differences) of the groups with data.
        let pts: Vec<(usize, f64, f64, f64)> = (0..GROUPS)
            .filter_map(|g| {
                let [n, s1, s2] = temporal.acc[pos * GROUPS + g];
                (n >= MIN_DIFFERENCES).then(|| {
                    let m = s1 / n;
                    (g, groups.center(pos, g), ((s2 / n - m * m) / 2.0).max(0.0), n)
                })
            })
            .collect();
        // The lowest group from which every group with data is collapsed against the law of the
        // groups below the first of them.
        for k in MIN_BELOW..pts.len() {
            let law = robust_line(&pts[..k]);
            let collapsed = |p: &(usize, f64, f64, f64)| p.2 < COLLAPSE * poly_eval(&law, p.1).max(0.0);
            if pts[k..].iter().all(collapsed) {
                let edge = pts[k].0 as f64 / GROUPS as f64 * span;
                let sd = poly_eval(&law, edge).max(0.0).sqrt();
                return Some(groups.black[pos] as f64 + edge - MARGIN_SIGMAS * sd);
            }
        }
        None
    })
}

/// The per-frame variance as a line in the level over `pts` (count-weighted), refitted without
/// the groups more than twice above it, as the flat test's robust line is: edges that moved
/// inflate the sparse level groups between a chart's patches, and a line they pulled up would
/// make the patches above them look collapsed.
fn robust_line(pts: &[(usize, f64, f64, f64)]) -> Vec<f64> {
    let mut kept: Vec<(usize, f64, f64, f64)> = pts.to_vec();
    let mut law = vec![0.0, 0.0];
    for _ in 0..3 {
        let x: Vec<f64> = kept.iter().map(|p| p.1).collect();
        let y: Vec<f64> = kept.iter().map(|p| p.2).collect();
        let w: Vec<f64> = kept.iter().map(|p| p.3).collect();
        law = nn_poly_fit(&x, &y, &w, 1);
        let next: Vec<(usize, f64, f64, f64)> =
            kept.iter().copied().filter(|p| p.2 <= 2.0 * poly_eval(&law, p.1) + 1.0).collect();
        if next.len() == kept.len() || next.len() < 2 {
            break;
        }
        kept = next;
    }
    law
}

/// Marks the flat pixels of `levels` (`w` wide) at or above their position's ceiling not flat,
/// and takes them out of `report`'s flat counts. Returns how many per position.
pub(crate) fn leave_out(
    levels: &mut [u16],
    w: usize,
    ceilings: &[Option<f64>; POSITIONS],
    report: &mut FlatReport,
) -> [u64; POSITIONS] {
    let mut out = [0u64; POSITIONS];
    if ceilings.iter().all(Option::is_none) {
        return out;
    }
    for (y, row) in levels.chunks_exact_mut(w.max(1)).enumerate() {
        for (x, c) in row.iter_mut().enumerate() {
            let pos = position(y, x);
            if let Some(top) = ceilings[pos]
                && *c != NOT_FLAT
                && *c as f64 >= top
            {
                *c = NOT_FLAT;
                out[pos] += 1;
            }
        }
    }
    for (flat, n) in report.flat.iter_mut().zip(out) {
        *flat -= n;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Temporal statistics of a 12-bit sensor (black 200, e⁻/DN 1) whose per-frame variance is
    /// `9 + level` up to `ceiling` (above black) and `9` from there: the differences are given as
    /// `n` of them with mean 0 and variance `2·var`.
    fn stats(ceiling: Option<f64>, inflate: Option<(usize, f64, f64)>) -> (TemporalStats, Groups) {
        let groups = Groups { black: [200.0; POSITIONS], white: 4095 };
        let mut t = TemporalStats::default();
        for pos in 0..POSITIONS {
            for g in 0..GROUPS {
                let level = groups.center(pos, g);
                let mut var = match ceiling {
                    Some(c) if level >= c => 9.0,
                    _ => 9.0 + level,
                };
                // A group of edges that moved: `factor` × the variance, `count` differences.
                let mut n = 4000.0;
                if let Some((_, factor, count)) = inflate.filter(|i| i.0 == g) {
                    var *= factor;
                    n = count;
                }
                t.acc[pos * GROUPS + g] = [n, 0.0, 2.0 * var * n];
            }
        }
        (t, groups)
    }

    #[test]
    fn a_full_well_below_white_is_found_with_its_margin() {
        // The well fills at 3 400 DN above black: the group holding it and those above collapse.
        let (t, groups) = stats(Some(3400.0), Some((20, 3.0, 80.0)));
        let c = ceilings(&t, &groups);
        let span = 4095.0 - 200.0;
        let first = (0..GROUPS).find(|&g| groups.center(0, g) >= 3400.0).expect("a group above");
        let edge = first as f64 / GROUPS as f64 * span;
        let want = 200.0 + edge - 2.0 * (9.0 + edge).sqrt();
        for top in c {
            let top = top.expect("a ceiling");
            assert!((top - want).abs() < 1.0, "ceiling {top:.1}, want {want:.1}");
        }
    }

    #[test]
    fn noise_that_keeps_rising_has_no_ceiling() {
        // A group of edges that moved does not make the groups above it look collapsed.
        for inflate in [None, Some((5, 3.0, 80.0)), Some((40, 3.0, 80.0)), Some((62, 100.0, 4000.0))] {
            let (t, groups) = stats(None, inflate);
            assert_eq!(ceilings(&t, &groups), [None; POSITIONS], "inflated group {inflate:?}");
        }
    }

    /// The last case above is one a plain (not robust) line through the groups below would
    /// take for a ceiling.
    #[test]
    fn the_inflated_group_fools_a_plain_line() {
        let (t, groups) = stats(None, Some((62, 100.0, 4000.0)));
        let pt = |g: usize| {
            let [n, _, s2] = t.acc[g];
            (groups.center(0, g), s2 / n / 2.0, n)
        };
        let below: Vec<(f64, f64, f64)> = (0..63).map(pt).collect();
        let x: Vec<f64> = below.iter().map(|p| p.0).collect();
        let y: Vec<f64> = below.iter().map(|p| p.1).collect();
        let w: Vec<f64> = below.iter().map(|p| p.2).collect();
        let plain = nn_poly_fit(&x, &y, &w, 1);
        let (level, var, _) = pt(63);
        assert!(var < COLLAPSE * poly_eval(&plain, level), "{var} against {}", poly_eval(&plain, level));
    }

    #[test]
    fn pixels_at_the_ceiling_leave_the_flat_set() {
        let mut levels = vec![100u16, 3000, 3500, NOT_FLAT, 3600, 3399, 4095, 10];
        let mut report = FlatReport { flat: [2, 1, 2, 2], ..FlatReport::default() };
        let ceilings = [Some(3400.0); POSITIONS];
        // 4 × 2 image: (0,0) 100, (0,1) 3000, (0,2) 3500, (0,3) –, (1,0) 3600, (1,1) 3399, …
        let out = leave_out(&mut levels, 4, &ceilings, &mut report);
        assert_eq!(levels, vec![100, 3000, NOT_FLAT, NOT_FLAT, NOT_FLAT, 3399, NOT_FLAT, 10]);
        assert_eq!(out, [1, 0, 2, 0]);
        assert_eq!(report.flat, [1, 1, 0, 2]);
    }
}
