//! Fast scalar samplers used per pixel: open uniforms, Student-t by chi-square from uniforms,
//! exact Poisson (inversion below 10, PTRS up to a threshold) and a Gaussian approximation above.
//! None of them allocates.

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

/// SplitMix64 finaliser: a strong 64-bit mix, used to derive seeds and the fixed pixel maps.
#[inline]
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Uniform on the open interval (0, 1).
#[inline]
pub(crate) fn uniform_open<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    ((rng.next_u64() >> 11) as f64 + 0.5) * (1.0 / (1u64 << 53) as f64)
}

/// Standard normal draw.
#[inline]
pub(crate) fn normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    StandardNormal.sample(rng)
}

/// Round half up and clamp to `[0, hi]` (values are non-negative after the clamp, so this is
/// `f64::round` there; written out because `round` is a libm call on baseline x86-64).
#[inline]
pub(crate) fn round_clamp(a: f64, hi: f64) -> f64 {
    if a <= 0.0 { 0.0 } else { ((a + 0.5) as u64 as f64).min(hi) }
}

/// `floor` for values well inside the i64 range.
#[inline]
fn floor_fast(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

/// Unit-variance Student-t noise with `dof` > 2 degrees of freedom:
/// `z · sqrt((ν − 2) / χ²_ν)` with `χ²_ν = 2·Gamma(ν/2)` drawn by Marsaglia–Tsang (a normal
/// and a uniform; a logarithm only in ~2 % of draws).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StudentT {
    nu: f64,
    d: f64,
    c: f64,
}

impl StudentT {
    /// `dof` must be ≥ 3 (checked by the model).
    pub(crate) fn new(dof: f64) -> Self {
        let d = dof / 2.0 - 1.0 / 3.0;
        Self { nu: dof, d, c: 1.0 / (9.0 * d).sqrt() }
    }

    /// Gamma(ν/2, 1) draw.
    #[inline]
    fn gamma<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        loop {
            let x = normal(rng);
            let v = 1.0 + self.c * x;
            if v <= 0.0 {
                continue;
            }
            let v = v * v * v;
            let u = uniform_open(rng);
            let x2 = x * x;
            if u < 1.0 - 0.0331 * x2 * x2 {
                return self.d * v;
            }
            if u.ln() < 0.5 * x2 + self.d * (1.0 - v + v.ln()) {
                return self.d * v;
            }
        }
    }

    /// One unit-variance draw.
    #[inline]
    pub(crate) fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        let z = normal(rng);
        let g = self.gamma(rng);
        z * ((self.nu - 2.0) / (2.0 * g)).sqrt()
    }
}

/// Unit-variance noise: Gaussian (`None`) or Student-t.
#[inline]
pub(crate) fn unit_noise<R: Rng + ?Sized>(t: Option<&StudentT>, rng: &mut R) -> f64 {
    match t {
        Some(t) => t.sample(rng),
        None => normal(rng),
    }
}

/// ln Γ(x) for x ≥ 1 (Stirling series with upward shift; as in numpy's `random_loggam`).
fn ln_gamma(x: f64) -> f64 {
    const A: [f64; 10] = [
        8.333333333333333e-02,
        -2.777777777777778e-03,
        7.936507936507937e-04,
        -5.952380952380952e-04,
        8.417508417508418e-04,
        -1.917526917526918e-03,
        6.41025641025641e-03,
        -2.955065359477124e-02,
        1.796443723688307e-01,
        -1.39243221690590e+00,
    ];
    if x == 1.0 || x == 2.0 {
        return 0.0;
    }
    let mut x0 = x;
    let mut n = 0;
    if x <= 7.0 {
        n = (7.0 - x).floor() as i32;
        x0 = x + n as f64;
    }
    let x2 = 1.0 / (x0 * x0);
    let mut gl0 = A[9];
    for k in (0..9).rev() {
        gl0 = gl0 * x2 + A[k];
    }
    let mut gl = gl0 / x0 + 0.5 * (2.0 * std::f64::consts::PI).ln() + (x0 - 0.5) * x0.ln() - x0;
    if x <= 7.0 {
        for _ in 0..n {
            gl -= (x0 - 1.0).ln();
            x0 -= 1.0;
        }
    }
    gl
}

/// Size of the ln k! table.
const LN_FACT_TABLE: usize = 2048;

