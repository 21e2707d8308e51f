//! What registration and the motion test read of a clean image, made once when a reference
//! burst closes ([`MotionProbe::new`]): each flat pixel's gradient in units of its motion
//! tolerance, and the edge and anchor samples registration reads.

use std::sync::OnceLock;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::anchor_bits::{AnchorBits, thin_anchors};
use crate::calibrate::flat::{FlatReport, Groups, NOT_FLAT};
use crate::math::fit::poly_eval;
use crate::math::round::round_half_away;
use crate::model::layout::{POSITIONS, position};

/// A flat pixel is left out of a frame when the frame's motion changes its clean level by more
/// than this many standard deviations of one frame's noise at its level (a motion error of at
/// most a quarter SD adds at most 6 % to the variance of the pixels kept, and on average far
/// less: most kept pixels are far from edges).
pub const MOTION_TOLERANCE: f64 = 0.25;

/// Gradients are stored in units of `tolerance / GRADIENT_UNITS` per pixel: an i8 then holds
/// up to 16 tolerances (4 SD of a reference frame's noise) per pixel, more than the flat test
/// lets a flat pixel have, at a resolution that misjudges a 2 px motion by at most 1/8 of the
/// tolerance.
pub(super) const GRADIENT_UNITS: f32 = 8.0;

/// Most edge samples a registration reads (a shift's standard error goes with one over the root
/// of their number: at 4 096 edges of 20 σ/px it is about 10⁻³ px).
const MAX_EDGE_SAMPLES: usize = 4_096;

/// Most anchor samples (flat pixels: they pin each position's gain and offset, and measure how
/// noisy the frame is).
const MAX_ANCHOR_SAMPLES: usize = 1_024;

/// What registration and the motion test read of a clean image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MotionProbe {
    /// The burst's mean, rounded, at every pixel (the clean image without its flat mask).
    pub mean: Vec<u16>,
    /// Pixels registration reads (row-major indices): strong edges, then flat anchors.
    pub samples: Vec<u32>,
    /// The first anchor in `samples` (the edges come before it).
    pub anchors_from: usize,
    /// Per anchor, one reference frame's noise SD at its level (DN): a target frame's anchors
    /// measure how much noisier it is.
    pub anchor_sd: Vec<f32>,
    /// Per pixel, the clean level's gradient, computed on first use ([`MotionProbe::gradients`]).
    #[serde(skip)]
    gradient: GradientCache,
    /// Per position and clean level, the tolerance (DN): [`MOTION_TOLERANCE`] SD of one
    /// reference frame's noise there.
    pub tolerance: [Vec<f32>; POSITIONS],
}

/// One frame's noise standard deviation at a level and position, as the reference burst measured
/// it (frame-to-frame differences; for a one-frame burst, the spatial spread of the clean image),
/// never below a quarter DN (quantisation).
fn frame_sd(flat: &FlatReport, groups: &Groups, frames: u32, pos: usize, level: f64) -> f64 {
    let var = if frames >= 2 {
        flat.mean_noise_at(groups, pos, level) * frames as f64
    } else {
        poly_eval(&flat.clean_variance[pos], (level - groups.black[pos] as f64).max(0.0))
    };
    var.max(0.0625).sqrt()
}

/// The gradient of `mean` at `(x, y)` on the pixel's own colour lattice (Sobel over ±2 px,
/// clamped at the borders), DN per pixel.
#[inline]
pub(super) fn sobel(mean: &[u16], w: usize, h: usize, x: usize, y: usize) -> [f64; 2] {
    let col = |dx: isize| lattice(x, dx, w);
    let row = |dy: isize| lattice(y, dy, h);
    let v = |yy: usize, xx: usize| mean[yy * w + xx] as f64;
    let (xm, xp, ym, yp) = (col(-2), col(2), row(-2), row(2));
    let dxs = if xp > xm { (xp - xm) as f64 } else { 1.0 };
    let dys = if yp > ym { (yp - ym) as f64 } else { 1.0 };
    let gx = (v(ym, xp) - v(ym, xm) + 2.0 * (v(y, xp) - v(y, xm)) + v(yp, xp) - v(yp, xm)) / (4.0 * dxs);
    let gy = (v(yp, xm) - v(ym, xm) + 2.0 * (v(yp, x) - v(ym, x)) + v(yp, xp) - v(ym, xp)) / (4.0 * dys);
    [gx, gy]
}

