//! Shrinkage toward the law's Gaussian against known truth: a flat field at one level with few
//! frames (a few thousand samples in each of a handful of bins), drawn from a Gaussian, a
//! Gaussian mixture of kurtosis ≈ 8 and a Student-t of 4 degrees of freedom. The estimator with
//! its shrinkage is compared with the same estimator without it (`α = 0` only, the estimator
//! before shrinkage) and with the heteroscedastic Gaussian of the fitted law, by JSD to the truth.

use super::shrink::gauss_pmf;
use super::tests::{BLACK, levels, mean_jsd, refs, sample_folds_of, var_law};
use super::*;
use crate::math::special::normal_mass;

/// The measured bins: a flat field's few bins around one level.
const MEASURED: std::ops::Range<usize> = 30..35;

fn mean_at(l: f64) -> f64 {
    0.02 * (l - BLACK)
}

fn gaussian(l: f64) -> Pmf {
    let (mu, sd) = (mean_at(l), var_law(l).sqrt());
    let lo = (mu - 12.0 * sd).floor() as i32 - 1;
    let hi = (mu + 12.0 * sd).ceil() as i32 + 1;
    Pmf::from_weights(lo, (lo..=hi).map(|n| normal_mass((n as f64 - 0.5 - mu) / sd, (n as f64 + 0.5 - mu) / sd)))
        .expect("pmf")
}

/// 85 % N(0, s²) + 15 % N(0, (3s)²), variance `var_law`: kurtosis ≈ 8.
fn mixture(l: f64) -> Pmf {
    let v = var_law(l);
    let s = (v / (0.85 + 1.35)).sqrt();
    let mu = mean_at(l);
    let lo = (mu - 36.0 * s).floor() as i32 - 1;
    let hi = (mu + 36.0 * s).ceil() as i32 + 1;
    let m = |n: i32, sig: f64| normal_mass((n as f64 - 0.5 - mu) / sig, (n as f64 + 0.5 - mu) / sig);
    Pmf::from_weights(lo, (lo..=hi).map(|n| 0.85 * m(n, s) + 0.15 * m(n, 3.0 * s))).expect("pmf")
}

/// Student-t with 4 degrees of freedom scaled to variance `var_law` (cells integrated by
/// Simpson's rule on 8 panels; the mass beyond ±80 scales is below 10⁻⁷).
fn student4(l: f64) -> Pmf {
    let nu = 4.0;
    let scale = (var_law(l) * (nu - 2.0) / nu).sqrt();
    let mu = mean_at(l);
    let pdf = |x: f64| (1.0 + ((x - mu) / scale).powi(2) / nu).powf(-(nu + 1.0) / 2.0);
    let cell = |n: i32| {
        let (a, h) = (n as f64 - 0.5, 1.0 / 8.0);
        let mut s = pdf(a) + pdf(a + 1.0);
        for k in 1..8 {
            s += if k % 2 == 1 { 4.0 } else { 2.0 } * pdf(a + k as f64 * h);
        }
        s * h / 3.0
    };
    let lo = (mu - 80.0 * scale).floor() as i32;
    let hi = (mu + 80.0 * scale).ceil() as i32;
    Pmf::from_weights(lo, (lo..=hi).map(cell)).expect("pmf")
}