/// ln k! (table below 2048, Stirling series above).
#[inline]
fn ln_factorial(k: f64) -> f64 {
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    if k < LN_FACT_TABLE as f64 {
        let t = TABLE.get_or_init(|| {
            let mut t = vec![0.0f64; LN_FACT_TABLE];
            for i in 1..LN_FACT_TABLE {
                t[i] = t[i - 1] + (i as f64).ln();
            }
            t
        });
        t[k as usize]
    } else {
        ln_gamma(k + 1.0)
    }
}

/// Poisson draw with mean `lambda`: exact (inversion below 10, Hörmann's PTRS up to
/// `gauss_above`), and `round(N(λ, λ))` clamped at 0 from `gauss_above` on.
#[inline]
pub(crate) fn poisson<R: Rng + ?Sized>(lambda: f64, gauss_above: f64, rng: &mut R) -> f64 {
    if lambda <= 0.0 {
        0.0
    } else if lambda < 10.0 {
        poisson_small(lambda, rng)
    } else if lambda < gauss_above {
        poisson_ptrs(lambda, rng)
    } else {
        round_clamp(lambda + lambda.sqrt() * normal(rng), f64::MAX)
    }
}

/// Poisson by inversion with sequential search from 0: one uniform, about λ steps (λ < 10).
#[inline]
fn poisson_small<R: Rng + ?Sized>(lambda: f64, rng: &mut R) -> f64 {
    let u = uniform_open(rng);
    let mut p = (-lambda).exp();
    let mut s = p;
    let mut k = 0.0;
    while u > s && k < 200.0 {
        k += 1.0;
        p *= lambda / k;
        s += p;
    }
    k
}

/// PTRS: W. Hörmann, "The transformed rejection method for generating Poisson random
/// variables", 1993. Valid for λ ≥ 10.
fn poisson_ptrs<R: Rng + ?Sized>(lam: f64, rng: &mut R) -> f64 {
    let slam = lam.sqrt();
    let b = 0.931 + 2.53 * slam;
    let a = -0.059 + 0.02483 * b;
    let vr = 0.9277 - 3.6224 / (b - 2.0);
    loop {
        let u = uniform_open(rng) - 0.5;
        let v = uniform_open(rng);
        let us = 0.5 - u.abs();
        let k = floor_fast((2.0 * a / us + b) * u + lam + 0.43);
        if us >= 0.07 && v <= vr {
            return k;
        }
        if k < 0.0 || (us < 0.013 && v > us) {
            continue;
        }
        // Slow path (about a third of the draws): the logarithms are only needed here.
        let invalpha = 1.1239 + 1.1328 / (b - 3.4);
        if (v * invalpha / (a / (us * us) + b)).ln() <= -lam + k * lam.ln() - ln_factorial(k) {
            return k;
        }
    }
}