/// `i + d` kept on `i`'s parity inside `[0, n)`.
#[inline]
fn lattice(i: usize, d: isize, n: usize) -> usize {
    let j = i as isize + d;
    if j < 0 {
        i & 1
    } else if j as usize >= n {
        let last = n - 1;
        if last & 1 == i & 1 { last } else { last - 1 }
    } else {
        j as usize
    }
}

/// One band of rows' edge samples and anchors, as [`MotionProbe::new`] finds them.
type BandSamples = (Vec<u32>, AnchorBits);

/// Rows per band of the probe's parallel passes.
const BAND_ROWS: usize = 64;

/// One row of a clean image as [`MotionProbe::new`] and [`MotionProbe::gradients`] read it.
struct ProbeRow<'a> {
    mean: &'a [u16],
    levels: &'a [u16],
    w: usize,
    h: usize,
    y: usize,
    tolerance: &'a [Vec<f32>; POSITIONS],
}

impl ProbeRow<'_> {
    /// Whether `sobel_row` gives this row's interior gradients (2 px from the top and bottom).
    fn inner_row(&self) -> bool {
        self.y >= 2 && self.y + 2 < self.h
    }

    /// The gradient at column `x` (DN per pixel): interior pixels take the Sobel from `inner`
    /// (this row's [`sobel_row`] when [`ProbeRow::inner_row`]), the same sums in the same order
    /// as [`sobel`], which the border pixels take.
    #[inline(always)]
    fn gradient_at(&self, x: usize, inner: &[[i32; 2]]) -> [f64; 2] {
        if self.inner_row() && x >= 2 && x + 2 < self.w {
            // Sums of integers below 2¹⁹, over 16: the f64 sums and division exactly.
            let [gx, gy] = inner[x - 2];
            [gx as f64 / 16.0, gy as f64 / 16.0]
        } else {
            sobel(self.mean, self.w, self.h, x, self.y)
        }
    }

    /// One frame's noise SD (DN) at pixel `i` of position `pos`, from the tolerance of its mean.
    #[inline(always)]
    fn sd(&self, pos: usize, i: usize) -> f64 {
        self.tolerance[pos][self.mean[i] as usize] as f64 / MOTION_TOLERANCE
    }

    /// A sampled row's edges and anchors, in column order (`frames`: the burst's; `clip`: the
    /// level above which values bend). The edge test is `hypot` exactly, without its libm call.
    fn samples(
        &self,
        frames: u32,
        clip: f32,
        edges: &mut Vec<u32>,
        anchors: &mut AnchorBits,
        inner: &mut Vec<[i32; 2]>,
    ) {
        let Self { mean, levels, w, y, .. } = *self;
        let margin = 4;
        if y < margin || y + margin >= self.h || w <= 2 * margin {
            return;
        }
        if self.inner_row() {
            sobel_row(mean, w, y, inner);
        }
        for x in margin..w - margin {
            let i = y * w + x;
            let below_clip = (mean[i] as f64 as f32) < clip;
            if !below_clip {
                continue;
            }
            let g = self.gradient_at(x, inner);
            let sd = self.sd(position(y, x), i);
            // An edge: a gradient far above what the mean's own noise makes (a Sobel
            // difference of means of `frames` frames has SD ≈ 0.22 · sd / √frames).
            let noise = 0.22 * sd / (frames.max(1) as f64).sqrt();
            let threshold = (8.0 * noise).max(0.5);
            if hypot_above(g, threshold) {
                edges.push(i as u32);
            } else if levels[i] != NOT_FLAT {
                anchors.set(i);
            }
        }
    }

    /// The row's gradients at its flat pixels in units of their tolerance ([`quantised`];
    /// `units_per_dn`: per position and level, `GRADIENT_UNITS / tol`); the other pixels are
    /// left as they are. The rounding is `f64::round` exactly, without its libm call.
    fn gradients(&self, units_per_dn: &[Vec<f64>; POSITIONS], grad_row: &mut [[i8; 2]], inner: &mut Vec<[i32; 2]>) {
        let Self { mean, levels, w, y, .. } = *self;
        if self.inner_row() {
            sobel_row(mean, w, y, inner);
        }
        for (x, gradient) in grad_row.iter_mut().enumerate() {
            let i = y * w + x;
            if levels[i] == NOT_FLAT {
                continue;
            }
            let pos = position(y, x);
            let g = self.gradient_at(x, inner);
            let tol = MOTION_TOLERANCE * self.sd(pos, i);
            *gradient = quantised(g, tol, units_per_dn[pos][mean[i] as usize]);
        }
    }
}