/// A bin's truth: the average of its integer levels' laws.
fn truth_bin(lv: &BinLevels, b: usize, truth: &impl Fn(f64) -> Pmf) -> Pmf {
    let pmfs: Vec<Pmf> = (lv.lo[b]..=lv.hi[b]).map(|l| truth(l as f64)).collect();
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

/// The value below which a PMF holds `q` of its mass, interpolated within the cell.
fn quantile(p: &Pmf, q: f64) -> f64 {
    let mut acc = 0.0;
    for (i, &x) in p.p.iter().enumerate() {
        if acc + x >= q {
            return p.first as f64 + i as f64 - 0.5 + (q - acc) / x.max(1e-300);
        }
        acc += x;
    }
    p.last() as f64 + 0.5
}

struct Outcome {
    /// The Gaussian's weight chosen.
    shrink: f64,
    /// Mean JSD to the truth over the measured bins: shrunk, unshrunk, the law's Gaussian.
    jsd: [f64; 3],
    /// Over the measured bins, the worst ratio to the truth of the 0.1 % and 99.9 % quantiles'
    /// distance from the mean (the larger of ratio and its inverse), and of the variance.
    tail: f64,
    var: f64,
}

/// A flat field: 4 000–5 000 samples in each measured bin (about 20 000 in all), 4 folds.
fn run(truth: impl Fn(f64) -> Pmf, seed: u64) -> Outcome {
    let lv = levels(MEASURED.end, 1023);
    let folds = sample_folds_of(&lv, &truth, |b| if MEASURED.contains(&b) { 4000 + 250 * (b % 5) } else { 0 }, seed);
    let shrunk = estimate_position_among(&refs(&folds), &[], &lv, Pooling::Auto, &SHRINK_CANDIDATES);
    let plain = estimate_position_among(&refs(&folds), &[], &lv, Pooling::Auto, &[0.0]);
    let truths: Vec<Pmf> = (0..lv.len()).map(|b| truth_bin(&lv, b, &truth)).collect();
    let hg: Vec<BinModel> = shrunk
        .report
        .law
        .iter()
        .map(|&[m, v]| {
            let p = gauss_pmf(m as f64, v as f64, lv.reach());
            BinModel::estimated(&p, 0, BinSource::Filled, None, false)
        })
        .collect();
    let jsd = [
        mean_jsd(&shrunk.bins, &truths, MEASURED),
        mean_jsd(&plain.bins, &truths, MEASURED),
        mean_jsd(&hg, &truths, MEASURED),
    ];
    let (mut tail, mut var) = (1.0f64, 1.0f64);
    for b in MEASURED {
        let (got, want) = (shrunk.bins[b].pmf(), &truths[b]);
        let ((gm, gv), (wm, wv)) = (got.moments(), want.moments());
        for q in [1e-3, 1.0 - 1e-3] {
            let r = (quantile(&got, q) - gm) / (quantile(want, q) - wm);
            tail = tail.max(r).max(1.0 / r);
        }
        var = var.max(gv / wv).max(wv / gv);
    }
    Outcome { shrink: shrunk.shrink, jsd, tail, var }
}

/// Gaussian noise, few frames: the pool is the histogram of ~20 000 samples, whose sampling
/// noise the Gaussian does not have. The shrunk pack must come close to the law's Gaussian (the
/// heteroscedastic Gaussian model, right here by construction), and well below the unshrunk
/// estimator, which (α = 0 always) stays at the histogram's sampling noise.
#[test]
fn a_gaussian_sensor_with_few_frames_shrinks_to_the_gaussian() {
    for seed in [11, 12, 13] {
        let o = run(gaussian, seed);
        let [shrunk, plain, hg] = o.jsd;
        eprintln!("gaussian seed {seed}: α {} JSD shrunk {shrunk:.2e} unshrunk {plain:.2e} HG {hg:.2e}", o.shrink);
        assert!(o.shrink >= 0.75, "seed {seed}: α {}", o.shrink);
        assert!(shrunk < 0.5 * plain, "seed {seed}: shrunk {shrunk:.2e} vs unshrunk {plain:.2e}");
        assert!(shrunk < 1.5 * hg + 2e-5, "seed {seed}: shrunk {shrunk:.2e} vs HG {hg:.2e}");
        assert!(o.tail < 1.1 && o.var < 1.05, "seed {seed}: tails {:.3} variance {:.3}", o.tail, o.var);
    }
}

/// Heavy tails, same few frames: the Gaussian would thin the tails, and the held-out frames'
/// tail samples say so, so the weight stays near 0 and the tails stay the data's.
#[test]
fn heavy_tails_keep_their_pool() {
    for (name, truth) in [("mixture", mixture as fn(f64) -> Pmf), ("student-t 4", student4)] {
        for seed in [21, 22, 23] {
            let o = run(truth, seed);
            let [shrunk, plain, hg] = o.jsd;
            eprintln!(
                "{name} seed {seed}: α {} JSD shrunk {shrunk:.2e} unshrunk {plain:.2e} HG {hg:.2e} tails {:.3} var {:.3}",
                o.shrink, o.tail, o.var
            );
            assert!(o.shrink <= 0.25, "{name} seed {seed}: α {}", o.shrink);
            assert!(o.tail < 1.25, "{name} seed {seed}: tails {:.3}", o.tail);
            // A Student-t of 4 degrees of freedom has no fourth moment: its sample variance
            // wanders by several per cent at 20 000 samples, shrunk or not.
            assert!(o.var < 1.15, "{name} seed {seed}: variance {:.3}", o.var);
            // Never worse than the unshrunk estimator, and far from the Gaussian's shape error.
            assert!(shrunk <= 1.1 * plain, "{name} seed {seed}: shrunk {shrunk:.2e} vs unshrunk {plain:.2e}");
            assert!(shrunk < 0.5 * hg, "{name} seed {seed}: shrunk {shrunk:.2e} vs HG {hg:.2e}");
        }
    }
}
