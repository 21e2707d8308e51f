//! Pooling's re-binnings with the exact moments (`Data::deselected`, `Data::means_on_law`)
//! against known truth on narrow PMFs, where the piecewise-uniform re-binning (`Pmf::rescaled`)
//! loses variance: each bin holds the exact discretisation (4·10⁶ samples) of a heavy-tailed law,
//! 85 % N(0, s²) + 15 % N(0, (3s)²), whose variance grows with the level from 1.1 DN².

use super::*;
use crate::math::special::normal_mass;
use crate::metrics::jsd_pmf;
use crate::model::layout::{Binning, CfaPattern, SensorLayout};

const SAMPLES: f64 = 4.0e6;

fn variance_at(b: usize) -> f64 {
    1.1 + 0.15 * b as f64
}

/// The law with variance `var` on the integers, mean `mu`.
fn truth(var: f64, mu: f64) -> Pmf {
    let s = (var / 2.2).sqrt();
    let (lo, hi) = ((mu - 40.0 * s).floor() as i32, (mu + 40.0 * s).ceil() as i32);
    let w = (lo..=hi).map(|n| {
        let m = |sig: f64| normal_mass((n as f64 - 0.5 - mu) / sig, (n as f64 + 0.5 - mu) / sig);
        0.85 * m(s) + 0.15 * m(3.0 * s)
    });
    Pmf::from_weights(lo, w).expect("truth")
}

fn histogram(p: &Pmf) -> NoiseHistogram {
    let mut h = NoiseHistogram::default();
    for (i, &x) in p.p.iter().enumerate() {
        h.add_n(p.first + i as i32, (x * SAMPLES).round() as u64);
    }
    h
}

fn levels() -> BinLevels {
    let layout = SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 };
    BinLevels::new(&Binning::new(&layout, 4), 0)
}

/// The clean image's selection undone on bins of 1.1–3.9 DN²: each bin's mean moved by a
/// fractional shift and 10 % of its variance given back. The result must have the new mean and
/// variance, and stay close to the same law at them. Measured: variance within 1.0·10⁻⁴, worst
/// JSD to the truth 1.6·10⁻⁴, 0.1 %/99.9 % quantiles within 0.27 DN (the shape and quantile
/// bounds are guards against a gross shape error, not tight). The piecewise-uniform re-binning was
/// not run on this fixture; on the demo's deselected bins of 2–5 DN² it gave 0.953–0.970 of the
/// target variance (method.md, "Estimation" 4), which the variance bound fails.
#[test]
fn a_narrow_bin_deselected_is_the_law_at_its_new_moments() {
    let lv = levels();
    let nb = 20;
    let hists: Vec<NoiseHistogram> = (0..nb).map(|b| histogram(&truth(variance_at(b), 0.0))).collect();
    let clipped = vec![false; nb];
    let stats: Vec<Stat> = hists.iter().map(Stat::of).collect();
    let select: Vec<(f64, f64)> = (0..nb).map(|b| (0.1 + 0.37 * b as f64 % 0.8, 0.1 * stats[b].var)).collect();
    let data = Data::new(&hists, &clipped, &lv).deselected(&select, &lv);
    let (mut worst_var, mut worst_jsd, mut worst_q) = (0.0f64, 0.0f64, 0.0f64);
    for b in 0..nb {
        let p = data.pmfs[b].as_ref().expect("pmf");
        let (m, v) = p.moments();
        let (want_m, want_v) = (stats[b].mean - select[b].0, 1.1 * stats[b].var);
        assert!((m - want_m).abs() < 1e-3, "bin {b}: mean {m} against {want_m}");
        worst_var = worst_var.max((v / want_v - 1.0).abs());
        let t = truth(want_v, want_m);
        worst_jsd = worst_jsd.max(jsd_pmf(p, &t));
        for u in [0.001, 0.999] {
            worst_q = worst_q.max((p.quantile(u) - t.quantile(u)).abs());
        }
    }
    println!("deselected: worst |var ratio − 1| {worst_var:.5}, JSD {worst_jsd:.2e}, quantile error {worst_q:.3} DN");
    assert!(worst_var < 1e-3, "variance off by {worst_var}");
    assert!(worst_jsd < 5e-4, "JSD {worst_jsd}");
    assert!(worst_q < 0.5, "quantile error {worst_q} DN");
}

/// A bin's mean put on the law keeps the bin's variance without a correction after the fact:
/// bins of 1.1–6.9 DN² whose means sit 0.08 SD off a line every other bin. Measured: 40 bins
/// moved, variance within 0.9·10⁻⁴. The piecewise-uniform re-binning alone (the loop that
/// corrected it is gone) was not run on this fixture; on the demo's put-on-law bins of 2–5 DN² it
/// gave 0.937–0.976 of the variance (with the loop 1.000–1.002), which the bound fails.
#[test]
fn a_mean_put_on_the_law_keeps_the_variance() {
    let lv = levels();
    let nb = 40;
    let mean = |b: usize| 0.03 * b as f64 + if b.is_multiple_of(2) { 0.08 * variance_at(b).sqrt() } else { 0.0 };
    let hists: Vec<NoiseHistogram> = (0..nb).map(|b| histogram(&truth(variance_at(b), mean(b)))).collect();
    let clipped = vec![false; nb];
    let before: Vec<Stat> = hists.iter().map(Stat::of).collect();
    let data = Data::new(&hists, &clipped, &lv).means_on_law(&lv);
    let mut moved_bins = 0;
    let mut worst = 0.0f64;
    for b in 0..nb {
        let p = data.pmfs[b].as_ref().expect("pmf");
        let (m, v) = p.moments();
        if (m - before[b].mean).abs() > 1e-3 {
            moved_bins += 1;
            worst = worst.max((v / before[b].var - 1.0).abs());
            assert!((m - data.stats[b].mean).abs() < 1e-3, "bin {b}: mean {m} against {}", data.stats[b].mean);
        }
    }
    println!("means on law: {moved_bins} bins moved, worst |var ratio − 1| {worst:.5}");
    assert!(moved_bins >= 10, "only {moved_bins} bins moved");
    assert!(worst < 1e-3, "variance off by {worst}");
}
