//! Blending two PMFs' standardised quantile functions (the shape of an interpolated bin).

use crate::model::pmf::Pmf;

/// One cell of a standardised quantile function: over `u ∈ [u0, u1]` it runs linearly from `z0`
/// with `slope` (the slope is computed once per cell, not at every evaluation).
#[derive(Debug, Clone, Copy)]
struct Cell {
    u0: f64,
    u1: f64,
    z0: f64,
    slope: f64,
}

impl Cell {
    /// The quantile at `u`, linear within the cell (clamped to it).
    fn at(&self, u: f64) -> f64 {
        self.z0 + self.slope * (u - self.u0).clamp(0.0, self.u1 - self.u0)
    }
}

/// Piecewise-linear quantile function of a PMF read as piecewise-uniform unit cells,
/// standardised to zero mean and unit variance: one [`Cell`] per cell with mass.
fn standard_quantile(p: &Pmf) -> Vec<Cell> {
    let (m, v) = p.moments();
    let s = (v + 1.0 / 12.0).sqrt();
    let mut u = 0.0;
    let mut out: Vec<Cell> = Vec::with_capacity(p.p.len());
    for (i, &q) in p.p.iter().enumerate() {
        if q <= 0.0 {
            continue;
        }
        let x = (p.first + i as i32) as f64;
        // A cell one code wide: `z` rises by `1/s` over its mass `q`.
        out.push(Cell { u0: u, u1: u + q, z0: (x - 0.5 - m) / s, slope: 1.0 / (s * q) });
        u += q;
    }
    if let Some(last) = out.last_mut() {
        last.u1 = 1.0;
    }
    out
}

/// Blends the standardised quantile functions of `a` and `b` (`(1 − t)·Q_a + t·Q_b`), then maps
/// the result to mean `mu` and variance `var` on the integer grid (as [`Pmf::rescaled_to`]).
pub fn blend_quantiles(a: &Pmf, b: &Pmf, t: f64, mu: f64, var: f64) -> Pmf {
    let t = t.clamp(0.0, 1.0);
    let qa = standard_quantile(a);
    let qb = standard_quantile(b);
    if qa.is_empty() || qb.is_empty() || t <= 0.0 {
        return a.rescaled_to(mu, var);
    }
    if t >= 1.0 {
        return b.rescaled_to(mu, var);
    }
    // Both quantile functions' cell ends ascend: merged in one pass (what sorting them gives).
    let mut knots: Vec<f64> = Vec::with_capacity(qa.len() + qb.len() + 1);
    knots.push(0.0);
    let (mut ea, mut eb) = (qa.iter().map(|c| c.u1).peekable(), qb.iter().map(|c| c.u1).peekable());
    while let (Some(&x), Some(&y)) = (ea.peek(), eb.peek()) {
        let from_a = x.total_cmp(&y).is_le();
        knots.push(if from_a { x } else { y });
        let _ = if from_a { ea.next() } else { eb.next() };
    }
    knots.extend(ea.chain(eb));
    knots.dedup_by(|x, y| (*x - *y).abs() < 1e-15);
    let mut segs: Vec<(f64, f64, f64)> = Vec::with_capacity(knots.len());
    let (mut ia, mut ib) = (0usize, 0usize);
    for w in knots.windows(2) {
        let (u0, u1) = (w[0], w[1]);
        let mid = 0.5 * (u0 + u1);
        while ia + 1 < qa.len() && qa[ia].u1 < mid {
            ia += 1;
        }
        while ib + 1 < qb.len() && qb[ib].u1 < mid {
            ib += 1;
        }
        let z0 = (1.0 - t) * qa[ia].at(u0) + t * qb[ib].at(u0);
        let z1 = (1.0 - t) * qa[ia].at(u1) + t * qb[ib].at(u1);
        segs.push((u1 - u0, z0, z1));
    }
    let mean: f64 = segs.iter().map(|(m, z0, z1)| m * 0.5 * (z0 + z1)).sum();
    let ez2: f64 = segs.iter().map(|(m, z0, z1)| m * (z0 * z0 + z0 * z1 + z1 * z1) / 3.0).sum();
    let sd = (ez2 - mean * mean).max(1e-12).sqrt();
    let target = (var - 1.0 / 12.0).max(1e-4).sqrt();
    let k = target / sd;
    let map = |z: f64| mu + k * (z - mean);
    let lo = map(segs.first().map_or(0.0, |s| s.1));
    let hi = map(segs.last().map_or(0.0, |s| s.2));
    let first = (lo + 0.5).floor() as i32;
    let last = (hi + 0.5).floor() as i32;
    let mut out = vec![0.0f64; (last - first + 1).max(1) as usize];
    for (m, z0, z1) in segs {
        if m <= 0.0 {
            continue;
        }
        let (x0, x1) = (map(z0), map(z1));
        if x1 - x0 < 1e-12 {
            let kc = ((x0 + 0.5).floor() as i32 - first).clamp(0, out.len() as i32 - 1);
            out[kc as usize] += m;
            continue;
        }
        let k0 = (x0 + 0.5).floor() as i32;
        let k1 = (x1 + 0.5).floor() as i32;
        let density = m / (x1 - x0);
        for kc in k0..=k1 {
            let c0 = (kc as f64 - 0.5).max(x0);
            let c1 = (kc as f64 + 0.5).min(x1);
            if c1 > c0
                && let Some(slot) = out.get_mut((kc - first) as usize)
            {
                *slot += density * (c1 - c0);
            }
        }
    }
    Pmf::from_weights(first, out).unwrap_or_else(|| a.rescaled_to(mu, var))
}
