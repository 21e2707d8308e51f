//! Structured components at synthesis (method.md, "Structured noise"): per image one offset per
//! CFA position (the frame), per row and per column one offset, drawn from the pack's measured
//! distributions; every pixel gets `frame + row + column` on top of its own noise.
//!
//! Offsets are fractional; a pixel's code is not. A pixel adds `⌊o⌋ + [v < o − ⌊o⌋]` (`v`
//! uniform per pixel): its mean is exactly `o`, so row means carry the row offset, not a
//! rounded one. The pixel PMFs were measured on frames that already held these offsets, so
//! synthesis first takes them out: per position the PMF `K` of the added integer offset is
//! computed from the component distributions, and each bin's PMF `P` is replaced by the `Q ≥ 0`
//! with `Q ∗ K ≈ P` (non-negative deconvolution, [`crate::renoise::deconv`]). A pixel's
//! marginal stays the measured one and no variance is counted twice.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::model::layout::POSITIONS;
use crate::model::pack::BinModel;
#[cfg(doc)]
use crate::model::pmf::Pmf;
use crate::model::structure::{Components, FrameOffsets, IsoStructure, OffsetDistribution};
use crate::renoise::deconv::{Problem, SolverLimits, richardson_lucy};

/// Grid of the offset densities (cells per DN).
const GRID: f64 = 32.0;
/// Below this share of a bin's variance, the offset kernel is taken out by narrowing alone (Eq.
/// 5–6): the shape error is second order in the share (the excess kurtosis of `Q ∗ K` comes out
/// `(1 − share)²` of the measured one), while Richardson–Lucy would cost `n · K` per iteration.
const RESCALE_ONLY: f64 = 0.1;
/// Richardson–Lucy iterations at most, and the work (`iterations · n · K`) per bin at most.
const RL_ITERATIONS: usize = 200;
const RL_WORK: f64 = 4e6;
/// RNG stream of the offsets (the pixel bands use streams `0 ..`, far below).
const STREAM: u64 = 1 << 62;

/// The components synthesis adds at one ISO.
#[derive(Debug, Clone)]
pub struct StructureSampler {
    rows: [Option<OffsetDistribution>; 2],
    columns: [Option<OffsetDistribution>; 2],
    frame: Option<FrameOffsets>,
}

/// One image's offsets.
pub(crate) struct ImageOffsets {
    pub(crate) frame: [f64; POSITIONS],
    /// Per row of the image.
    pub(crate) rows: Vec<f64>,
    /// Per column of the image.
    pub(crate) columns: Vec<f64>,
}

impl StructureSampler {
    /// The significant components of `st` that `which` asks for; `None` when that leaves none.
    pub fn new(st: &IsoStructure, which: Components) -> Option<Self> {
        let s = Self {
            rows: std::array::from_fn(|p| st.row(p).filter(|_| which.row).cloned()),
            columns: std::array::from_fn(|p| st.column(p).filter(|_| which.column).cloned()),
            frame: st.frame().filter(|_| which.frame).cloned(),
        };
        (s.rows.iter().chain(&s.columns).any(Option::is_some) || s.frame.is_some()).then_some(s)
    }

    /// Draws an image's offsets (`origin`: the sensor row and column of its pixel (0, 0); only
    /// parities matter). Deterministic in the seed, whatever the thread count.
    pub(crate) fn draw(&self, seed: u64, h: usize, w: usize, origin: (usize, usize)) -> ImageOffsets {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(STREAM);
        let frame = match &self.frame {
            Some(f) => {
                let pick = rng.next_u64();
                let gauss = std::array::from_fn(|_| gaussian(&mut rng));
                f.draw(pick, gauss)
            }
            None => [0.0; POSITIONS],
        };
        let mut line = |n: usize, first: usize, d: &[Option<OffsetDistribution>; 2]| -> Vec<f64> {
            (0..n)
                .map(|i| match &d[(first + i) & 1] {
                    Some(d) => d.at(unit(rng.next_u64())),
                    None => 0.0,
                })
                .collect()
        };
        let rows = line(h, origin.0, &self.rows);
        let columns = line(w, origin.1, &self.columns);
        ImageOffsets { frame, rows, columns }
    }

