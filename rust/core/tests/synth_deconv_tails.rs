//! The deconvolution of the structured offsets out of a bin's PMF (synth/structure.rs) depends on
//! the noise, not on how far the stored PMF's tail reaches: a bin with and without a tail of 10⁻⁶
//! of its mass (a pack's tail cut at 2⁻²⁰ of the largest cell, or floor counts reaching far out)
//! deconvolves to the same PMF, and the deconvolved PMF convolved back with the offsets' kernel
//! still gives the measured one; a tail cut short is not taken for the clamp's pile.

use noisecal_core::math::special::erfc;
use noisecal_core::metrics::jsd;
use noisecal_core::model::pack::{BinModel, BinSource};
use noisecal_core::model::pmf::Pmf;
use noisecal_core::model::structure::{Components, IsoStructure, OffsetDistribution, QUANTILES};
use noisecal_core::synth::structure::StructureSampler;

/// Row offsets (both parities) Gaussian of SD `sd`, stored as a quantile function.
fn rows(sd: f64) -> StructureSampler {
    let quantiles: Vec<f32> = (0..QUANTILES)
        .map(|i| {
            let u = (i as f64 + 0.5) / QUANTILES as f64;
            let (mut lo, mut hi) = (-8.0f64, 8.0f64);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if 1.0 - 0.5 * erfc(mid / std::f64::consts::SQRT_2) < u {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            (sd * 0.5 * (lo + hi)) as f32
        })
        .collect();
    let dist =
        OffsetDistribution { quantiles, count: 100_000, measured_var: sd * sd, sampling_var: 0.0, significant: true };
    let st = IsoStructure {
        iso: 3200,
        rows: [Some(dist.clone()), Some(dist)],
        columns: [None, None],
        frames: None,
        frames_used: 10,
        fpn: None,
    };
    StructureSampler::new(&st, Components::ALL).expect("significant rows")
}

/// `a ∗ b` (first index of the result: `a0 + b0`).
fn convolve(a0: i32, a: &[f64], b0: i32, b: &[f64]) -> Pmf {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, &x) in a.iter().enumerate() {
        for (j, &y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    Pmf { first: a0 + b0, p: out }
}

/// The pixel noise without the offsets: skewed (a Gaussian mixture), so the narrowed start of
/// the deconvolution is not already the answer and the iterations matter.
fn pixel_noise() -> Pmf {
    let g = |x: f64, m: f64, s: f64| (-(x - m).powi(2) / (2.0 * s * s)).exp() / s;
    let w: Vec<f64> = (-200..=300).map(|n| 0.7 * g(n as f64, 0.0, 20.0) + 0.3 * g(n as f64, 45.0, 25.0)).collect();
    Pmf::from_weights(-200, w).expect("mass")
}

/// `p` as a pack stores it: cells below 2⁻²⁰ of the largest cut from both ends.
fn stored_cut(p: &Pmf) -> Pmf {
    let top = p.p.iter().copied().fold(0.0, f64::max);
    let lo = p.p.iter().position(|&x| x >= top / f64::from(1u32 << 20)).expect("cell");
    let hi = p.p.iter().rposition(|&x| x >= top / f64::from(1u32 << 20)).expect("cell");
    Pmf::from_weights(p.first + lo as i32, p.p[lo..=hi].iter().copied()).expect("mass")
}

/// `p` with `mass` spread evenly over `reach` cells past each end.
fn with_tail(p: &Pmf, mass: f64, reach: usize) -> Pmf {
    let cell = mass / (2 * reach) as f64;
    let mut w = vec![cell; reach];
    w.extend(p.p.iter().map(|x| x * (1.0 - mass)));
    w.extend(std::iter::repeat_n(cell, reach));
    Pmf::from_weights(p.first - reach as i32, w).expect("mass")
}

fn bin(p: &Pmf) -> BinModel {
    BinModel::estimated(p, 1_000_000, BinSource::Measured, None, false)
}

/// Two PMFs on one grid from `lo` to `hi`.
fn grid(p: &Pmf, lo: i32, hi: i32) -> Vec<f64> {
    (lo..=hi).map(|n| p.at(n)).collect()
}

fn total_variation(a: &Pmf, b: &Pmf) -> f64 {
    let (lo, hi) = (a.first.min(b.first), a.last().max(b.last()));
    0.5 * (lo..=hi).map(|n| (a.at(n) - b.at(n)).abs()).sum::<f64>()
}

#[test]
fn a_negligible_tail_does_not_change_the_deconvolved_pmf() {
    let sampler = rows(15.0);
    let (k0, kernel) = sampler.kernel(0);
    let q = pixel_noise();
    let measured = stored_cut(&convolve(k0, &kernel, q.first, &q.p));
    // Floor-count tails: 10⁻⁶ of the mass over 400 cells past each end (about 1.3 counts in
    // 2³⁰ a cell), the support three times the measured one's.
    let tailed = with_tail(&measured, 1e-6, 400);
    let cut = sampler.deconvolved(0, &[bin(&measured)])[0].pmf();
    let long = sampler.deconvolved(0, &[bin(&tailed)])[0].pmf();
    // With the iterations and the start's moments set by the whole support, the two differed by
    // 9.9·10⁻⁴ (141 iterations against 40); from the support less 10⁻⁵ at each end, 2.1·10⁻⁴
    // (170 against 169: the rest is Richardson–Lucy, short of convergence, run on the longer
    // support).
    let tv = total_variation(&cut, &long);
    eprintln!("total variation cut vs tailed: {tv:.3e}");
    assert!(tv < 4e-4, "the tail changed the deconvolved PMF by {tv:.3e}");
}

#[test]
fn the_deconvolved_pmf_convolved_back_gives_the_measured_one() {
    let sampler = rows(15.0);
    let (k0, kernel) = sampler.kernel(0);
    let q = pixel_noise();
    let measured = stored_cut(&convolve(k0, &kernel, q.first, &q.p));
    for (name, p) in [("cut", measured.clone()), ("tailed", with_tail(&measured, 1e-6, 400))] {
        let d = sampler.deconvolved(0, &[bin(&p)])[0].pmf();
        let back = convolve(k0, &kernel, d.first, &d.p);
        let kept = convolve(k0, &kernel, p.first, &p.p);
        let (lo, hi) = (measured.first - 50, measured.last() + 50);
        let after = jsd(&grid(&back, lo, hi), &grid(&p, lo, hi));
        let twice = jsd(&grid(&kept, lo, hi), &grid(&p, lo, hi));
        let (_, dv) = d.moments();
        let (_, qv) = q.moments();
        eprintln!("{name}: JSD back {after:.3e}, kept {twice:.3e}, variance {dv:.1} truth {qv:.1}");
        // The offsets counted twice (the PMF kept as measured) leave a JSD near 4·10⁻³; the
        // deconvolution brings it three orders of magnitude lower.
        assert!(after < 1e-5, "{name}: re-convolved JSD {after:.3e} (kept {twice:.3e})");
        assert!(twice > 1e-3, "{name}: the kernel is too narrow to tell ({twice:.3e})");
        assert!((dv / qv - 1.0).abs() < 0.01, "{name}: variance {dv:.2} against {qv:.2}");
        // The shape, not just the variance: the deconvolved PMF is the pixel noise.
        let tv = total_variation(&d, &q);
        assert!(tv < 0.02, "{name}: total variation from the pixel noise {tv:.3e}");
    }
}

/// A bin flagged clipped (its samples reached a clip) whose stored tail was cut where the end
/// cell still holds a few 10⁻⁶ (as sensor 17 of the random family had them at ISO 3200 and 4000)
/// has no pile there: it deconvolves exactly as the same bin unflagged, on either end (the end
/// cell's mass alone, at least 10⁻⁶, took it for a pile and folded mass past a clip the sensor
/// does not have).
#[test]
fn a_tail_cut_short_is_not_taken_for_a_clamp_pile() {
    let sampler = rows(0.7);
    let (k0, kernel) = sampler.kernel(0);
    for sd in [1.5, 2.0, 3.0, 6.0] {
        let g: Vec<f64> = (-60..=60).map(|n| (-(n as f64 + 0.3).powi(2) / (2.0 * sd * sd)).exp()).collect();
        let q = Pmf::from_weights(-60, g).expect("mass");
        let full = convolve(k0, &kernel, q.first, &q.p);
        // Cut both tails at the outermost cells holding at least 2·10⁻⁶.
        let lo = full.p.iter().position(|&x| x >= 2e-6).expect("cell");
        let hi = full.p.iter().rposition(|&x| x >= 2e-6).expect("cell");
        let cut = Pmf::from_weights(full.first + lo as i32, full.p[lo..=hi].iter().copied()).expect("mass");
        let flagged = BinModel { clipped: true, ..bin(&cut) };
        let plain = bin(&cut);
        let a = sampler.deconvolved(0, &[flagged])[0].pmf();
        let b = sampler.deconvolved(0, &[plain])[0].pmf();
        let tv = total_variation(&a, &b);
        assert!(tv == 0.0, "sd {sd}: a cut tail folded as a pile ({tv:.3e} from the unclipped result)");
    }
}