/// An approximately standard-normal number from 64 hash bits (Irwin–Hall of four 16-bit
/// uniforms, rescaled to unit variance; bounded by ±3.46). Used for fixed pixel maps.
#[inline]
pub(crate) fn hashed_unit(h: u64) -> f32 {
    let s = (h & 0xFFFF) + ((h >> 16) & 0xFFFF) + ((h >> 32) & 0xFFFF) + (h >> 48);
    // Sum of four U(0,1): mean 2, variance 1/3.
    let u = (s as f32 + 2.0) / 65536.0;
    (u - 2.0) * 3.0f32.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn moments(xs: &[f64]) -> (f64, f64, f64) {
        let n = xs.len() as f64;
        let m = xs.iter().sum::<f64>() / n;
        let v = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n;
        let k = xs.iter().map(|x| (x - m).powi(4)).sum::<f64>() / n / (v * v) - 3.0;
        (m, v, k)
    }

    #[test]
    fn poisson_matches_mean_and_variance_in_every_regime() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for &lam in &[0.3, 3.0, 9.9, 10.0, 37.5, 400.0, 2500.0] {
            let n = 200_000;
            let xs: Vec<f64> = (0..n).map(|_| poisson(lam, 1000.0, &mut rng)).collect();
            let (m, v, _) = moments(&xs);
            // Standard errors: mean √(λ/n); variance ≈ λ·√(2/n).
            assert!((m - lam).abs() < 5.0 * (lam / n as f64).sqrt(), "λ={lam}: mean {m}");
            assert!((v / lam - 1.0).abs() < 0.02, "λ={lam}: variance {v}");
            assert!(xs.iter().all(|&x| x >= 0.0 && x.fract() == 0.0));
        }
        // Exact PMF at λ = 3: P(0) = e^-3, P(3) = 4.5 e^-3.
        let xs: Vec<f64> = (0..400_000).map(|_| poisson(3.0, 1000.0, &mut rng)).collect();
        let p0 = xs.iter().filter(|&&x| x == 0.0).count() as f64 / 4e5;
        let p3 = xs.iter().filter(|&&x| x == 3.0).count() as f64 / 4e5;
        assert!((p0 - (-3.0f64).exp()).abs() < 0.003, "{p0}");
        assert!((p3 - 4.5 * (-3.0f64).exp()).abs() < 0.004, "{p3}");
        // PTRS at λ = 20.5 and 1500.5 (threshold raised) vs the exact PMF.
        for (lam, thr) in [(20.5f64, 1000.0), (1500.5, 1e9)] {
            let xs: Vec<f64> = (0..400_000).map(|_| poisson(lam, thr, &mut rng)).collect();
            let (m, v, _) = moments(&xs);
            assert!((m - lam).abs() < 5.0 * (lam / 4e5).sqrt(), "λ={lam}: mean {m}");
            assert!((v / lam - 1.0).abs() < 0.015, "λ={lam}: variance {v}");
            let mode = lam.floor();
            let p = xs.iter().filter(|&&x| x == mode).count() as f64 / 4e5;
            let exact = (-lam + mode * lam.ln() - ln_gamma(mode + 1.0)).exp();
            assert!((p - exact).abs() < 4.0 * (exact / 4e5).sqrt(), "λ={lam}: P(mode) {p} vs {exact}");
            assert!(xs.iter().all(|&x| x >= 0.0 && x.fract() == 0.0));
        }
    }

    #[test]
    fn student_t_has_unit_variance_and_the_right_tails() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        for &dof in &[0.0, 7.0, 12.0, 30.5] {
            let t = StudentT::new(dof);
            let t = (dof > 0.0).then_some(&t);
            let xs: Vec<f64> = (0..400_000).map(|_| unit_noise(t, &mut rng)).collect();
            let (m, v, k) = moments(&xs);
            let want_k = if dof == 0.0 { 0.0 } else { 6.0 / (dof - 4.0) };
            assert!(m.abs() < 0.01, "dof {dof}: mean {m}");
            assert!((v - 1.0).abs() < 0.03, "dof {dof}: variance {v}");
            assert!((k - want_k).abs() < 0.25 + 0.2 * want_k, "dof {dof}: kurtosis {k} vs {want_k}");
        }
        // dof 3: P(|t| > 3·sd) for the unit-variance t3 is P(|T3| > 3√3) = 0.0138.
        let t3 = StudentT::new(3.0);
        let xs: Vec<f64> = (0..400_000).map(|_| unit_noise(Some(&t3), &mut rng)).collect();
        let tail = xs.iter().filter(|x| x.abs() > 3.0).count() as f64 / 4e5;
        assert!((tail - 0.0138).abs() < 0.0015, "{tail}");
    }

    #[test]
    fn fast_rounding_matches_std() {
        for &x in &[-3.2, -0.5, 0.0, 0.49, 0.5, 1.5, 2.5, 1022.7, 1e6 + 0.5, 5000.0] {
            assert_eq!(round_clamp(x, 4095.0), f64::round(x).clamp(0.0, 4095.0), "{x}");
        }
        for &x in &[-3.2, -3.0, -0.1, 0.0, 0.9, 7.0, 12.5] {
            assert_eq!(floor_fast(x), x.floor(), "{x}");
        }
    }

    #[test]
    fn ln_gamma_is_accurate() {
        let mut f = 1.0f64;
        for k in 1..30 {
            f *= k as f64;
            assert!((ln_gamma(k as f64 + 1.0) - f.ln()).abs() < 1e-9, "{k}");
            assert!((ln_factorial(k as f64) - f.ln()).abs() < 1e-9, "{k}");
        }
        for k in [2000.0, 2047.0] {
            assert!((ln_factorial(k) - ln_gamma(k + 1.0)).abs() < 1e-7 * ln_gamma(k + 1.0), "{k}");
        }
    }

    #[test]
    fn hashed_unit_is_standardised() {
        let xs: Vec<f64> = (0..200_000u64).map(|i| hashed_unit(mix64(i)) as f64).collect();
        let (m, v, _) = moments(&xs);
        assert!(m.abs() < 0.01 && (v - 1.0).abs() < 0.02, "{m} {v}");
    }
}