    /// The PMF of the integer offset a pixel at `pos` gets: `⌊o⌋ + Bernoulli(o − ⌊o⌋)` with `o`
    /// the sum of its frame, row and column offsets. Returns `(first, pmf)`.
    pub fn kernel(&self, pos: usize) -> (i32, Vec<f64>) {
        let mut dens = (0i64, vec![1.0]);
        if let Some(d) = &self.rows[pos >> 1] {
            dens = convolve(&dens, &quantile_density(d));
        }
        if let Some(d) = &self.columns[pos & 1] {
            dens = convolve(&dens, &quantile_density(d));
        }
        if let Some(f) = &self.frame {
            dens = convolve(&dens, &frame_density(f, pos));
        }
        // Dither each grid point onto the integers.
        let (first_cell, w) = dens;
        let lo = ((first_cell as f64) / GRID).floor() as i32;
        let hi = (((first_cell + w.len() as i64) as f64) / GRID).floor() as i32 + 1;
        let mut out = vec![0.0; (hi - lo + 1) as usize];
        for (i, &p) in w.iter().enumerate() {
            let o = (first_cell + i as i64) as f64 / GRID;
            let f = o.floor();
            let k = (f as i32 - lo) as usize;
            out[k] += p * (1.0 - (o - f));
            out[k + 1] += p * (o - f);
        }
        let first = out.iter().position(|&p| p > 1e-12).unwrap_or(0);
        let last = out.iter().rposition(|&p| p > 1e-12).unwrap_or(first);
        let p: Vec<f64> = out[first..=last].to_vec();
        let t: f64 = p.iter().sum();
        (lo + first as i32, p.into_iter().map(|x| x / t).collect())
    }

    /// A position's bins with the structured offsets taken out of their PMFs (see the module
    /// docs). Clipped bins, and bins narrower than the kernel, are kept as they are.
    pub fn deconvolved(&self, pos: usize, bins: &[BinModel]) -> Vec<BinModel> {
        let (k0, kernel) = self.kernel(pos);
        if kernel.len() <= 1 {
            return bins.to_vec();
        }
        bins.par_iter().map(|b| deconvolve_bin(b, k0, &kernel)).collect()
    }
}

/// `Q` with `Q ∗ K ≈ P` for one bin: `P`'s shape narrowed by `K`'s variance (Eq. 5–6 of the
/// paper, [`Pmf::rescaled`]) as the start, then Richardson–Lucy. In a clipped bin the sensor's
/// clamp piled mass at one end of `P`; synthesis clamps after adding the offsets, so `Q ∗ K` is
/// folded onto that end the same way before it is compared with `P`.
fn deconvolve_bin(b: &BinModel, k0: i32, kernel: &[f64]) -> BinModel {
    let pmf = b.pmf();
    if pmf.p.len() < kernel.len() + 2 {
        return b.clone();
    }
    let (pm, pv) = pmf.moments();
    let km: f64 = kernel.iter().enumerate().map(|(i, p)| (k0 + i as i32) as f64 * p).sum();
    let kv: f64 = kernel.iter().enumerate().map(|(i, p)| ((k0 + i as i32) as f64 - km).powi(2) * p).sum();
    if pv <= kv + 1.0 / 12.0 {
        return b.clone();
    }
    let n = pmf.p.len();
    let start_only = kv < RESCALE_ONLY * pv;
    // Richardson–Lucy costs `n · K` per iteration: bounded per bin, so a wide bin with a long
    // kernel cannot stall the sampler build (the narrowed start is already close there).
    let iterations = (RL_WORK / (n * kernel.len()) as f64).min(RL_ITERATIONS as f64) as usize;
    if !b.clipped && (start_only || iterations < 10) {
        let start = pmf.rescaled(pm - km, pv - kv);
        return from_weights(b, start.first, &start.p);
    }
    if iterations < 10 {
        // A clipped bin too wide to fold: kept as measured (its clamp pile would move inward
        // under narrowing alone).
        return b.clone();
    }
    // Which end holds the clamp's pile (clipped bins only).
    let (low, high) = match b.clipped {
        false => (false, false),
        true if pmf.p[0] >= pmf.p[n - 1] => (true, false),
        true => (false, true),
    };
    let ext = kernel.len();
    let (ext_lo, ext_hi) = (if low { ext } else { 0 }, if high { ext } else { 0 });
    let m = n - kernel.len() + 1 + ext_lo + ext_hi;
    let q_first = pmf.first - k0 - ext_lo as i32;
    let start = pmf.rescaled(pm - km, pv - kv);
    let mut q: Vec<f64> = (0..m).map(|j| start.at(q_first + j as i32) + 1e-9).collect();
    let s: f64 = q.iter().sum();
    q.iter_mut().for_each(|x| *x /= s);
    let mut target = vec![0.0; ext_lo];
    target.extend_from_slice(&pmf.p);
    target.resize(ext_lo + n + ext_hi, 0.0);
    let problem = Problem { a: kernel.to_vec(), b: target, clip_lo: ext_lo, clip_hi: ext_lo + n - 1 };
    richardson_lucy(&problem, &mut q, &SolverLimits { max_iterations: iterations, tolerance: 1e-5 });
    from_weights(b, q_first, &q)
}

/// `b` with its PMF replaced by the weights `q` over `first, first + 1, …`.
fn from_weights(b: &BinModel, first: i32, q: &[f64]) -> BinModel {
    const SCALE: f64 = (1u64 << 30) as f64;
    let counts: Vec<u64> = q.iter().map(|&x| (x * SCALE).round() as u64).collect();
    let lo = counts.iter().position(|&c| c > 0);
    let hi = counts.iter().rposition(|&c| c > 0);
    let (Some(lo), Some(hi)) = (lo, hi) else {
        return b.clone();
    };
    BinModel { first: first + lo as i32, counts: counts[lo..=hi].to_vec(), ..b.clone() }
}