/// Whether registration reads row `y`: every fourth row pair of large frames (`row_step` 4),
/// every row of small ones.
fn sampled(y: usize, row_step: usize) -> bool {
    (y / 2).is_multiple_of(row_step)
}

/// A clean image's per-pixel gradients ([`MotionProbe::gradients`]), computed on first use:
/// only a frame that moved reads them. Derived data: it never takes part in a comparison or a
/// checkpoint (two probes are equal whether or not either has computed it).
#[derive(Debug, Clone, Default)]
pub(crate) struct GradientCache(OnceLock<Vec<[i8; 2]>>);

impl PartialEq for GradientCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// The gradient `g` (DN per pixel) in units of `tol / GRADIENT_UNITS`, rounded half away from
/// zero, `[i8::MIN, 0]` where either component is beyond ±127: `round(g / tol · GRADIENT_UNITS)`
/// exactly. The product with `per_dn` (`GRADIENT_UNITS / tol`, rounded) is within a few units
/// in the last place of that quotient (under 10⁻¹³ below 128), so wherever it lies further than
/// [`QUANTISE_MARGIN`] from every half-integer and from ±127 it rounds and range-tests as the
/// quotient does; the rare values that close are decided by the division itself. Two
/// multiplications instead of two divisions per flat pixel of a 12 MP clean image.
#[inline]
fn quantised(g: [f64; 2], tol: f64, per_dn: f64) -> [i8; 2] {
    const LIMIT: f64 = 127.0;
    let p = [g[0] * per_dn, g[1] * per_dn];
    let a = [p[0].abs(), p[1].abs()];
    if a[0] > LIMIT + QUANTISE_MARGIN || a[1] > LIMIT + QUANTISE_MARGIN {
        return [i8::MIN, 0];
    }
    // Below 128 in magnitude: truncation and its fraction are exact, and nothing saturates.
    let t = [p[0] as i64, p[1] as i64];
    let f = [p[0] - t[0] as f64, p[1] - t[1] as f64];
    let near = |a: f64, f: f64| (a - LIMIT).abs() <= QUANTISE_MARGIN || (f.abs() - 0.5).abs() <= QUANTISE_MARGIN;
    if near(a[0], f[0]) || near(a[1], f[1]) {
        let q = [g[0] / tol * GRADIENT_UNITS as f64, g[1] / tol * GRADIENT_UNITS as f64];
        return if q[0].abs() > LIMIT || q[1].abs() > LIMIT {
            [i8::MIN, 0]
        } else {
            [round_half_away(q[0]) as i8, round_half_away(q[1]) as i8]
        };
    }
    let round = |t: i64, f: f64| (t + (f > 0.5) as i64 - (f < -0.5) as i64) as i8;
    [round(t[0], f[0]), round(t[1], f[1])]
}

