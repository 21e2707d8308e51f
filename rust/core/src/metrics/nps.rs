//! Noise power spectra of flat crops (method.md, "Evaluation"; the NPS item of
//! [`super::spatial`]'s list): where the crops go, the periodogram of one crop, the summary curves
//! (row, column, radial) and the log distance between two spectra.
//!
//! The DFT is a direct separable transform on 16×16 crops with a precomputed twiddle table
//! (2·16³ complex products per crop): no FFT library is needed at this size.

use serde::{Deserialize, Serialize};

/// Side of an NPS crop in same-colour pixels (a crop spans 2·NPS_TILE sensor pixels).
pub const NPS_TILE: usize = 16;

/// White level (DN²) below which a crop is taken as noiseless (clipped) and left out of the
/// normalised spectra: half the variance of rounding alone.
const MIN_WHITE: f64 = 1.0 / 24.0;

/// Non-overlapping wholly flat crops of one CFA plane, by a row-major scan in quarter-tile steps.
pub(super) fn find_tiles(width: usize, height: usize, mask: &[bool], pos: usize) -> Vec<(u32, u32)> {
    let (dy, dx) = (pos / 2, pos % 2);
    let ph = height.saturating_sub(dy).div_ceil(2);
    let pw = width.saturating_sub(dx).div_ceil(2);
    let t = NPS_TILE;
    if ph < t || pw < t {
        return Vec::new();
    }
    // Summed-area table of non-flat plane pixels.
    let mut sat = vec![0u32; (ph + 1) * (pw + 1)];
    for py in 0..ph {
        for px in 0..pw {
            let (y, x) = (2 * py + dy, 2 * px + dx);
            let bad = (y >= height || x >= width || !mask[y * width + x]) as u32;
            sat[(py + 1) * (pw + 1) + px + 1] =
                bad + sat[py * (pw + 1) + px + 1] + sat[(py + 1) * (pw + 1) + px] - sat[py * (pw + 1) + px];
        }
    }
    let bad_in = |y0: usize, x0: usize| {
        let (y1, x1) = (y0 + t, x0 + t);
        sat[y1 * (pw + 1) + x1] + sat[y0 * (pw + 1) + x0] - sat[y0 * (pw + 1) + x1] - sat[y1 * (pw + 1) + x0]
    };
    let mut taken = vec![false; ph * pw];
    let mut tiles = Vec::new();
    let step = (t / 4).max(1);
    let mut y0 = 0;
    while y0 + t <= ph {
        let mut x0 = 0;
        while x0 + t <= pw {
            let free = !taken[y0 * pw + x0]
                && !taken[y0 * pw + x0 + t - 1]
                && !taken[(y0 + t - 1) * pw + x0]
                && !taken[(y0 + t - 1) * pw + x0 + t - 1];
            if free && bad_in(y0, x0) == 0 {
                for yy in y0..y0 + t {
                    taken[yy * pw + x0..yy * pw + x0 + t].fill(true);
                }
                tiles.push((y0 as u32, x0 as u32));
                x0 += t;
                continue;
            }
            x0 += step;
        }
        y0 += step;
    }
    tiles
}

/// The 2-D periodogram of `T × T` crops by a direct separable DFT.
pub(super) struct Dft {
    cos: Vec<f64>,
    sin: Vec<f64>,
}

impl Dft {
    pub(super) fn new() -> Self {
        let t = NPS_TILE;
        let ang = |k: usize| 2.0 * std::f64::consts::PI * k as f64 / t as f64;
        Self { cos: (0..t).map(|k| ang(k).cos()).collect(), sin: (0..t).map(|k| -ang(k).sin()).collect() }
    }

    /// Adds `|DFT(x − mean)|² / T²` of the crop `x` (row-major `T × T`) to `acc`, and the same
    /// divided by the crop's white level (its mean power off both axes) to `norm`.
    /// Returns whether the crop had noise enough to join `norm` ([`MIN_WHITE`]).
    pub(super) fn add_periodogram(&self, x: &mut [f64], acc: &mut [f64], norm: &mut [f64]) -> bool {
        let t = NPS_TILE;
        let mean = x.iter().sum::<f64>() / (t * t) as f64;
        x.iter_mut().for_each(|v| *v -= mean);
        // Along rows: (re, im)[y][k].
        let mut re = vec![0.0f64; t * t];
        let mut im = vec![0.0f64; t * t];
        for y in 0..t {
            let row = &x[y * t..(y + 1) * t];
            for k in 0..t {
                let (mut a, mut b) = (0.0, 0.0);
                for (j, &v) in row.iter().enumerate() {
                    let w = (k * j) % t;
                    a += v * self.cos[w];
                    b += v * self.sin[w];
                }
                re[y * t + k] = a;
                im[y * t + k] = b;
            }
        }
        // Along columns.
        let scale = 1.0 / (t * t) as f64;
        let mut p = vec![0.0f64; t * t];
        for kx in 0..t {
            for ky in 0..t {
                let (mut a, mut b) = (0.0, 0.0);
                for y in 0..t {
                    let w = (ky * y) % t;
                    let (c, s) = (self.cos[w], self.sin[w]);
                    let (r, i) = (re[y * t + kx], im[y * t + kx]);
                    a += r * c - i * s;
                    b += r * s + i * c;
                }
                p[ky * t + kx] = (a * a + b * b) * scale;
            }
        }
        let mut white = 0.0;
        for ky in 1..t {
            for kx in 1..t {
                white += p[ky * t + kx];
            }
        }
        let white = white / ((t - 1) * (t - 1)) as f64;
        for (a, v) in acc.iter_mut().zip(&p) {
            *a += v;
        }
        // A crop without noise (a clipped patch) has no spectral shape: it joins the DN² sums
        // only.
        if white < MIN_WHITE {
            return false;
        }
        for (n, v) in norm.iter_mut().zip(&p) {
            *n += v / white;
        }
        true
    }
}

