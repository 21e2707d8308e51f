//! Dark frames (lens covered): the fixed pattern per ISO (method.md, "Fixed pattern").
//!
//! [`check_dark`] tells a dark frame from a lit one by its content; a [`DarkBurst`] sums one
//! ISO's dark frames per pixel (O(pixels), whatever the number of frames) and closes into that
//! ISO's [`FixedPattern`]: each pixel's mean over the burst, less its frame's mean per CFA
//! position (the frame offsets are not part of the pattern), split into a coarse shading grid
//! and the pixel-to-pixel residual, whose distribution is stored with the sampling noise of a
//! mean of `n` frames taken out.

use serde::{Deserialize, Serialize};

use crate::calibrate::frame::FrameView;
use crate::error::SessionError;
use crate::model::histogram::NoiseHistogram;
use crate::model::layout::{Binning, POSITIONS, SensorLayout, position};
use crate::model::structure::{FixedPattern, OffsetDistribution, PATTERN_QUANTILES};

/// Shading grid cells (rows, columns) per CFA position.
pub const SHADING_GRID: [u32; 2] = [12, 16];
/// The most frames one dark burst takes (its sums are u32).
pub const MAX_DARK_FRAMES: u32 = 60_000;
/// A dark frame's mean is at most this share of the range above black.
const DARK_LEVEL: f64 = 0.02;
/// A dark frame's block means stay within this share of the range (plus six times their sampling
/// noise) of its mean: dark shading at short exposures is a fraction of this, while even a scene
/// four stops under a mid-grey exposure has patches several percent apart.
const DARK_SPREAD: f64 = 0.002;
/// Blocks per side of the darkness test.
const TEST_BLOCKS: usize = 8;

/// Each CFA position's mean above black (DN) of a frame, from one pass of exact integer sums
/// (0 for a position the frame has no pixel of). What [`surely_lit`] tests, and what a folder's
/// driver compares a dim EV step with the dark burst by (method.md, "Dim steps and dark frames").
pub fn frame_level(frame: &FrameView<'_>, black: &[f32; POSITIONS]) -> [f64; POSITIONS] {
    let (w, h) = (frame.width(), frame.height());
    let mut sums = [0u64; POSITIONS];
    for y in 0..h {
        let row = frame.row(y);
        // Per chunk, 32-bit sums (32768 codes of at most 65535 fit), which the compiler vectorises.
        for chunk in row.chunks(1 << 16) {
            let (mut even, mut odd) = (0u32, 0u32);
            for pair in chunk.chunks_exact(2) {
                even += pair[0] as u32;
                odd += pair[1] as u32;
            }
            if let [.., last] = chunk
                && chunk.len() % 2 == 1
            {
                even += *last as u32;
            }
            // Every chunk starts at an even column.
            sums[position(y, 0)] += even as u64;
            sums[position(y, 1)] += odd as u64;
        }
    }
    std::array::from_fn(|p| {
        let rows = (h + 1 - (p >> 1)) / 2;
        let cols = (w + 1 - (p & 1)) / 2;
        let n = (rows * cols) as f64;
        if n == 0.0 { 0.0 } else { sums[p] as f64 / n - black[p] as f64 }
    })
}

/// Whether [`check_dark`] certainly fails on a frame of this [`frame_level`] because of its first
/// test alone: some position's mean above black is over the dark level, by a margin that summing
/// exact integers here rather than `f64` differences there cannot cross (a few 10⁻⁵ DN at most
/// on 2²⁴ pixels). A folder's driver asks it of every lit frame before the whole test (blocks,
/// neighbour differences), which is then left to the frames that may be dark.
pub fn lit_by_level(level: &[f64; POSITIONS], black: &[f32; POSITIONS], layout: &SensorLayout) -> bool {
    (0..POSITIONS).any(|p| {
        let range = (layout.white as f64 - black[p] as f64).max(1.0);
        level[p] > DARK_LEVEL * range + 1e-3 + 1e-9 * range
    })
}

/// [`lit_by_level`] of the frame's [`frame_level`]: one pass of integer sums.
pub fn surely_lit(frame: &FrameView<'_>, black: &[f32; POSITIONS], layout: &SensorLayout) -> bool {
    lit_by_level(&frame_level(frame, black), black, layout)
}