/// How close to a rounding boundary (DN in gradient units) [`quantised`]'s product may come
/// before the division decides: far above the product's error, far below any spacing of
/// values that matters.
const QUANTISE_MARGIN: f64 = 1e-9;

/// Whether `hypot(g) > t` (`t > 0`), by the squares where they decide it beyond their rounding,
/// else by `hypot` itself.
#[inline]
fn hypot_above(g: [f64; 2], t: f64) -> bool {
    let (s, t2) = (g[0] * g[0] + g[1] * g[1], t * t);
    if s > t2 * (1.0 + 1e-9) {
        true
    } else if s < t2 * (1.0 - 1e-9) {
        false
    } else {
        g[0].hypot(g[1]) > t
    }
}

/// The numerators of [`sobel`] away from the borders (its divisor is 16 there: sixteenths of a
/// DN per pixel) for row `y` (2 ≤ y < h − 2) from column 2 to `w − 3`: `out[x − 2]`. Integer
/// sums over whole rows, which the compiler vectorises; each is the exact integer the f64 sums
/// of [`sobel`] make (every term is an integer of magnitude below 2¹⁸, exact in both types),
/// so `out / 16.0` is [`sobel`] bit for bit.
fn sobel_row(mean: &[u16], w: usize, y: usize, out: &mut Vec<[i32; 2]>) {
    out.clear();
    if w < 5 {
        return;
    }
    let n = w - 4;
    let row = |yy: usize| &mean[yy * w..yy * w + w];
    let (up, mid, down) = (row(y - 2), row(y), row(y + 2));
    let (up_m, up_c, up_p) = (&up[..n], &up[2..2 + n], &up[4..4 + n]);
    let (mid_m, mid_p) = (&mid[..n], &mid[4..4 + n]);
    let (down_m, down_c, down_p) = (&down[..n], &down[2..2 + n], &down[4..4 + n]);
    out.extend((0..n).map(|k| {
        let v = |r: &[u16]| r[k] as i32;
        let gx = v(up_p) - v(up_m) + 2 * (v(mid_p) - v(mid_m)) + v(down_p) - v(down_m);
        let gy = v(down_m) - v(up_m) + 2 * (v(down_c) - v(up_c)) + v(down_p) - v(up_p);
        [gx, gy]
    }));
}

impl MotionProbe {
    /// The probe of a closed reference burst: `mean` is its rounded mean at every pixel,
    /// `levels` the clean image with [`NOT_FLAT`] where not flat, `flat` what the flat test
    /// measured, `clip` the level above which values bend. Its per-pixel gradients are made
    /// when first asked for ([`MotionProbe::gradients`]).
    pub fn new(
        mean: Vec<u16>,
        levels: &[u16],
        width: usize,
        height: usize,
        frames: u32,
        flat: &FlatReport,
        groups: &Groups,
        clip: f32,
    ) -> Self {
        let (w, h) = (width, height);
        // One frame's noise SD per position and level, looked up per pixel below.
        let tolerance: [Vec<f32>; POSITIONS] = std::array::from_fn(|pos| {
            (0..=groups.white as usize)
                .map(|l| (MOTION_TOLERANCE * frame_sd(flat, groups, frames, pos, l as f64)) as f32)
                .collect()
        });
        // Registration reads every fourth row pair of large frames.
        let row_step = if h > 512 { 4 } else { 1 };
        // Bands of rows in parallel, their edges and anchors joined in row order.
        let bands: Vec<BandSamples> = (0..h.div_ceil(BAND_ROWS))
            .into_par_iter()
            .map(|b| {
                let rows = (b * BAND_ROWS..((b + 1) * BAND_ROWS).min(h)).filter(|&y| sampled(y, row_step));
                let mut edges: Vec<u32> = Vec::new();
                let first = b * BAND_ROWS;
                let mut anchors = AnchorBits::new(first * w, (((b + 1) * BAND_ROWS).min(h) - first) * w);
                let mut inner = Vec::with_capacity(w);
                for y in rows {
                    let row = ProbeRow { mean: &mean, levels, w, h, y, tolerance: &tolerance };
                    row.samples(frames, clip, &mut edges, &mut anchors, &mut inner);
                }
                (edges, anchors)
            })
            .collect();
        // Thinned across the bands in row order, without joining them first (the anchors are
        // every flat pixel of the sampled rows: megabytes for the thousand kept).
        let mut samples: Vec<u32> = thin_parts(bands.iter().map(|b| b.0.as_slice()), MAX_EDGE_SAMPLES);
        let anchors_from = samples.len();
        let anchor_bits: Vec<AnchorBits> = bands.into_iter().map(|b| b.1).collect();
        let anchors = thin_anchors(&anchor_bits, MAX_ANCHOR_SAMPLES);
        samples.extend_from_slice(&anchors);
        // Each kept anchor's noise SD, as the row pass reads it ([`ProbeRow::sd`]).
        let anchor_sd: Vec<f32> = anchors
            .iter()
            .map(|&i| {
                let i = i as usize;
                let row = ProbeRow { mean: &mean, levels, w, h, y: i / w, tolerance: &tolerance };
                row.sd(position(i / w, i % w), i) as f32
            })
            .collect();
        Self { mean, samples, anchors_from, anchor_sd, gradient: GradientCache::default(), tolerance }
    }

