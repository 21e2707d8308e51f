//! Filling under-sampled bins from their neighbours (method.md, Calibration 5): the normalised
//! shape of the nearest well-sampled bin, rescaled to a mean and variance interpolated across
//! levels. Sparse bins are pooled, never trusted.

use crate::fit::{nn_poly_fit, poly_eval};
use crate::histogram::NoiseHistogram;
use crate::pack::BinModel;
use crate::pmf::Pmf;

/// A measured bin that is trusted: its level, moments and PMF.
#[derive(Debug, Clone)]
pub struct Anchor {
    pub bin: usize,
    pub level: f64,
    pub mean: f64,
    pub var: f64,
    pub pmf: Pmf,
}

/// Turns one position's histograms into bin models, filling bins with fewer than
/// `min_samples` samples. `level_of(bin)` gives a bin's centre level. Returns `None` when no
/// bin of this position has enough samples to stand on.
pub fn fill_position(
    hists: &[NoiseHistogram],
    min_samples: u64,
    level_of: impl Fn(usize) -> f64,
) -> Option<Vec<BinModel>> {
    let anchors: Vec<Anchor> = hists
        .iter()
        .enumerate()
        .filter(|(_, h)| h.total() >= min_samples.max(1))
        .map(|(b, h)| {
            let (mean, var) = h.moments();
            let t = h.trimmed();
            let pmf = Pmf::from_weights(t.first, t.counts.iter().map(|&c| c as f64))
                .unwrap_or(Pmf { first: 0, p: vec![1.0] });
            Anchor { bin: b, level: level_of(b), mean, var, pmf }
        })
        .collect();
    if anchors.is_empty() {
        return None;
    }
    let var_fit = variance_fit(&anchors);
    let mut out = Vec::with_capacity(hists.len());
    let mut next = 0usize; // index of the first anchor with bin >= b
    for (b, h) in hists.iter().enumerate() {
        while next < anchors.len() && anchors[next].bin < b {
            next += 1;
        }
        if next < anchors.len() && anchors[next].bin == b {
            let t = h.trimmed();
            out.push(BinModel { first: t.first, counts: t.counts, samples: h.total(), filled: false });
            continue;
        }
        let below = next.checked_sub(1).map(|i| &anchors[i]);
        let above = anchors.get(next);
        let level = level_of(b);
        let (mean, var, shape) = match (below, above) {
            (Some(lo), Some(hi)) => {
                let t = (level - lo.level) / (hi.level - lo.level);
                let shape = if level - lo.level <= hi.level - level { &lo.pmf } else { &hi.pmf };
                (lo.mean + t * (hi.mean - lo.mean), lo.var + t * (hi.var - lo.var), shape)
            }
            (Some(lo), None) => (lo.mean, poly_eval(&var_fit, level).max(lo.var.min(1.0)), &lo.pmf),
            (None, Some(hi)) => (hi.mean, poly_eval(&var_fit, level).max(0.05), &hi.pmf),
            (None, None) => (anchors[0].mean, anchors[0].var, &anchors[0].pmf),
        };
        let pmf = shape.rescaled(mean, var.max(0.05));
        out.push(BinModel::from_pmf(&pmf, h.total(), true));
    }
    Some(out)
}

/// Non-negative quadratic fit of variance against level over the anchors (for extrapolation
/// beyond the measured range).
fn variance_fit(anchors: &[Anchor]) -> Vec<f64> {
    let x: Vec<f64> = anchors.iter().map(|a| a.level).collect();
    let y: Vec<f64> = anchors.iter().map(|a| a.var).collect();
    let w = vec![1.0; x.len()];
    let degree = if anchors.len() >= 6 {
        2
    } else if anchors.len() >= 2 {
        1
    } else {
        0
    };
    nn_poly_fit(&x, &y, &w, degree)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gaussian_hist(mean: f64, sd: f64, n: u64) -> NoiseHistogram {
        let mut h = NoiseHistogram::default();
        let lo = (mean - 6.0 * sd).floor() as i32;
        let hi = (mean + 6.0 * sd).ceil() as i32;
        let w: Vec<f64> = (lo..=hi).map(|k| (-(k as f64 - mean).powi(2) / (2.0 * sd * sd)).exp()).collect();
        let t: f64 = w.iter().sum();
        for (i, x) in w.iter().enumerate() {
            h.add_n(lo + i as i32, (x / t * n as f64).round() as u64);
        }
        h
    }

    #[test]
    fn gaps_are_filled_with_interpolated_moments() {
        // variance = 2 + 0.5·level, bins at levels 10, 20, …; bins 3..=6 are sparse.
        let hists: Vec<NoiseHistogram> = (0..12)
            .map(|b| {
                let level = 10.0 * (b as f64 + 1.0);
                let n = if (3..=6).contains(&b) { 20 } else { 100_000 };
                gaussian_hist(0.0, (2.0 + 0.5 * level).sqrt(), n)
            })
            .collect();
        let bins = fill_position(&hists, 1000, |b| 10.0 * (b as f64 + 1.0)).unwrap();
        for b in 0..12 {
            let level = 10.0 * (b as f64 + 1.0);
            let (m, v) = bins[b].moments();
            assert_eq!(bins[b].filled, (3..=6).contains(&b));
            let want = 2.0 + 0.5 * level;
            assert!((v - want).abs() / want < 0.06, "bin {b}: var {v} want {want}");
            assert!(m.abs() < 0.1);
        }
        assert_eq!(bins[4].samples, hists[4].total());
    }

    #[test]
    fn no_anchor_means_none() {
        let hists = vec![gaussian_hist(0.0, 1.0, 10); 4];
        assert!(fill_position(&hists, 1000, |b| b as f64).is_none());
    }
}