/// Checks that a frame is dark: close to black everywhere. A scene (even a dim one) has patches
/// whose means differ by more than the noise allows; a covered lens does not.
pub fn check_dark(
    frame: &FrameView<'_>,
    black: &[f32; POSITIONS],
    layout: &SensorLayout,
    iso: u32,
) -> Result<(), SessionError> {
    let (w, h) = (frame.width(), frame.height());
    let mut blocks = vec![[0f64; 2]; TEST_BLOCKS * TEST_BLOCKS * POSITIONS];
    let mut total = [[0f64; 3]; POSITIONS];
    // The noise from same-colour neighbour differences (a scene's patches do not enter it).
    let mut diffs = [[0f64; 2]; POSITIONS];
    for y in 0..h {
        let row = frame.row(y);
        let by = y * TEST_BLOCKS / h;
        for (x, pair) in row.windows(3).enumerate() {
            let d = pair[2] as f64 - pair[0] as f64;
            let s = &mut diffs[position(y, x)];
            s[0] += d * d;
            s[1] += 1.0;
        }
        for (x, &v) in row.iter().enumerate() {
            let p = position(y, x);
            let v = v as f64 - black[p] as f64;
            let b = &mut blocks[((by * TEST_BLOCKS) + x * TEST_BLOCKS / w) * POSITIONS + p];
            b[0] += v;
            b[1] += 1.0;
            let t = &mut total[p];
            t[0] += v;
            t[1] += v * v;
            t[2] += 1.0;
        }
    }
    for p in 0..POSITIONS {
        let [s, s2, n] = total[p];
        if n == 0.0 {
            continue;
        }
        let range = (layout.white as f64 - black[p] as f64).max(1.0);
        let mean = s / n;
        if mean > DARK_LEVEL * range {
            return Err(SessionError::NotDark {
                iso,
                why: format!(
                    "its mean is {mean:.1} DN above black ({:.1} % of the range; a covered lens stays under {:.0} %)",
                    100.0 * mean / range,
                    100.0 * DARK_LEVEL
                ),
            });
        }
        let sd = match diffs[p] {
            [d2, m] if m > 0.0 => (d2 / m / 2.0).sqrt(),
            _ => (s2 / n - mean * mean).max(0.0).sqrt(),
        };
        for b in blocks.iter().skip(p).step_by(POSITIONS) {
            if b[1] == 0.0 {
                continue;
            }
            let m = b[0] / b[1];
            let allowed = DARK_SPREAD * range + 6.0 * sd / b[1].sqrt();
            if (m - mean).abs() > allowed {
                return Err(SessionError::NotDark {
                    iso,
                    why: format!(
                        "parts of it differ from its mean by {:.1} DN (a covered lens allows {allowed:.1}): a scene shows through",
                        (m - mean).abs()
                    ),
                });
            }
        }
    }
    Ok(())
}

/// The reference ISO's pattern, pixel by pixel ([`DarkBurst::pattern_map`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReferencePattern {
    pub iso: u32,
    pub map: Vec<f32>,
    /// Per position, the sampling variance of the per-pixel means (DN²).
    pub sampling_var: [f64; POSITIONS],
}

/// One ISO's dark frames being summed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DarkBurst {
    pub iso: u32,
    width: usize,
    height: usize,
    frames: u32,
    sum: Vec<u32>,
    /// The previous frame (consecutive differences give the temporal noise).
    previous: Vec<u16>,
    /// Per position, the sum over frames of each frame's mean above black.
    means: [f64; POSITIONS],
    /// Per consecutive pair of frames and position, the variance within the frame of their
    /// difference (twice the temporal variance). Its median is the estimate: one abnormal frame
    /// (a first frame after a reset, measured on real dark bursts at 163 DN² against 20–27 for
    /// the others) spoils two pairs, not the estimate (anchored on the first frame, it made the
    /// temporal SD 3.6× too large and the pattern SD 18 % too small).
    pair_var: Vec<[f64; POSITIONS]>,
}