/// The summary curves of a noise power spectrum at one CFA position (DN² per frequency bin:
/// white noise of variance σ² is σ² everywhere). Frequencies are in cycles per same-colour pixel
/// (0.5 is the plane's Nyquist frequency).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NpsCurves {
    /// Crops × frames averaged.
    pub periodograms: u64,
    /// Frequencies of the row and column curves: `k / T` for `k = 1 … T/2`.
    pub freq: Vec<f64>,
    /// `P(f_y, f_x = 0)`: row-correlated (banding) power at each vertical frequency.
    pub row: Vec<f64>,
    /// `P(f_y = 0, f_x)`: column-correlated power at each horizontal frequency.
    pub col: Vec<f64>,
    /// Radial frequencies of the `radial` curve (mean radius of the bins in each ring).
    pub radial_freq: Vec<f64>,
    /// Mean power of the bins off both axes, by ring of rounded radius.
    pub radial: Vec<f64>,
}

impl NpsCurves {
    /// The curves of an averaged periodogram `p` (row-major `T × T`, `f_y` major).
    pub(super) fn from_periodogram(p: &[f64], periodograms: u64) -> Self {
        let t = NPS_TILE;
        let at = |ky: usize, kx: usize| p[(ky % t) * t + (kx % t)];
        let half = t / 2;
        let both = |f: &dyn Fn(usize) -> f64, k: usize| if k == half { f(k) } else { 0.5 * (f(k) + f(t - k)) };
        let freq: Vec<f64> = (1..=half).map(|k| k as f64 / t as f64).collect();
        let row = (1..=half).map(|k| both(&|j| at(j, 0), k)).collect();
        let col = (1..=half).map(|k| both(&|j| at(0, j), k)).collect();
        let rings = (half as f64 * std::f64::consts::SQRT_2).round() as usize;
        let mut sum = vec![0.0f64; rings + 1];
        let mut rad = vec![0.0f64; rings + 1];
        let mut n = vec![0u32; rings + 1];
        for ky in 1..t {
            for kx in 1..t {
                let (a, b) = (ky.min(t - ky) as f64, kx.min(t - kx) as f64);
                let r = (a * a + b * b).sqrt();
                let ring = (r.round() as usize).min(rings);
                sum[ring] += at(ky, kx);
                rad[ring] += r;
                n[ring] += 1;
            }
        }
        let mut radial_freq = Vec::new();
        let mut radial = Vec::new();
        for i in 0..=rings {
            if n[i] > 0 {
                radial_freq.push(rad[i] / n[i] as f64 / t as f64);
                radial.push(sum[i] / n[i] as f64);
            }
        }
        Self { periodograms, freq, row, col, radial_freq, radial }
    }

    /// Every point of the three curves, in a fixed order.
    #[cfg(test)]
    pub(super) fn points(&self) -> impl Iterator<Item = f64> + '_ {
        self.row.iter().chain(&self.col).chain(&self.radial).copied()
    }
}

/// Mean `|ln(b / a)|` over the points of two spectra's curves, each spectrum first divided by
/// its white level (the mean of its radial curve), so that the distance measures the shape of
/// the spectrum — spatial correlation — and not the noise variance, which the pixel JSDs score;
/// `[all points, the row curve, the column curve]`. Points where either is not positive are left
/// out; `None` when no point is left.
pub fn nps_log_distances(a: &NpsCurves, b: &NpsCurves) -> Option<[f64; 3]> {
    let white = |c: &NpsCurves| c.radial.iter().sum::<f64>() / c.radial.len().max(1) as f64;
    let (wa, wb) = (white(a), white(b));
    if !(wa > 0.0 && wb > 0.0) {
        return None;
    }
    let dist = |x: &[f64], y: &[f64]| {
        let (mut acc, mut n) = (0.0, 0usize);
        for (&p, &q) in x.iter().zip(y) {
            if p > 0.0 && q > 0.0 {
                acc += ((q / wb) / (p / wa)).ln().abs();
                n += 1;
            }
        }
        (acc, n)
    };
    let (r, nr) = dist(&a.row, &b.row);
    let (c, nc) = dist(&a.col, &b.col);
    let (d, nd) = dist(&a.radial, &b.radial);
    let n = nr + nc + nd;
    (n > 0 && nr > 0 && nc > 0).then(|| [(r + c + d) / n as f64, r / nr as f64, c / nc as f64])
}

/// The overall distance of [`nps_log_distances`].
pub fn nps_log_distance(a: &NpsCurves, b: &NpsCurves) -> Option<f64> {
    nps_log_distances(a, b).map(|d| d[0])
}
