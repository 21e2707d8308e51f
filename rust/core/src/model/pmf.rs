//! Operations on integer-grid PMFs: normalised shapes (paper Eq. 5) rescaled to a new mean and
//! variance (Eq. 6), back on the integer grid.

use crate::math::round::floor_i32;

/// A probability mass function over `first, first + 1, …`.
#[derive(Debug, Clone, PartialEq)]
pub struct Pmf {
    pub first: i32,
    pub p: Vec<f64>,
}

impl Pmf {
    /// From counts or weights (normalised here). Returns `None` when the total is zero.
    pub fn from_weights(first: i32, w: impl IntoIterator<Item = f64>) -> Option<Self> {
        let p: Vec<f64> = w.into_iter().collect();
        let t: f64 = p.iter().sum();
        if t.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        Some(Self { first, p: p.into_iter().map(|x| x / t).collect() }.trimmed())
    }

    pub fn moments(&self) -> (f64, f64) {
        crate::model::histogram::moments(self.first, self.p.iter().copied())
    }

    pub fn last(&self) -> i32 {
        self.first + self.p.len() as i32 - 1
    }

    /// Probability of value `n`.
    pub fn at(&self, n: i32) -> f64 {
        let i = n - self.first;
        if i < 0 { 0.0 } else { self.p.get(i as usize).copied().unwrap_or(0.0) }
    }

    /// Drops zero tails.
    pub fn trimmed(self) -> Self {
        let Some(lo) = self.p.iter().position(|&c| c > 0.0) else {
            return Self { first: 0, p: vec![1.0] };
        };
        let hi = self.p.iter().rposition(|&c| c > 0.0).unwrap_or(lo);
        Self { first: self.first + lo as i32, p: self.p[lo..=hi].to_vec() }
    }

    /// Rescales this PMF's shape to mean `mu` and variance `var` on the integer grid (Eq. 5–6).
    ///
    /// The PMF is read as a piecewise-uniform density (each integer a unit cell), mapped
    /// affinely, and integrated back over unit cells. The affine factor accounts for the 1/12
    /// variance that cells add (Sheppard), so the result's discrete variance is close to `var`.
    pub fn rescaled(&self, mu: f64, var: f64) -> Pmf {
        let (m_s, v_s) = self.moments();
        let v_cont = v_s + 1.0 / 12.0;
        let target_cont = (var - 1.0 / 12.0).max(1e-4);
        let a = (target_cont / v_cont).sqrt();
        // source cell [n-0.5, n+0.5] maps to [mu + a(n-0.5-m_s), mu + a(n+0.5-m_s)]
        let lo = mu + a * (self.first as f64 - 0.5 - m_s);
        let hi = mu + a * (self.last() as f64 + 0.5 - m_s);
        let first = floor_i32(lo + 0.5);
        let last = floor_i32(hi + 0.5);
        let mut out = vec![0.0f64; (last - first + 1).max(1) as usize];
        for (i, &p) in self.p.iter().enumerate() {
            if p <= 0.0 {
                continue;
            }
            let n = self.first + i as i32;
            let a0 = mu + a * (n as f64 - 0.5 - m_s);
            let a1 = mu + a * (n as f64 + 0.5 - m_s);
            let width = a1 - a0;
            if width <= 0.0 {
                continue;
            }
            let k0 = floor_i32(a0 + 0.5);
            let k1 = floor_i32(a1 + 0.5);
            for k in k0..=k1 {
                let c0 = (k as f64 - 0.5).max(a0);
                let c1 = (k as f64 + 0.5).min(a1);
                if c1 > c0 {
                    let idx = (k - first) as usize;
                    if let Some(slot) = out.get_mut(idx) {
                        *slot += p * (c1 - c0) / width;
                    }
                }
            }
        }
        Pmf::from_weights(first, out).unwrap_or(Pmf { first: mu.round() as i32, p: vec![1.0] })
    }

    /// Cumulative distribution at each support point.
    pub fn cdf(&self) -> Vec<f64> {
        let mut acc = 0.0;
        self.p
            .iter()
            .map(|&x| {
                acc += x;
                acc
            })
            .collect()
    }

    /// Quantile function at `u ∈ [0,1]`, linear within unit cells.
    pub fn quantile(&self, u: f64) -> f64 {
        let mut acc = 0.0;
        for (i, &p) in self.p.iter().enumerate() {
            if acc + p >= u && p > 0.0 {
                let frac = ((u - acc) / p).clamp(0.0, 1.0);
                return self.first as f64 + i as f64 - 0.5 + frac;
            }
            acc += p;
        }
        self.last() as f64 + 0.5
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn discrete_gaussian(mu: f64, sd: f64) -> Pmf {
        let lo = (mu - 8.0 * sd).floor() as i32 - 1;
        let hi = (mu + 8.0 * sd).ceil() as i32 + 1;
        Pmf::from_weights(lo, (lo..=hi).map(|n| (-(n as f64 - mu).powi(2) / (2.0 * sd * sd)).exp())).unwrap()
    }

    #[test]
    fn rescale_hits_target_moments() {
        let src = discrete_gaussian(0.3, 2.0);
        for (mu, var) in [(0.0, 1.0), (5.5, 40.0), (-3.0, 400.0), (0.0, 0.5)] {
            let r = src.rescaled(mu, var);
            let (m, v) = r.moments();
            assert!((m - mu).abs() < 0.02, "mean {m} for {mu}");
            assert!((v - var).abs() / var < 0.03, "var {v} for {var}");
            assert!((r.p.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn rescale_keeps_skewed_shape() {
        // Exponential-like shape: skew must survive a widening.
        let src = Pmf::from_weights(0, (0..60).map(|n| (-(n as f64) / 6.0).exp())).unwrap();
        let skew = |p: &Pmf| {
            let (m, v) = p.moments();
            p.p.iter().enumerate().map(|(i, &q)| q * ((p.first + i as i32) as f64 - m).powi(3)).sum::<f64>()
                / v.powf(1.5)
        };
        let r = src.rescaled(0.0, 4.0 * src.moments().1);
        assert!((skew(&r) - skew(&src)).abs() < 0.15, "{} vs {}", skew(&r), skew(&src));
        assert!(skew(&r) > 1.5);
    }

    #[test]
    fn quantile_inverts_cdf() {
        let p = discrete_gaussian(0.0, 3.0);
        assert!(p.quantile(0.5).abs() < 0.05);
        assert!(p.quantile(0.0) <= p.first as f64);
    }
}
