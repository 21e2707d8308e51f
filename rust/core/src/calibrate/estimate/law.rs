//! The noise law of one (ISO, position): mean and variance of the noise against the clean
//! level (method.md, "Estimation" 3).

use crate::calibrate::estimate::stat::{MIN_VAR, Stat};
use crate::math::fit::{nn_poly_fit, poly_eval, wls};
use crate::model::bin_levels::BinLevels;

/// The local-linear law's variance window holds at least this many samples and
/// [`LAW_MIN_BINS`] bins …
pub(super) const LAW_MIN_SAMPLES: f64 = 8192.0;
const LAW_MIN_BINS: usize = 4;
/// … and its mean window four times as many bins: what is left of the clean image's selection
/// shift ([`crate::calibrate::deselect`]) swings the mean from bin to bin across a cluster of levels, and a
/// narrow window would carry one cluster edge's swing into the next gap.
pub(super) const LAW_MIN_BINS_MEAN: usize = 16;

/// The noise law of one (ISO, position): mean and variance of `n` at every bin.
#[derive(Debug, Clone, PartialEq)]
pub struct Law {
    pub mean: Vec<f64>,
    pub var: Vec<f64>,
}

impl Law {
    /// Fits the law on the measured bins (`stats`) not flagged clipped; see the module docs.
    pub(super) fn fit(stats: &[Stat], clipped: &[bool], levels: &BinLevels) -> Self {
        let nbins = levels.len();
        let mut pts: Vec<(f64, f64, f64, f64)> = stats
            .iter()
            .enumerate()
            .filter(|(b, s)| s.n >= 2 && !clipped[*b])
            .map(|(b, s)| (levels.center[b], s.n as f64, s.mean, s.var))
            .collect();
        if pts.is_empty() {
            // Everything measured is clipped (or nothing is measured): use what there is.
            pts = stats
                .iter()
                .enumerate()
                .filter(|(_, s)| s.n >= 1)
                .map(|(b, s)| (levels.center[b], s.n as f64, s.mean, s.var))
                .collect();
        }
        if pts.is_empty() {
            return Self { mean: vec![0.0; nbins], var: vec![1.0; nbins] };
        }
        let first_level = pts[0].0;
        let last_level = pts[pts.len() - 1].0;
        let bw = if nbins > 1 { (levels.center[1] - levels.center[0]).abs().max(1.0) } else { 1.0 };
        let local =
            |x: f64| (local_linear(&pts, x, bw, LAW_MIN_BINS_MEAN).0, local_linear(&pts, x, bw, LAW_MIN_BINS).1);
        // Global trends for extrapolation.
        // Trends for extrapolation: shot noise makes the variance linear in the level, so each
        // end continues along a non-negative line fitted on the half of the measured levels
        // next to it (the slope the data shows there, not one bent by the far end).
        let mid = 0.5 * (first_level + last_level);
        // Weights from the local law's variance at each point (a sparse bin's own variance can
        // be near 0 by chance and would take all the weight).
        let smooth_var: Vec<f64> = pts.iter().map(|p| local(p.0).1.max(MIN_VAR)).collect();
        let trend = |upper: bool| -> (Vec<f64>, Vec<f64>) {
            // (variance line, mean line) of one half
            let sel: Vec<(f64, f64, f64, f64)> = pts
                .iter()
                .zip(&smooth_var)
                .filter(|(p, _)| if upper { p.0 >= mid } else { p.0 <= mid })
                .map(|(p, &sv)| (p.0, p.1, p.2, sv))
                .collect();
            let raw: Vec<f64> =
                pts.iter().filter(|p| if upper { p.0 >= mid } else { p.0 <= mid }).map(|p| p.3).collect();
            // In levels above the first selected one, so that "non-negative" means a variance
            // ≥ 0 there and a slope ≥ 0, whatever the intercept at level 0 would be.
            let x0 = sel.first().map_or(0.0, |p| p.0);
            let xs: Vec<f64> = sel.iter().map(|p| p.0 - x0).collect();
            let vs = raw;
            let ms: Vec<f64> = sel.iter().map(|p| p.2).collect();
            let wv: Vec<f64> = sel.iter().map(|p| p.1 / p.3.powi(2)).collect();
            let wm: Vec<f64> = sel.iter().map(|p| p.1 / p.3).collect();
            let (gv, gm) = if sel.len() < 2 {
                (vec![vs.first().copied().unwrap_or(1.0), 0.0], vec![ms.first().copied().unwrap_or(0.0), 0.0])
            } else {
                (nn_poly_fit(&xs, &vs, &wv, 1), wls(&xs, &ms, &wm, &[0, 1]).unwrap_or(vec![ms[0], 0.0]))
            };
            // Back to absolute levels.
            (vec![gv[0] - gv[1] * x0, gv[1]], vec![gm[0] - gm[1] * x0, gm[1]])
        };
        let (gv_hi, gm_hi) = trend(true);
        let (gv_lo, gm_lo) = trend(false);
        let (m_first, v_first) = local(first_level);
        let (m_last, v_last) = local(last_level);
        let span = levels.reach() as f64;
        let mut mean = Vec::with_capacity(nbins);
        let mut var = Vec::with_capacity(nbins);
        for (b, &x) in levels.center.iter().enumerate() {
            // Beyond an end: the trend line, joined to the local law at the end by an offset
            // that fades over a few bins.
            let v = if x > last_level {
                let fade = (-(x - last_level) / (4.0 * bw)).exp();
                let tv = poly_eval(&gv_hi, x) + fade * (v_last - poly_eval(&gv_hi, last_level));
                tv.max(v_last.min(poly_eval(&gv_hi, last_level)))
            } else if x < first_level {
                let fade = (-(first_level - x) / (4.0 * bw)).exp();
                let tv = poly_eval(&gv_lo, x) + fade * (v_first - poly_eval(&gv_lo, first_level));
                // Toward black the variance falls along the trend (shot noise fades, read noise
                // stays); a measured bin's own variance, shrunk by the floor's clipping if
                // anything, bounds it from below. Holding the darkest unclipped level's variance
                // (or half of it) gave a 14-bit sensor at ISO 3200 about 104 DN² down to black
                // where the truth falls to 4.9, and the demo's phone at ISO 3200 1740 DN² where
                // its darkest bins measured 680 (clipped).
                let own = stats.get(b).filter(|s| s.n >= LAW_MIN_BINS as u64 * 8).map_or(0.0, |s| s.var);
                tv.min(v_first.max(poly_eval(&gv_lo, first_level))).max(own)
            } else {
                local(x).1
            };
            // The mean likewise, except that a local slope is never carried past an end: the
            // trend of the half next to it takes over.
            let m = if x > last_level {
                let fade = (-(x - last_level) / (4.0 * bw)).exp();
                poly_eval(&gm_hi, x) + fade * (m_last - poly_eval(&gm_hi, last_level))
            } else if x < first_level {
                let fade = (-(first_level - x) / (4.0 * bw)).exp();
                poly_eval(&gm_lo, x) + fade * (m_first - poly_eval(&gm_lo, first_level))
            } else {
                local(x).0
            };
            // Noise wider than the codes the sensor writes is all clipping: bounding the law
            // there bounds every prior PMF built on it (a damaged capture's law can be absurd).
            mean.push(m.clamp(-span, span));
            var.push(v.max(MIN_VAR).min(span * span));
        }
        Self { mean, var }
    }
}