    /// Per pixel, the clean level's gradient `[∂x, ∂y]` in units of the pixel's tolerance
    /// ([`MOTION_TOLERANCE`] SD of one frame's noise at its level) per 8 px: a shift `u` changes
    /// the pixel by more than its tolerance when `|g · u| > 8`. `[i8::MIN, 0]` where the
    /// gradient is beyond the range (more than 16 tolerances per pixel); `[0, 0]` for pixels
    /// not flat. `levels`: the clean image the probe was made with (`width` wide). Made on the
    /// first call (only a frame that moved needs them: 2 bytes a pixel) and kept.
    pub fn gradients(&self, levels: &[u16], width: usize) -> &[[i8; 2]] {
        self.gradient.0.get_or_init(|| {
            let (w, mean, tolerance) = (width, &self.mean, &self.tolerance);
            let h = mean.len().checked_div(w).unwrap_or(0);
            let units_per_dn: [Vec<f64>; POSITIONS] = std::array::from_fn(|pos| {
                tolerance[pos]
                    .iter()
                    .map(|&t| GRADIENT_UNITS as f64 / (MOTION_TOLERANCE * (t as f64 / MOTION_TOLERANCE)))
                    .collect()
            });
            let mut gradient = vec![[0i8; 2]; w * h];
            gradient.par_chunks_mut(BAND_ROWS * w.max(1)).enumerate().for_each(|(b, rows)| {
                let mut inner = Vec::with_capacity(w);
                for (dy, grad_row) in rows.chunks_mut(w.max(1)).enumerate() {
                    let row = ProbeRow { mean, levels, w, h, y: b * BAND_ROWS + dy, tolerance };
                    row.gradients(&units_per_dn, grad_row, &mut inner);
                }
            });
            gradient
        })
    }
}