impl DarkBurst {
    pub fn new(layout: &SensorLayout, iso: u32) -> Self {
        let (w, h) = (layout.width as usize, layout.height as usize);
        Self {
            iso,
            width: w,
            height: h,
            frames: 0,
            sum: vec![0; w * h],
            previous: Vec::new(),
            means: [0.0; POSITIONS],
            pair_var: Vec::new(),
        }
    }

    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// The temporal variance at a position: half the median over consecutive pairs of their
    /// difference's variance.
    fn temporal_var(&self, pos: usize) -> f64 {
        let mut v: Vec<f64> = self.pair_var.iter().map(|p| p[pos]).collect();
        v.sort_by(f64::total_cmp);
        let k = v.len();
        if k == 0 {
            return 0.0;
        }
        let median = if k % 2 == 1 { v[k / 2] } else { 0.5 * (v[k / 2 - 1] + v[k / 2]) };
        median / 2.0
    }

    /// Adds a dark frame (already checked: size, darkness).
    pub fn push(&mut self, frame: &FrameView<'_>, black: &[f32; POSITIONS]) -> Result<(), SessionError> {
        if self.frames >= MAX_DARK_FRAMES {
            return Err(SessionError::Metadata(format!(
                "more than {MAX_DARK_FRAMES} dark frames at ISO {}: a dark burst needs 8–32",
                self.iso
            )));
        }
        let w = self.width;
        let first = self.frames == 0;
        if first {
            self.previous = vec![0; w * self.height];
        }
        let mut s = [[0f64; 2]; POSITIONS];
        let mut d = [[0f64; 3]; POSITIONS];
        for y in 0..self.height {
            let row = frame.row(y);
            let at = y * w;
            for (x, &v) in row.iter().enumerate() {
                let p = position(y, x);
                self.sum[at + x] += v as u32;
                s[p][0] += v as f64;
                s[p][1] += 1.0;
                let before = std::mem::replace(&mut self.previous[at + x], v);
                if !first {
                    let e = v as f64 - before as f64;
                    d[p][0] += e;
                    d[p][1] += e * e;
                    d[p][2] += 1.0;
                }
            }
        }
        for p in 0..POSITIONS {
            if s[p][1] > 0.0 {
                self.means[p] += s[p][0] / s[p][1] - black[p] as f64;
            }
        }
        if !first {
            self.pair_var.push(std::array::from_fn(|p| {
                let [sum, sq, n] = d[p];
                if n > 0.0 { sq / n - (sum / n).powi(2) } else { 0.0 }
            }));
        }
        self.frames += 1;
        Ok(())
    }

    /// The noise at black that the burst measures, as the pack's bins count noise: per CFA
    /// position, the histogram of `v − round(m)` over the pixels whose level `round(m)` falls in
    /// bin 0 of `binning` (black's bin, which also takes the levels below black), `v` the pixel in
    /// the burst's last frame and `m` its mean over the other frames (an estimate of its clean
    /// level that the sample itself is not part of). `None` below three frames. Where a session's
    /// darkest step holds only dark frames, this is the only measurement of bin 0
    /// ([`crate::calibrate::estimate::estimate_position_with_black`]).
    ///
    /// `m` carries `σ²/(n − 1)` of sampling variance (3 % of `σ²` for 32 frames) and is rounded
    /// to a whole level as a lit sample's clean level is; on a sub-DN sensor the sample is then
    /// `round(c + e) − round(c)`, whose spread depends on where the pixels' clean levels `c`
    /// sit in their codes, which no variance law can tell.
    pub fn black_noise(&self, binning: &Binning) -> Option<[NoiseHistogram; POSITIONS]> {
        if self.frames < 3 || self.previous.len() != self.sum.len() {
            return None;
        }
        let w = self.width;
        let others = (self.frames - 1) as f64;
        let mut out: [NoiseHistogram; POSITIONS] = std::array::from_fn(|_| NoiseHistogram::default());
        for (i, (&s, &v)) in self.sum.iter().zip(&self.previous).enumerate() {
            let p = position(i / w, i % w);
            let level = ((s - v as u32) as f64 / others).round();
            if binning.bin(p, level as f32) == 0 {
                out[p].add(v as i32 - level as i32);
            }
        }
        Some(out)
    }

