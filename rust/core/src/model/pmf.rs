//! Operations on integer-grid PMFs: normalised shapes (paper Eq. 5) rescaled to a new mean and
//! variance (Eq. 6), back on the integer grid.

use multiversion::multiversion;

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
    /// variance that cells add (Sheppard), so the result's discrete variance is close to `var`
    /// for a density smooth on a cell's scale; a PMF a few cells wide misses it, by 1–30 % at
    /// sub-DN noise ([`Pmf::rescaled_to`] meets it). The calibration's pooling moves keep this
    /// map (`calibrate/estimate/pool.rs`, which corrects its own moves): with `rescaled_to`
    /// there, its held-out choice no longer pooled the sparse bin of
    /// `calibrate::estimate::tests_folds::a_sparse_bin_off_the_law_pools_with_its_own_mean`.
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
        let cells = Cells { first: self.first, mu, a, m_s };
        // Two passes: every source cell's shares of the (at most) two output cells it reaches,
        // a loop without a store to a computed index that the compiler vectorises, with a
        // division per share; then the shares added into the output cells in the order of the
        // one-pass loop (cell by cell, the lower output cell first), so the same sums to the
        // bit. A cell reaching further (a widening by more than 2) takes the one-pass loop.
        // Skipped terms (no mass, no overlap) are zeros added here: the sums stay at +0 or
        // above, where adding +0 changes no bit.
        let n = self.p.len();
        let (mut k0s, mut lows, mut highs) = (vec![0i32; n], vec![0.0f64; n], vec![0.0f64; n]);
        let mut reach = vec![false; n];
        shares(&cells, &self.p, &mut k0s, &mut lows, &mut highs, &mut reach);
        for i in 0..n {
            let k0 = k0s[i];
            if reach[i] {
                cells.scatter(i, self.p[i], first, &mut out);
                continue;
            }
            for (k, v) in [(k0, lows[i]), (k0 + 1, highs[i])] {
                if let Some(slot) = out.get_mut((k - first) as usize) {
                    *slot += v;
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

/// Where [`Pmf::rescaled`] maps the source cells: cell `n` (from `first`) onto
/// `[mu + a(n − 0.5 − m_s), mu + a(n + 0.5 − m_s)]`.
struct Cells {
    first: i32,
    mu: f64,
    a: f64,
    m_s: f64,
}

impl Cells {
    /// The mapped ends of source cell `i`.
    #[inline(always)]
    fn ends(&self, i: usize) -> (f64, f64) {
        let n = self.first + i as i32;
        (self.mu + self.a * (n as f64 - 0.5 - self.m_s), self.mu + self.a * (n as f64 + 0.5 - self.m_s))
    }

    /// The share of source cell `i` (mass `p`) that falls in output cell `k`, of the mapped
    /// ends `a0`, `a1` (0 where it has none).
    #[inline(always)]
    fn share(k: i32, a0: f64, a1: f64, p: f64) -> f64 {
        let width = a1 - a0;
        let c0 = (k as f64 - 0.5).max(a0);
        let c1 = (k as f64 + 0.5).min(a1);
        if p > 0.0 && width > 0.0 && c1 > c0 { p * (c1 - c0) / width } else { 0.0 }
    }

    /// The one-pass loop for source cell `i`: its shares added into every output cell it
    /// reaches (`out[0]` is cell `first`).
    fn scatter(&self, i: usize, p: f64, first: i32, out: &mut [f64]) {
        let (a0, a1) = self.ends(i);
        if p <= 0.0 || a1 - a0 <= 0.0 {
            return;
        }
        for k in floor_i32(a0 + 0.5)..=floor_i32(a1 + 0.5) {
            let v = Self::share(k, a0, a1, p);
            if v != 0.0
                && let Some(slot) = out.get_mut((k - first) as usize)
            {
                *slot += v;
            }
        }
    }
}

/// Per source cell of [`Pmf::rescaled`]: the first output cell it reaches, its shares of that
/// cell and the next (0 beyond its reach), and whether it reaches further than those two.
#[multiversion(targets(
    "x86_64+avx512f+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn shares(cells: &Cells, p: &[f64], k0s: &mut [i32], lows: &mut [f64], highs: &mut [f64], reach: &mut [bool]) {
    let n = p.len();
    let (k0s, lows, highs, reach) = (&mut k0s[..n], &mut lows[..n], &mut highs[..n], &mut reach[..n]);
    for i in 0..n {
        let (a0, a1) = cells.ends(i);
        let (k0, k1) = (floor_i32(a0 + 0.5), floor_i32(a1 + 0.5));
        k0s[i] = k0;
        lows[i] = Cells::share(k0, a0, a1, p[i]);
        highs[i] = if k1 > k0 { Cells::share(k0 + 1, a0, a1, p[i]) } else { 0.0 };
        reach[i] = k1 > k0 + 1;
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

    /// The one-pass loop `rescaled` had before its two passes: each source cell's shares added
    /// into the output cells as they are found.
    fn rescaled_one_pass(src: &Pmf, mu: f64, var: f64) -> Pmf {
        let (m_s, v_s) = src.moments();
        let a = ((var - 1.0 / 12.0).max(1e-4) / (v_s + 1.0 / 12.0)).sqrt();
        let first = floor_i32(mu + a * (src.first as f64 - 0.5 - m_s) + 0.5);
        let last = floor_i32(mu + a * (src.last() as f64 + 0.5 - m_s) + 0.5);
        let mut out = vec![0.0f64; (last - first + 1).max(1) as usize];
        for (i, &p) in src.p.iter().enumerate() {
            if p <= 0.0 {
                continue;
            }
            let n = src.first + i as i32;
            let a0 = mu + a * (n as f64 - 0.5 - m_s);
            let a1 = mu + a * (n as f64 + 0.5 - m_s);
            let width = a1 - a0;
            if width <= 0.0 {
                continue;
            }
            for k in floor_i32(a0 + 0.5)..=floor_i32(a1 + 0.5) {
                let c0 = (k as f64 - 0.5).max(a0);
                let c1 = (k as f64 + 0.5).min(a1);
                if c1 > c0
                    && let Some(slot) = out.get_mut((k - first) as usize)
                {
                    *slot += p * (c1 - c0) / width;
                }
            }
        }
        Pmf::from_weights(first, out).unwrap_or(Pmf { first: mu.round() as i32, p: vec![1.0] })
    }

    /// The two-pass `rescaled` gives the one-pass loop's PMF bit for bit: narrowed (the sampler
    /// build's deconvolution starts) and widened by up to 30× (a cell then reaches many output
    /// cells, the fallback), on PMFs with zero cells inside and at the ends, long floor-count
    /// tails and single cells, at means on and off the grid. A two-pass version that dropped a
    /// cell's second share, or summed in another order, differs on most of these.
    #[test]
    fn two_passes_are_the_one_pass_loop_bit_for_bit() {
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut sources = vec![
            Pmf { first: 3, p: vec![1.0] },
            Pmf { first: -2, p: vec![0.5, 0.0, 0.5] },
            discrete_gaussian(0.3, 2.0),
            discrete_gaussian(-40.0, 25.0),
        ];
        for len in [2usize, 5, 40, 700, 3000] {
            let first = (next() * 200.0) as i32 - 100;
            let w: Vec<f64> = (0..len)
                .map(|i| {
                    let x = (i as f64 - len as f64 / 3.0) / (len as f64 / 8.0 + 0.5);
                    let body = (-0.5 * x * x).exp();
                    // Floor counts in the tails, and some empty cells.
                    if next() < 0.1 { 0.0 } else { body + 1e-9 * (next() < 0.5) as u8 as f64 }
                })
                .collect();
            sources.extend(Pmf::from_weights(first, w));
        }
        let mut compared = 0;
        for src in &sources {
            let (m, v) = src.moments();
            for scale in [0.01, 0.3, 0.9, 0.999, 1.0, 1.7, 4.0, 30.0, 900.0] {
                for shift in [0.0, 0.5, -0.25, next() * 10.0 - 5.0] {
                    let (mu, var) = (m + shift, (v + 1.0 / 12.0) * scale);
                    let got = src.rescaled(mu, var);
                    let want = rescaled_one_pass(src, mu, var);
                    assert_eq!(got.first, want.first, "first, scale {scale}, shift {shift}");
                    let bits = |p: &Pmf| p.p.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&got), bits(&want), "scale {scale}, shift {shift}, {} cells", src.p.len());
                    compared += 1;
                }
            }
        }
        assert!(compared >= 300, "{compared} rescalings compared");
    }

    #[test]
    fn quantile_inverts_cdf() {
        let p = discrete_gaussian(0.0, 3.0);
        assert!(p.quantile(0.5).abs() < 0.05);
        assert!(p.quantile(0.0) <= p.first as f64);
    }
}