/// Every k-th of the parts' elements joined in order (counted across the parts, from the first),
/// so that at most `max` remain, without joining them.
fn thin_parts<'a, T: Copy + 'a>(parts: impl Iterator<Item = &'a [T]> + Clone, max: usize) -> Vec<T> {
    let total: usize = parts.clone().map(<[T]>::len).sum();
    let k = if total <= max { 1 } else { total.div_ceil(max) };
    let mut out = Vec::with_capacity(total.div_ceil(k));
    // The global index of each part's first element; its first kept element is the next
    // multiple of k from there.
    let mut start = 0usize;
    for p in parts {
        let skip = (k - start % k) % k;
        out.extend(p.iter().skip(skip).step_by(k).copied());
        start += p.len();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Every k-th of `v` so that at most `max` remain: the thinning of the joined bands that
    /// `thin_parts` stands for.
    fn thin<T>(v: Vec<T>, max: usize) -> Vec<T> {
        if v.len() <= max {
            return v;
        }
        let k = v.len().div_ceil(max);
        v.into_iter().step_by(k).collect()
    }

    /// Thinning the bands in place of their join keeps exactly what thinning the join keeps,
    /// whatever the parts' lengths (empty ones among them) and `max`. Thinning each part on
    /// its own (the same k, restarting at every part's first element) keeps other elements
    /// wherever a part's length is not a multiple of k, and the test asserts such cases occur.
    #[test]
    fn thinning_parts_is_thinning_their_join() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut restart_differs = 0;
        for _ in 0..2000 {
            let n = rng.random_range(0..12);
            let mut next = 0u32;
            let parts: Vec<Vec<u32>> = (0..n)
                .map(|_| {
                    let len = if rng.random_bool(0.2) { 0 } else { rng.random_range(0..300) };
                    (0..len)
                        .map(|_| {
                            next += 1;
                            next
                        })
                        .collect()
                })
                .collect();
            let joined: Vec<u32> = parts.iter().flatten().copied().collect();
            let max = rng.random_range(1..400);
            let got = thin_parts(parts.iter().map(Vec::as_slice), max);
            assert_eq!(got, thin(joined.clone(), max), "{} parts, {} elements, max {max}", parts.len(), joined.len());
            let k = if joined.len() <= max { 1 } else { joined.len().div_ceil(max) };
            let restarted: Vec<u32> = parts.iter().flat_map(|p| p.iter().step_by(k).copied()).collect();
            restart_differs += usize::from(restarted != got);
        }
        assert!(restart_differs > 100, "{restart_differs}");
    }

    /// The division `quantised` stands for.
    fn divided(g: [f64; 2], tol: f64) -> [i8; 2] {
        let q = [g[0] / tol * GRADIENT_UNITS as f64, g[1] / tol * GRADIENT_UNITS as f64];
        if q[0].abs() > 127.0 || q[1].abs() > 127.0 {
            [i8::MIN, 0]
        } else {
            [round_half_away(q[0]) as i8, round_half_away(q[1]) as i8]
        }
    }

    /// The gradients made on first use are, at every flat pixel, the Sobel gradient over the
    /// pixel's tolerance rounded (`divided`, the definition), and `[0, 0]` elsewhere: on a
    /// random image of 150 rows (three bands of the parallel pass, borders included) with a
    /// random flat mask. A probe does not make them until asked, makes them once, and two
    /// probes compare equal either way. A pass that filled the pixels not flat, or read a
    /// band's rows from the image's top, differs at thousands of pixels.
    #[test]
    fn gradients_are_the_definition_at_every_flat_pixel() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let (w, h) = (53usize, 150usize);
        let mean: Vec<u16> =
            (0..w * h).map(|i| (100 + (i % w) * 5 + (i / w) * 2) as u16 + rng.random_range(0..40)).collect();
        let levels: Vec<u16> = mean.iter().map(|&m| if rng.random_bool(0.8) { m } else { NOT_FLAT }).collect();
        let groups = Groups { black: [0.0; POSITIONS], white: 1023 };
        let mut flat = FlatReport::default();
        flat.mean_noise = [[0.5, 0.01, 0.0]; POSITIONS];
        flat.mean_noise_groups = vec![f32::NAN; POSITIONS * crate::calibrate::flat::GROUPS];
        let probe = MotionProbe::new(mean.clone(), &levels, w, h, 4, &flat, &groups, 1000.0);
        assert!(probe.gradient.0.get().is_none(), "made before it was asked for");
        let unmade = probe.clone();
        let got = probe.gradients(&levels, w);
        assert!(std::ptr::eq(got, probe.gradients(&levels, w)), "made twice");
        assert_eq!(probe, unmade);
        let (mut flat_pixels, mut nonzero) = (0, 0);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let want = if levels[i] == NOT_FLAT {
                    [0, 0]
                } else {
                    flat_pixels += 1;
                    let pos = position(y, x);
                    let tol = MOTION_TOLERANCE * (probe.tolerance[pos][mean[i] as usize] as f64 / MOTION_TOLERANCE);
                    divided(sobel(&mean, w, h, x, y), tol)
                };
                nonzero += (want != [0, 0]) as usize;
                assert_eq!(got[i], want, "pixel ({x}, {y})");
            }
        }
        assert!(flat_pixels > 5000 && nonzero > 5000, "{flat_pixels} flat, {nonzero} with a gradient");
    }

    /// The whole-row integer Sobel over 16 is `sobel` bit for bit at every pixel 2 px from the
    /// borders: on random 16-bit means, on means of only 0 and 65 535 (the largest sums either
    /// sign), and on a smooth ramp. A wrong tap (a swapped sign, the centre column's weight 1
    /// instead of 2, an off-by-one column) differs on most pixels of the random image.
    #[test]
    fn sobel_row_is_sobel() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (w, h) = (37, 11);
        let images: [Vec<u16>; 3] = [
            (0..w * h).map(|_| rng.random::<u16>()).collect(),
            (0..w * h).map(|_| if rng.random::<bool>() { u16::MAX } else { 0 }).collect(),
            (0..w * h).map(|i| ((i % w) * 1000 + (i / w) * 37) as u16).collect(),
        ];
        let mut row = Vec::new();
        let mut checked = 0;
        for mean in &images {
            for y in 2..h - 2 {
                sobel_row(mean, w, y, &mut row);
                assert_eq!(row.len(), w - 4);
                for x in 2..w - 2 {
                    let [gx, gy] = row[x - 2];
                    let want = sobel(mean, w, h, x, y);
                    assert_eq!([(gx as f64 / 16.0).to_bits(), (gy as f64 / 16.0).to_bits()], want.map(f64::to_bits));
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 3 * (h - 4) * (w - 4));
        // Too narrow for an inner column: nothing.
        sobel_row(&images[0][..4 * h], 4, 2, &mut row);
        assert!(row.is_empty());
    }

    /// `quantised` is the division exactly: on every Sobel value (sixteenths of a DN) up to
    /// ±40 DN/px against tolerances that are powers of two (the quotients then hit half-integers
    /// and ±127 exactly: the division's path), tolerances a frame's noise gives (an f32 times a
    /// quarter), and random ones; each component against the other's extremes.
    #[test]
    fn quantised_is_the_division() {
        let mut rng = ChaCha8Rng::seed_from_u64(26);
        let mut tols: Vec<f64> = vec![0.0625, 0.125, 0.25, 0.5, 1.0, 2.0, 0.75, 1.5, 3.0, 0.3];
        tols.extend((0..40).map(|_| (rng.random_range(0.25f64..60.0) as f32) as f64 * MOTION_TOLERANCE));
        let (mut checked, mut at_boundary) = (0u64, 0u64);
        for &tol in &tols {
            let per_dn = GRADIENT_UNITS as f64 / tol;
            for s in -640i32..=640 {
                let g0 = s as f64 / 16.0;
                for g1 in [0.0, g0, -g0, 1.0 / 16.0, 40.0, -40.0] {
                    for g in [[g0, g1], [g1, g0]] {
                        assert_eq!(quantised(g, tol, per_dn), divided(g, tol), "g {g:?}, tol {tol}");
                        checked += 1;
                        let q = g[0] / tol * GRADIENT_UNITS as f64;
                        at_boundary += (q.abs() == 127.0 || (q.abs().fract() == 0.5)) as u64;
                    }
                }
            }
        }
        assert!(checked > 500_000, "{checked}");
        assert!(at_boundary > 1_000, "only {at_boundary} values on a rounding boundary");
    }
}