    /// Each pixel's mean over the burst minus its position's mean (DN, row-major), and the
    /// sampling variance of those means per position: what a later ISO's pattern is compared
    /// with, pixel by pixel ([`Self::close`]).
    pub fn pattern_map(&self, black: &[f32; POSITIONS]) -> Option<ReferencePattern> {
        if self.frames < 2 || self.pair_var.is_empty() {
            return None;
        }
        let w = self.width;
        let n = self.frames as f64;
        let offset: [f64; POSITIONS] = std::array::from_fn(|p| self.means[p] / n + black[p] as f64);
        let map =
            (0..self.sum.len()).map(|i| (self.sum[i] as f64 / n - offset[position(i / w, i % w)]) as f32).collect();
        let sampling_var = std::array::from_fn(|p| self.temporal_var(p) / n);
        Some(ReferencePattern { iso: self.iso, map, sampling_var })
    }

    /// The burst's pattern (`None` below two frames: the temporal noise is then unknown). With
    /// the reference ISO's pattern map, what the pixel PMFs hold of this pattern (its change
    /// from the reference's, pixel by pixel) is measured too; otherwise it is derived when the
    /// pack is assembled. The significance is set then.
    pub fn close(&self, black: &[f32; POSITIONS], reference: Option<&ReferencePattern>) -> Option<FixedPattern> {
        let own = self.pattern_map(black)?;
        let (w, h) = (self.width, self.height);
        let pattern = |y: usize, x: usize| own.map[y * w + x] as f64;
        let [gh, gw] = SHADING_GRID.map(|v| v as usize);
        let (gh, gw) = (gh.min(h / 2).max(1), gw.min(w / 2).max(1));
        // Per cell and position: Σ pattern and count; per position: Σ pattern², count.
        let mut cells = vec![[0f64; 2]; gh * gw * POSITIONS];
        let mut spread = [[0f64; 2]; POSITIONS];
        for y in 0..h {
            let cy = y * gh / h;
            for x in 0..w {
                let (p, v) = (position(y, x), pattern(y, x));
                let c = &mut cells[(cy * gw + x * gw / w) * POSITIONS + p];
                c[0] += v;
                c[1] += 1.0;
                spread[p][0] += v * v;
                spread[p][1] += 1.0;
            }
        }
        let mut shading: [Vec<f32>; POSITIONS] = std::array::from_fn(|p| {
            cells
                .iter()
                .skip(p)
                .step_by(POSITIONS)
                .map(|c| if c[1] > 0.0 { (c[0] / c[1]) as f32 } else { 0.0 })
                .collect()
        });
        let temporal_var: [f64; POSITIONS] = std::array::from_fn(|p| self.temporal_var(p));
        // A cell's mean carries the noise of the pixels in it (their own pattern and the
        // sampling noise of their means): the grid's spread is shrunk by that much before the
        // residuals are taken against it, so that variance stays with the residual (against the
        // raw grid, a 192 × 128 sensor lost 3 % of its pattern variance into cell means).
        for (p, grid) in shading.iter_mut().enumerate() {
            let per_cell = spread[p][1] / grid.len().max(1) as f64;
            let noise = spread[p][0] / spread[p][1].max(1.0) / per_cell.max(1.0);
            let m = grid.iter().map(|&v| v as f64).sum::<f64>() / grid.len().max(1) as f64;
            let var = grid.iter().map(|&v| (v as f64 - m).powi(2)).sum::<f64>() / grid.len().max(1) as f64;
            let k = if var > 0.0 { (1.0 - noise / var).max(0.0).sqrt() } else { 0.0 };
            for v in grid.iter_mut() {
                *v = ((*v as f64 - m) * k) as f32;
            }
        }
        let empty = OffsetDistribution {
            quantiles: vec![0.0; 2],
            count: 0,
            measured_var: 0.0,
            sampling_var: 0.0,
            significant: false,
        };
        let mut fp = FixedPattern {
            pixels: std::array::from_fn(|_| empty.clone()),
            shading,
            grid: [gh as u32, gw as u32],
            size: [h as u32, w as u32],
            frames: self.frames,
            temporal_var,
            in_pixel_noise: std::array::from_fn(|_| empty.clone()),
            significant: false,
        };
        let mut residuals: [Vec<f32>; POSITIONS] = std::array::from_fn(|_| Vec::with_capacity(w * h / POSITIONS + w));
        for y in 0..h {
            let lines: [Option<Vec<f64>>; 2] = std::array::from_fn(|px| fp.shading_line(position(y, px), y));
            for x in 0..w {
                let shade = lines[x & 1].as_deref().map_or(0.0, |l| fp.shading_on_line(l, x));
                residuals[position(y, x)].push((pattern(y, x) - shade) as f32);
            }
        }
        for (p, mut r) in residuals.into_iter().enumerate() {
            fp.pixels[p] = pattern_distribution(&mut r, own.sampling_var[p]);
        }
        if let Some(r) = reference.filter(|r| r.map.len() == w * h && r.iso != self.iso) {
            let mut diffs: [Vec<f32>; POSITIONS] = std::array::from_fn(|_| Vec::with_capacity(w * h / POSITIONS + w));
            for y in 0..h {
                for x in 0..w {
                    diffs[position(y, x)].push((pattern(y, x) - r.map[y * w + x] as f64) as f32);
                }
            }
            for (p, mut d) in diffs.into_iter().enumerate() {
                let mut dist = pattern_distribution(&mut d, own.sampling_var[p] + r.sampling_var[p]);
                dist.significant = true;
                fp.in_pixel_noise[p] = dist;
            }
        }

        Some(fp)
    }
}

