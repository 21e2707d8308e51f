//! The estimator against known truth: per-bin noise drawn from an analytic heavy-tailed law,
//! split in folds like the session does, estimated, and compared with the truth by JSD — next
//! to the plain empirical estimator on the same samples.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::math::special::normal_mass;
use crate::metrics::jsd_pmf;
use crate::model::layout::Binning;

pub(super) const BLACK: f64 = 64.0;
const BW: f64 = 4.0;

/// Noise at clean level `l`: 85 % N(0, s²) + 15 % N(0, (3s)²) (kurtosis ≈ 8), scaled so the
/// variance is `var(l)`, mean `0.02·(l − black)`, rounded to integers.
fn truth_at(l: f64, var: impl Fn(f64) -> f64) -> Pmf {
    let v = var(l);
    // 0.85 s² + 0.15·9 s² = v
    let s = (v / (0.85 + 1.35)).sqrt();
    let mu = 0.02 * (l - BLACK);
    let sd = 3.0 * s;
    let lo = (mu - 12.0 * sd).floor() as i32 - 1;
    let hi = (mu + 12.0 * sd).ceil() as i32 + 1;
    let w = (lo..=hi).map(|n| {
        let m = |sig: f64| normal_mass((n as f64 - 0.5 - mu) / sig, (n as f64 + 0.5 - mu) / sig);
        0.85 * m(s) + 0.15 * m(sd)
    });
    Pmf::from_weights(lo, w).expect("pmf")
}

/// The truth of a bin: the average of its integer levels' laws.
fn truth_bin(levels: &BinLevels, b: usize, var: &impl Fn(f64) -> f64) -> Pmf {
    let pmfs: Vec<Pmf> = (levels.lo[b]..=levels.hi[b]).map(|l| truth_at(l as f64, var)).collect();
    let first = pmfs.iter().map(|p| p.first).min().expect("levels");
    let last = pmfs.iter().map(|p| p.last()).max().expect("levels");
    let mut acc = vec![0.0; (last - first + 1) as usize];
    for p in &pmfs {
        for (i, &x) in p.p.iter().enumerate() {
            acc[(p.first - first) as usize + i] += x;
        }
    }
    Pmf::from_weights(first, acc).expect("pmf")
}

pub(super) fn draw(p: &Pmf, rng: &mut ChaCha8Rng) -> i32 {
    let u: f64 = rng.random();
    let mut acc = 0.0;
    for (i, &x) in p.p.iter().enumerate() {
        acc += x;
        if u < acc {
            return p.first + i as i32;
        }
    }
    p.last()
}

pub(super) fn levels(nbins: usize, white: i32) -> BinLevels {
    let layout = crate::model::layout::SensorLayout {
        width: 8,
        height: 8,
        cfa: crate::model::layout::CfaPattern::Rggb,
        black: [BLACK as f32; 4],
        white: white as u16,
    };
    let l = BinLevels::new(&Binning::new(&layout, BW as u16), 0);
    assert!(l.len() >= nbins);
    l
}

/// Fold histograms with `count(b)` samples in bin `b`, each sample clamped like a sensor:
/// `clamp(level + n, 0, white) − level` at a random integer level of the bin.
fn sample_folds(
    levels: &BinLevels,
    var: &impl Fn(f64) -> f64,
    count: impl Fn(usize) -> usize,
    seed: u64,
) -> Vec<Vec<NoiseHistogram>> {
    sample_folds_of(levels, |l| truth_at(l, var), count, seed)
}

/// [`sample_folds`] for any law: `truth(level)` is the noise PMF at an integer level.
pub(super) fn sample_folds_of(
    levels: &BinLevels,
    truth: impl Fn(f64) -> Pmf,
    count: impl Fn(usize) -> usize,
    seed: u64,
) -> Vec<Vec<NoiseHistogram>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut folds = vec![vec![NoiseHistogram::default(); levels.len()]; FOLDS];
    for b in 0..levels.len() {
        let n = count(b);
        if n == 0 {
            continue;
        }
        let per_level: Vec<Pmf> = (levels.lo[b]..=levels.hi[b]).map(|l| truth(l as f64)).collect();
        for i in 0..n {
            let k = rng.random_range(0..per_level.len());
            let l = levels.lo[b] + k as i32;
            let noisy = (l + draw(&per_level[k], &mut rng)).clamp(0, levels.white);
            folds[i % FOLDS][b].add(noisy - l);
        }
    }
    folds
}

