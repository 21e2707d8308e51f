//! The variance of a normal variable clamped at a floor, and its inverse: what a dark frame's
//! spread measures when its black level sits within a few SDs of the code the output clamps at
//! (10-bit phones at high ISO), and the spread before the clamp.
//!
//! `Y = max(X, L)` with `X ~ N(μ, σ²)` and headroom `D = μ − L`: with `t = D/σ`,
//! `Var Y / σ² = (t² + 1)·Φ(t) + t·φ(t) − (t·Φ(t) + φ(t))²`, 1 far above the floor, `½ − 1/(2π)`
//! (0.341) with the black level on it.

use crate::math::special::erfc;

/// Headroom (in SDs of the unclamped spread) below which [`unclamped_variance`] declines: at
/// `t = 0` half the samples sit on the floor, and the shape of the other half (not only its
/// width) decides the answer.
pub const MIN_HEADROOM_SD: f64 = 0.0;

/// `Var(max(X, L)) / σ²` for `X ~ N(L + t·σ, σ²)`.
pub fn clamped_variance_ratio(t: f64) -> f64 {
    // Beyond 8 SDs the clamp holds under 10⁻¹⁵ of the mass (and `t²` would cancel).
    if t > 8.0 {
        return 1.0;
    }
    let cdf = 0.5 * erfc(-t / std::f64::consts::SQRT_2);
    let pdf = (-0.5 * t * t).exp() / (2.0 * std::f64::consts::PI).sqrt();
    let mean = t * cdf + pdf;
    ((t * t + 1.0) * cdf + t * pdf - mean * mean).max(0.0)
}

/// The variance `σ²` of the normal spread whose clamp at a floor `headroom` DN below its mean
/// measures `measured` (DN²): the root of `σ²·r(headroom/σ) = measured`
/// ([`clamped_variance_ratio`]), by bisection on `σ²` in `[measured, measured / r(0)]`. `None`
/// when the mean is not above the floor (`headroom ≤ 0`: half the samples or more on it) or
/// the inputs are not finite and positive. A normal law is assumed: for heavy-tailed read
/// noise it corrects less than the clamp took (a Student-t's clamped share lies farther out).
pub fn unclamped_variance(measured: f64, headroom: f64) -> Option<f64> {
    if !(measured.is_finite() && measured > 0.0 && headroom.is_finite() && headroom > MIN_HEADROOM_SD) {
        return None;
    }
    let clamped = |var: f64| var * clamped_variance_ratio(headroom / var.sqrt());
    let (mut lo, mut hi) = (measured, measured / clamped_variance_ratio(0.0));
    if clamped(lo) >= measured {
        return Some(measured);
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if clamped(mid) < measured {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(0.5 * (lo + hi))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    fn normal(rng: &mut ChaCha8Rng) -> f64 {
        StandardNormal.sample(rng)
    }

    #[test]
    fn the_ratio_has_its_known_values() {
        assert!((clamped_variance_ratio(0.0) - (0.5 - 0.5 / std::f64::consts::PI)).abs() < 1e-6);
        assert!((clamped_variance_ratio(8.0) - 1.0).abs() < 1e-6);
        // Rises with the headroom (the bisection's bracket relies on it).
        let r: Vec<f64> = (0..=80).map(|k| clamped_variance_ratio(k as f64 * 0.1)).collect();
        assert!(r.windows(2).all(|w| w[1] >= w[0] - 1e-12), "{r:?}");
    }

    /// Known truth in: integer dark codes `round(black + σ·z)` clamped at 0, measured as a dark
    /// burst measures its temporal variance (half the variance of two frames' difference), for
    /// the headrooms random sensor 19's dark steps have (10 bits, black 13.5 DN: 0.70 SD at ISO
    /// 500, 0.22 SD at ISO 1600). The clamp takes 36–57 % of the variance; the inverse gives it
    /// back within 2 %. A wrong implementation (the clamped variance as it is, the old read
    /// term) scores 0.64 and 0.43 of the truth.
    #[test]
    fn the_spread_before_the_clamp_comes_back() {
        let mut rng = ChaCha8Rng::seed_from_u64(19);
        for (sd, black) in [(19.5f64, 13.5f64), (62.2, 13.5), (4.0, 13.5), (30.0, 40.0)] {
            let n = 200_000;
            let frame = |rng: &mut ChaCha8Rng| -> Vec<f64> {
                (0..n).map(|_| (black + sd * normal(rng)).round().max(0.0)).collect()
            };
            let (a, b) = (frame(&mut rng), frame(&mut rng));
            let d: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
            let m = d.iter().sum::<f64>() / n as f64;
            let measured = d.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n as f64 / 2.0;
            // The codes' own rounding adds 1/12 DN² to the truth.
            let truth = sd * sd + 1.0 / 12.0;
            let got = unclamped_variance(measured, black).expect("headroom above the floor");
            let t = black / sd;
            eprintln!(
                "σ {sd} headroom {t:.2} SD: measured {:.3}, corrected {:.3} of the truth",
                measured / truth,
                got / truth
            );
            assert!((got / truth - 1.0).abs() < 0.02, "σ {sd}: {got} against {truth} (measured {measured})");
            if t < 1.0 {
                assert!(measured / truth < 0.7, "the clamp must show at {t:.2} SD: {measured} against {truth}");
            }
        }
    }

    #[test]
    fn no_headroom_no_answer() {
        assert_eq!(unclamped_variance(100.0, 0.0), None);
        assert_eq!(unclamped_variance(100.0, -3.0), None);
        assert_eq!(unclamped_variance(0.0, 10.0), None);
        assert_eq!(unclamped_variance(f64::NAN, 10.0), None);
        // Far above the floor the clamp takes nothing.
        let v = unclamped_variance(100.0, 200.0).expect("headroom");
        assert!((v - 100.0).abs() < 1e-6, "{v}");
    }
}