/// A pattern residual's distribution: its quantile function with the mean removed and shrunk
/// about zero by `√(1 − sampling / measured)` (the sampling noise of the per-pixel means taken
/// out, the shape kept).
pub(crate) fn pattern_distribution(r: &mut [f32], sampling_var: f64) -> OffsetDistribution {
    let len = r.len();
    if len < 2 {
        return OffsetDistribution {
            quantiles: vec![0.0; 2],
            count: len as u64,
            measured_var: 0.0,
            sampling_var,
            significant: false,
        };
    }
    let mean = r.iter().map(|&v| v as f64).sum::<f64>() / len as f64;
    let measured_var = r.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / (len - 1) as f64;
    r.sort_unstable_by(f32::total_cmp);
    let own = (measured_var - sampling_var).max(0.0);
    let q = PATTERN_QUANTILES;
    // The end points are the quantiles half a step in, not the extremes: one hot pixel would
    // otherwise stretch the last step over 1/4096 of all draws.
    let edge = 0.5 / (q - 1) as f64;
    let raw: Vec<f64> = (0..q)
        .map(|i| {
            let u = (i as f64 / (q - 1) as f64).clamp(edge, 1.0 - edge);
            r[((u * (len - 1) as f64).round() as usize).min(len - 1)] as f64 - mean
        })
        .collect();
    // Scaled about its mean so that the quantile function's own variance (linear between the
    // points, as synthesis draws it) is the pattern's: the trimmed ends and the interpolation
    // otherwise lose 2–3 % of it.
    let (m, v) = piecewise_linear_moments(&raw);
    let k = if v > 0.0 { (own / v).sqrt() } else { 0.0 };
    let quantiles = raw.iter().map(|&x| ((x - m) * k) as f32).collect();
    OffsetDistribution { quantiles, count: len as u64, measured_var, sampling_var, significant: false }
}

/// Mean and variance of `Q(U)`, `U` uniform, for the quantile function linear between the
/// equally spaced points `q`.
fn piecewise_linear_moments(q: &[f64]) -> (f64, f64) {
    let segs = q.len().saturating_sub(1).max(1) as f64;
    let (mut m1, mut m2) = (0.0, 0.0);
    for w in q.windows(2) {
        let (a, b) = (w[0], w[1]);
        m1 += (a + b) / 2.0;
        m2 += (a * a + a * b + b * b) / 3.0;
    }
    let (m1, m2) = (m1 / segs, m2 / segs);
    (m1, (m2 - m1 * m1).max(0.0))
}