/// Local-linear (tricube-weighted) estimate of (mean, variance) at level `x` from
/// `(level, samples, mean, var)` points sorted by level.
pub(super) fn local_linear(pts: &[(f64, f64, f64, f64)], x: f64, bw: f64, min_bins: usize) -> (f64, f64) {
    // Grow a window around x until it holds enough samples and bins.
    let start = pts.partition_point(|p| p.0 < x);
    let (mut lo, mut hi) = (start, start); // window is pts[lo..hi]
    let mut n = 0.0;
    let mut radius: f64 = 0.0;
    // Inside the measured range the window also reaches the nearest point on each side, so a
    // gap between measured levels is bridged (shot noise grows steadily across it) instead of
    // continuing one side's local slope.
    let inside = start > 0 && start < pts.len();
    while (n < LAW_MIN_SAMPLES || hi - lo < min_bins || (inside && (lo == start || hi == start)))
        && (lo > 0 || hi < pts.len())
    {
        let take_lo = match (lo > 0, hi < pts.len()) {
            (true, true) => (x - pts[lo - 1].0) <= (pts[hi].0 - x),
            (l, _) => l,
        };
        if take_lo {
            lo -= 1;
            n += pts[lo].1;
            radius = radius.max(x - pts[lo].0);
        } else {
            n += pts[hi].1;
            radius = radius.max(pts[hi].0 - x);
            hi += 1;
        }
    }
    let h = (radius * 1.25).max(2.5 * bw);
    let mut sel: Vec<(f64, f64, f64, f64)> = Vec::new();
    for p in pts {
        let d = (p.0 - x).abs() / h;
        if d < 1.0 {
            let k = (1.0 - d * d * d).powi(3);
            sel.push((p.0 - x, p.1 * k, p.2, p.3));
        }
    }
    if sel.is_empty() {
        let p = pts[start.min(pts.len() - 1)];
        return (p.2, p.3);
    }
    let xs: Vec<f64> = sel.iter().map(|s| s.0).collect();
    let w: Vec<f64> = sel.iter().map(|s| s.1).collect();
    let ms: Vec<f64> = sel.iter().map(|s| s.2).collect();
    let vs: Vec<f64> = sel.iter().map(|s| s.3).collect();
    let spread = {
        let sw: f64 = w.iter().sum();
        let mx = xs.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>() / sw;
        (xs.iter().zip(&w).map(|(a, b)| b * (a - mx).powi(2)).sum::<f64>() / sw).sqrt()
    };
    let fit = |ys: &[f64]| -> f64 {
        if sel.len() >= 2
            && spread > 0.25 * bw
            && let Some(c) = wls(&xs, ys, &w, &[0, 1])
        {
            return c[0];
        }
        let sw: f64 = w.iter().sum();
        ys.iter().zip(&w).map(|(y, w)| y * w).sum::<f64>() / sw
    };
    (fit(&ms), fit(&vs))
}