pub(super) fn refs(folds: &[Vec<NoiseHistogram>]) -> Vec<&[NoiseHistogram]> {
    folds.iter().map(|f| f.as_slice()).collect()
}

fn total(folds: &[Vec<NoiseHistogram>]) -> Vec<NoiseHistogram> {
    let mut t = vec![NoiseHistogram::default(); folds[0].len()];
    for f in folds {
        for (a, h) in t.iter_mut().zip(f) {
            a.merge(h);
        }
    }
    t
}

/// Mean JSD to the truth over bins `bins` for an estimate's bin models.
pub(super) fn mean_jsd(models: &[BinModel], truth: &[Pmf], bins: impl Iterator<Item = usize>) -> f64 {
    let v: Vec<f64> = bins.map(|b| jsd_pmf(&models[b].pmf(), &truth[b])).collect();
    v.iter().sum::<f64>() / v.len() as f64
}

pub(super) fn var_law(l: f64) -> f64 {
    (3.0 + 0.6 * (l - BLACK)).max(3.0)
}

#[test]
fn sparse_bins_beat_the_plain_histogram_by_far() {
    let lv = levels(150, 1023);
    let truth: Vec<Pmf> = (0..lv.len()).map(|b| truth_bin(&lv, b, &var_law)).collect();
    // 10–60 samples in every bin up to 150: far too few for a histogram of σ ≈ 5–17 DN.
    let folds = sample_folds(&lv, &var_law, |b| if b < 150 { 10 + (b * 37) % 50 } else { 0 }, 1);
    let est = estimate_position(&refs(&folds), &[], &lv, Pooling::Auto);
    let plain = plain_empirical(&total(&folds));
    let (je, jp) = (mean_jsd(&est.bins, &truth, 0..150), mean_jsd(&plain, &truth, 0..150));
    assert!(je < 0.25 * jp, "estimate {je:.4} vs plain {jp:.4}");
    assert!(je < 0.02, "estimate {je:.4}");
    assert!(est.report.pooling >= 256, "sparse data must pool: chose {} (shrink {})", est.report.pooling, est.shrink);
    let (plain_ce, chosen_ce) = est.report.gain_over_plain().expect("cross-validated");
    assert!(chosen_ce < plain_ce);
    // The pooled PMFs keep the truth's heavy tails (kurtosis ≈ 8, a Gaussian's is 3).
    let kurt = |p: &Pmf| {
        let (m, v) = p.moments();
        p.p.iter().enumerate().map(|(i, &q)| q * ((p.first + i as i32) as f64 - m).powi(4)).sum::<f64>() / (v * v)
    };
    let k: f64 = (60..140).map(|b| kurt(&est.bins[b].pmf())).sum::<f64>() / 80.0;
    let kt: f64 = (60..140).map(|b| kurt(&truth[b])).sum::<f64>() / 80.0;
    assert!((k / kt - 1.0).abs() < 0.25, "kurtosis {k:.2} vs truth {kt:.2}");
}

#[test]
fn dense_bins_stay_their_own_histograms() {
    let lv = levels(40, 1023);
    let truth: Vec<Pmf> = (0..lv.len()).map(|b| truth_bin(&lv, b, &var_law)).collect();
    let folds = sample_folds(&lv, &var_law, |b| if b < 40 { 200_000 } else { 0 }, 2);
    let est = estimate_position(&refs(&folds), &[], &lv, Pooling::Auto);
    let plain = plain_empirical(&total(&folds));
    let (je, jp) = (mean_jsd(&est.bins, &truth, 0..40), mean_jsd(&plain, &truth, 0..40));
    assert!(je <= 1.1 * jp, "estimate {je:.6} vs plain {jp:.6}");
    // Every bin's variance is its measured variance (no smoothing step moved it).
    for b in 0..40 {
        let [_, mv] = est.bins[b].measured.expect("measured");
        let (_, v) = est.bins[b].moments();
        assert!((v / mv - 1.0).abs() < 0.02, "bin {b}: {v} vs measured {mv}");
    }
}