/// A quantile function as a density on the grid.
fn quantile_density(d: &OffsetDistribution) -> (i64, Vec<f64>) {
    let q = &d.quantiles;
    let n = q.len();
    let pts: Vec<(f64, f64)> =
        (0..n.saturating_sub(1)).map(|i| (0.5 * (q[i] as f64 + q[i + 1] as f64), 1.0 / (n - 1) as f64)).collect();
    on_grid(&pts)
}

/// The density of one position's frame offsets as [`FrameOffsets::draw`] makes them: the
/// measured offsets, shrunk, each with its Gaussian kernel.
fn frame_density(f: &FrameOffsets, pos: usize) -> (i64, Vec<f64>) {
    let Some(b) = f.bootstrap(pos) else {
        return (0, vec![1.0]);
    };
    // The kernel at 33 points over ±4 sd.
    let ws: Vec<f64> = (-16..=16).map(|j| (-0.5 * (j as f64 / 4.0).powi(2)).exp()).collect();
    let t = ws.iter().sum::<f64>() * f.offsets.len() as f64;
    let mut pts = Vec::with_capacity(f.offsets.len() * ws.len());
    for o in &f.offsets {
        let c = (o[pos] as f64 - b.mean) * b.shrink;
        pts.extend((-16..=16).zip(&ws).map(|(j, w)| (c + b.kernel_sd * j as f64 / 4.0, w / t)));
    }
    on_grid(&pts)
}

/// Weighted points onto the grid (linear split between the two nearest cells).
fn on_grid(pts: &[(f64, f64)]) -> (i64, Vec<f64>) {
    if pts.is_empty() {
        return (0, vec![1.0]);
    }
    let lo = pts.iter().map(|p| (p.0 * GRID).floor() as i64).min().unwrap_or(0);
    let hi = pts.iter().map(|p| (p.0 * GRID).floor() as i64 + 1).max().unwrap_or(0);
    let mut out = vec![0.0; (hi - lo + 1) as usize];
    for &(x, w) in pts {
        let g = x * GRID;
        let f = g.floor();
        let k = (f as i64 - lo) as usize;
        out[k] += w * (1.0 - (g - f));
        out[k + 1] += w * (g - f);
    }
    (lo, out)
}

fn convolve(a: &(i64, Vec<f64>), b: &(i64, Vec<f64>)) -> (i64, Vec<f64>) {
    let mut out = vec![0.0; a.1.len() + b.1.len() - 1];
    crate::renoise::deconv::convolve(&a.1, &b.1, &mut out);
    (a.0 + b.0, out)
}

/// A uniform draw in `[0, 1)` from 53 bits.
#[inline]
fn unit(u: u64) -> f64 {
    (u >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A standard normal draw (Box–Muller).
fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    let u1 = 1.0 - unit(rng.next_u64());
    let u2 = unit(rng.next_u64());
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::structure::QUANTILES;

    fn gaussian_dist(sd: f64) -> OffsetDistribution {
        let quantiles = (0..QUANTILES)
            .map(|i| {
                let u = (i as f64 + 0.5) / QUANTILES as f64;
                // Bisection on Φ(z) = 1 − erfc(z/√2)/2.
                let (mut lo, mut hi) = (-8.0f64, 8.0f64);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if 1.0 - 0.5 * crate::math::special::erfc(mid / std::f64::consts::SQRT_2) < u {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                (sd * 0.5 * (lo + hi)) as f32
            })
            .collect();
        OffsetDistribution { quantiles, count: 1000, measured_var: sd * sd, sampling_var: 0.0, significant: true }
    }

    #[test]
    fn kernel_has_the_offsets_variance_plus_the_dither() {
        let st = IsoStructure {
            iso: 100,
            rows: [Some(gaussian_dist(0.7)), Some(gaussian_dist(0.7))],
            columns: [None, None],
            frames: None,
            frames_used: 10,
        };
        let s = StructureSampler::new(&st, Components::ALL).expect("significant rows");
        let (first, k) = s.kernel(0);
        let mean: f64 = k.iter().enumerate().map(|(i, p)| (first + i as i32) as f64 * p).sum();
        let var: f64 = k.iter().enumerate().map(|(i, p)| ((first + i as i32) as f64 - mean).powi(2) * p).sum();
        assert!(mean.abs() < 0.01, "mean {mean}");
        // Var = 0.49 + E[f(1 − f)] with f the fractional part (≈ 1/6 for a wide offset).
        assert!(var > 0.49 + 0.12 && var < 0.49 + 0.2, "var {var}");
    }
}