/// The distribution of `Q_a(U) − Q_b(U)` plus the shading difference over the grid's cells
/// (the two patterns coupled through one uniform per pixel, as synthesis couples them): what a
/// pixel PMF measured against a clean image at ISO `b` holds of ISO `a`'s pattern.
pub(crate) fn difference(a: &FixedPattern, b: Option<&FixedPattern>, pos: usize) -> OffsetDistribution {
    let q = PATTERN_QUANTILES;
    let grid_a = &a.shading[pos];
    let same_grid = b.is_some_and(|b| b.grid == a.grid && b.shading[pos].len() == grid_a.len());
    let cells: Vec<f64> = (0..grid_a.len().max(1))
        .map(|c| {
            let sa = grid_a.get(c).copied().unwrap_or(0.0) as f64;
            let sb = match b {
                Some(b) if same_grid => b.shading[pos][c] as f64,
                _ => 0.0,
            };
            sa - sb
        })
        .collect();
    let mut values = Vec::with_capacity(q * cells.len());
    for i in 0..q {
        let u = i as f64 / (q - 1) as f64;
        let d = a.pixels[pos].at(u) - b.map_or(0.0, |b| b.pixels[pos].at(u));
        values.extend(cells.iter().map(|s| (d + s) as f32));
    }
    let mut d = pattern_distribution(&mut values, 0.0);
    d.count = a.pixels[pos].count;
    d.significant = true;
    d
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::layout::CfaPattern;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn layout(w: u32, h: u32) -> SensorLayout {
        SensorLayout { width: w, height: h, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 }
    }

    fn gauss(rng: &mut ChaCha8Rng) -> f64 {
        let (u, v): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }

    /// Dark frames with a known pattern (a Laplace per-pixel part of SD `dsnu`, a corner glow of
    /// `glow` DN), temporal noise of SD `read`, and frame offsets: the pattern comes back with
    /// its variance and shape, the temporal noise taken out.
    #[test]
    fn recovers_a_known_pattern() {
        let (w, h) = (256usize, 192usize);
        let l = layout(w as u32, h as u32);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (dsnu, read, glow) = (1.5, 3.0, 3.0);
        let lap = |rng: &mut ChaCha8Rng| {
            let u: f64 = rng.random::<f64>() - 0.5;
            -(dsnu / 2f64.sqrt()) * u.signum() * (1.0f64 - 2.0 * u.abs()).max(1e-300).ln()
        };
        let pix: Vec<f64> = (0..w * h).map(|_| lap(&mut rng)).collect();
        let shade = |y: usize, x: usize| glow * (-((x as f64 / 40.0).powi(2) + (y as f64 / 40.0).powi(2))).exp();
        let mut burst = DarkBurst::new(&l, 1600);
        let frames = 16;
        for _ in 0..frames {
            let off = 2.0 * gauss(&mut rng);
            let data: Vec<u16> = (0..w * h)
                .map(|i| {
                    let (y, x) = (i / w, i % w);
                    (64.0 + off + pix[i] + shade(y, x) + read * gauss(&mut rng)).round().clamp(0.0, 1023.0) as u16
                })
                .collect();
            let view = FrameView::from_u16(&data, w, h, w).unwrap();
            check_dark(&view, &l.black, &l, 1600).unwrap();
            burst.push(&view, &l.black).unwrap();
        }
        let fp = burst.close(&l.black, None).unwrap();
        for p in 0..POSITIONS {
            // Temporal variance 9 (+ 1/12 rounding).
            assert!((fp.temporal_var[p] - 9.083).abs() < 0.3, "temporal {}", fp.temporal_var[p]);
            let v = fp.pixels[p].variance();
            assert!((v - dsnu * dsnu).abs() < 0.12 * dsnu * dsnu, "pixel var {v} vs {}", dsnu * dsnu);
            // Laplace: the quantile at 0.9 is b·ln 5 = 1.138·sd … a Gaussian's is 1.28·sd.
            let q90 = fp.pixels[p].at(0.9);
            assert!((q90 / dsnu - 1.138).abs() < 0.08, "q90/sd {}", q90 / dsnu);
        }
        // The glow is in the shading: the corner cell is well above the far one.
        let corner = fp.shading_at(0, 0, 0);
        let far = fp.shading_at(0, h - 1, w - 1);
        assert!(corner - far > 0.4 * glow, "corner {corner} far {far}");
    }

    /// One abnormal frame (the first after a reset: extra noise of SD 12 on a read noise of 3)
    /// moves the temporal variance and the pattern by little: the median of consecutive pairs.
    #[test]
    fn an_abnormal_first_frame_does_not_spoil_the_burst() {
        let (w, h) = (128usize, 96usize);
        let l = layout(w as u32, h as u32);
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let pix: Vec<f64> = (0..w * h).map(|_| 2.0 * gauss(&mut rng)).collect();
        let mut burst = DarkBurst::new(&l, 800);
        for k in 0..16 {
            let extra = if k == 0 { 12.0 } else { 0.0 };
            let data: Vec<u16> = (0..w * h)
                .map(|i| (100.0 + pix[i] + 3.0 * gauss(&mut rng) + extra * gauss(&mut rng)).round() as u16)
                .collect();
            burst.push(&FrameView::from_u16(&data, w, h, w).unwrap(), &l.black).unwrap();
        }
        let fp = burst.close(&l.black, None).unwrap();
        for p in 0..POSITIONS {
            assert!((fp.temporal_var[p] - 9.083).abs() < 0.8, "temporal {}", fp.temporal_var[p]);
            // The abnormal frame's extra variance, 144/16² = 0.56, stays in the means: 4 → ≈4.6.
            let v = fp.pixels[p].variance();
            assert!((3.6..5.2).contains(&v), "pattern var {v}");
            // The stored quantile function carries that variance (as synthesis draws it).
            let (_, qv) =
                piecewise_linear_moments(&fp.pixels[p].quantiles.iter().map(|&x| x as f64).collect::<Vec<_>>());
            assert!((qv / v - 1.0).abs() < 1e-3, "quantile variance {qv} vs {v}");
        }
    }

    #[test]
    fn a_scene_is_not_dark() {
        let (w, h) = (128usize, 96usize);
        let l = layout(w as u32, h as u32);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        // A dim chart: patches 0.5–3 % of the range above black.
        let data: Vec<u16> = (0..w * h)
            .map(|i| {
                let patch = ((i % w) / 32 + (i / w) / 32 * 4) as f64;
                (64.0 + 5.0 + patch * 2.0 + 2.0 * gauss(&mut rng)).round() as u16
            })
            .collect();
        let view = FrameView::from_u16(&data, w, h, w).unwrap();
        let e = check_dark(&view, &l.black, &l, 100).unwrap_err();
        assert!(e.to_string().contains("cover"), "{e}");
        let dark: Vec<u16> = (0..w * h).map(|_| (64.0 + 2.0 * gauss(&mut rng)).round() as u16).collect();
        check_dark(&FrameView::from_u16(&dark, w, h, w).unwrap(), &l.black, &l, 100).unwrap();
        let bright: Vec<u16> = vec![200; w * h];
        assert!(check_dark(&FrameView::from_u16(&bright, w, h, w).unwrap(), &l.black, &l, 100).is_err());
    }

    /// The quick test says "lit" only where the whole test fails on its mean (so a folder's
    /// frames are sorted as before): never on dark frames, nor on a frame whose mean sits just
    /// under the dark level, and on every frame clearly over it, at odd sizes too.
    #[test]
    fn surely_lit_only_where_the_mean_test_fails() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for (w, h) in [(128usize, 96usize), (127, 95), (33, 2)] {
            let l = layout(w as u32, h as u32);
            let range = l.white as f64 - 64.0;
            for level in [0.0, 0.5 * DARK_LEVEL, DARK_LEVEL - 0.2 / range, DARK_LEVEL + 0.2 / range, 0.1, 0.9] {
                let data: Vec<u16> = (0..w * h)
                    .map(|_| (64.0 + level * range + 2.0 * gauss(&mut rng)).round().clamp(0.0, 1023.0) as u16)
                    .collect();
                let view = FrameView::from_u16(&data, w, h, w).unwrap();
                let mean_over = (0..POSITIONS).any(|p| {
                    let (mut s, mut n) = (0.0, 0.0);
                    for y in (p >> 1..h).step_by(2) {
                        for x in (p & 1..w).step_by(2) {
                            s += data[y * w + x] as f64 - 64.0;
                            n += 1.0;
                        }
                    }
                    s / n > DARK_LEVEL * range + 1e-3
                });
                let lit = surely_lit(&view, &l.black, &l);
                assert_eq!(lit, mean_over, "{w}×{h} at {level}");
                if lit {
                    assert!(check_dark(&view, &l.black, &l, 100).is_err(), "{w}×{h} at {level}");
                }
            }
        }
    }
}