#[test]
fn clipped_bins_never_inform_the_fill_and_the_law_continues_to_white() {
    // White at 500: the top bins of the measured range clip. Bins above 95 have no samples.
    let white = 500;
    let lv = levels(105, white);
    let folds = sample_folds(&lv, &var_law, |b| if b < 95 { 4000 } else { 0 }, 3);
    let est = estimate_position(&refs(&folds), &[], &lv, Pooling::Auto);
    let clipped = &est.report.clipped;
    // σ at the top ≈ 16 DN: bins within ~2σ of white are clipped, bins 5σ below are not.
    let sigma_top = var_law(white as f64).sqrt();
    for b in 0..95 {
        let gap = (white - lv.hi[b]) as f64 / sigma_top;
        let is = clipped.contains(&(b as u32));
        if gap < 1.5 {
            assert!(is, "bin {b} ({gap:.1}σ from white) must be flagged clipped");
        }
        if gap > 6.0 {
            assert!(!is, "bin {b} ({gap:.1}σ from white) is not clipped");
        }
    }
    // The law at every bin from the last unclipped one up follows the truth, not the shrunken
    // variance of the clipped bins.
    let first_clipped = *clipped.first().expect("some clipped bins") as usize;
    for b in first_clipped.saturating_sub(3)..lv.len() {
        let want = var_law(lv.center[b]);
        let got = est.report.law[b][1] as f64;
        assert!((got / want - 1.0).abs() < 0.08, "bin {b}: law variance {got:.1}, truth {want:.1}");
    }
    // Clipped bins in law mode hold the unclipped noise; synthesis clamps it.
    if est.report.clip_mode == ClipMode::Law {
        for b in clipped.iter().map(|&b| b as usize).filter(|&b| est.bins[b].filled()) {
            let (_, v) = est.bins[b].moments();
            let want = var_law(lv.center[b]);
            assert!((v / want - 1.0).abs() < 0.15, "clipped bin {b}: {v:.1} vs unclipped truth {want:.1}");
        }
    }
    // Filled bins above the data never fall towards white.
    let fills: Vec<f64> = (95..lv.len()).map(|b| est.bins[b].moments().1).collect();
    for w in fills.windows(2) {
        assert!(w[1] >= 0.99 * w[0], "{fills:?}");
    }
}

#[test]
fn fixed_pooling_and_too_few_folds_are_reported() {
    let lv = levels(20, 1023);
    let folds = sample_folds(&lv, &var_law, |b| if b < 20 { 100 } else { 0 }, 4);
    let fixed = estimate_position(&refs(&folds), &[], &lv, Pooling::Fixed(0));
    assert_eq!((fixed.report.choice, fixed.report.pooling), (Choice::Fixed, 0));
    // Pooling 0: measured bins are exactly their own histograms (plus the 1-sample prior).
    let t = total(&folds);
    let (m, v) = t[5].moments();
    let (pm, pv) = fixed.bins[5].moments();
    assert!((m - pm).abs() < 0.1 && (pv / v - 1.0).abs() < 0.05, "{m} {v} vs {pm} {pv}");
    let mut one = folds.clone();
    for f in one.iter_mut().skip(1) {
        f.iter_mut().for_each(|h| *h = NoiseHistogram::default());
    }
    let d = estimate_position(&refs(&one), &[], &lv, Pooling::Auto);
    assert_eq!((d.report.choice, d.report.pooling), (Choice::Default, DEFAULT_POOLING));
    // Deterministic.
    let again = estimate_position(&refs(&folds), &[], &lv, Pooling::Auto);
    assert_eq!(again, estimate_position(&refs(&folds), &[], &lv, Pooling::Auto));
}
