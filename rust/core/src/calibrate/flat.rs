//! The clean image of an EV step and its flat mask (method.md, Calibration 2).
//!
//! The clean level of a pixel is `round(mean of the reference burst)`. A pixel is flat when its
//! clean value differs from each same-position neighbour (2 px away) by no more than the noise
//! of the mean explains, plus any fixed-pattern spread the chart shows on its flat patches. The
//! noise of the mean is measured from the burst itself (frame-to-frame differences, pooled by
//! level and fitted smoothly), so a short or noisy burst does not mask out a flat chart; with a
//! single reference frame, the spatial spread alone sets the threshold.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calibrate::flat_neighbours::NeighbourLimit;
use crate::calibrate::flat_spread::{SpreadLimit, burst_variance};
use crate::calibrate::half_code;
use crate::calibrate::saturated::{self, BurstView};
use crate::math::fit::{nn_poly_fit, poly_eval};
use crate::math::round::RoundedQuotient;
use crate::model::layout::{POSITIONS, position};

/// Marks a pixel of the clean image that is not on a flat region.
pub const NOT_FLAT: u16 = u16::MAX;
/// Level groups per position for the noise statistics.
pub const GROUPS: usize = 64;

/// A rectangle `[x0, x1) × [y0, y1)` in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Roi {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl Roi {
    #[inline]
    pub fn contains(&self, x: usize, y: usize) -> bool {
        x >= self.x0 as usize && x < self.x1 as usize && y >= self.y0 as usize && y < self.y1 as usize
    }
}

/// Maps a level to its statistics group at a position.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Groups {
    pub black: [f32; POSITIONS],
    pub white: u16,
}

impl Groups {
    /// `⌊(level − black) / span · GROUPS⌋` within `0..GROUPS` (NaN to 0). The conversion to
    /// `usize` truncates toward zero and saturates negative values to 0, which is the floor's
    /// group for every value (a fraction below 1 is group 0 either way), without the call to
    /// libm's `floorf` that `f32::floor` is on x86-64 without SSE4.1 (once per pixel of the
    /// flat test's samples).
    #[inline]
    pub fn group(&self, pos: usize, level: f32) -> usize {
        let span = (self.white as f32 - self.black[pos]).max(1.0);
        let g = (level - self.black[pos]) / span * GROUPS as f32;
        (g as usize).min(GROUPS - 1)
    }

    pub fn center(&self, pos: usize, g: usize) -> f64 {
        let span = (self.white as f64 - self.black[pos] as f64).max(1.0);
        (g as f64 + 0.5) / GROUPS as f64 * span
    }
}

/// Frame-to-frame difference statistics of a reference burst, per (position, level group):
/// `d = frame_k − frame_1` for k ≥ 2, grouped by the first frame's level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TemporalStats {
    /// `[n, Σd, Σd²]` per `pos * GROUPS + group`.
    pub acc: Vec<[f64; 3]>,
}

impl Default for TemporalStats {
    fn default() -> Self {
        Self { acc: vec![[0.0; 3]; POSITIONS * GROUPS] }
    }
}

impl TemporalStats {
    /// Per-frame noise variance as a smooth, non-negative quadratic in (level − black), per position.
    /// `None` for a position without enough differences (a single-frame burst).
    pub fn variance_fits(&self, groups: &Groups) -> [Option<Vec<f64>>; POSITIONS] {
        std::array::from_fn(|pos| {
            let (mut x, mut y, mut w) = (Vec::new(), Vec::new(), Vec::new());
            for g in 0..GROUPS {
                let [n, s1, s2] = self.acc[pos * GROUPS + g];
                if n >= 64.0 {
                    let m = s1 / n;
                    x.push(groups.center(pos, g));
                    y.push(((s2 / n - m * m) / 2.0).max(0.0));
                    w.push(n.sqrt());
                }
            }
            (!x.is_empty()).then(|| nn_poly_fit(&x, &y, &w, if x.len() >= 3 { 2 } else { 0 }))
        })
    }
}

impl TemporalStats {
    /// Per-frame noise variance as a robust line in (level − black) per position, `[c0, c1, 0]`:
    /// weighted by pixel count and refitted without the level groups that sit far above it.
    /// Frame-to-frame differences at chart edges (a scene that moves by a fraction of a pixel)
    /// are large; they dominate sparse level groups, never the patch interiors that fill the
    /// populated ones. Zero where the burst has no differences.
    pub fn robust_variance_fits(&self, groups: &Groups) -> [[f64; 3]; POSITIONS] {
        std::array::from_fn(|pos| {
            let pts: Vec<(f64, f64, f64)> = (0..GROUPS)
                .filter_map(|g| {
                    let [n, s1, s2] = self.acc[pos * GROUPS + g];
                    (n >= 64.0).then(|| {
                        let m = s1 / n;
                        (groups.center(pos, g), ((s2 / n - m * m) / 2.0).max(0.0), n)
                    })
                })
                .collect();
            robust_line(pts)
        })
    }
}

/// A robust line `[c0, c1, 0]` through `(level, variance, weight)` points: weighted, and
/// refitted (up to three times) without the points above twice the line plus 1 DN². Zero
/// without points.
fn robust_line(mut pts: Vec<(f64, f64, f64)>) -> [f64; 3] {
    let mut c = vec![0.0, 0.0];
    for _ in 0..3 {
        if pts.is_empty() {
            return [0.0; 3];
        }
        let x: Vec<f64> = pts.iter().map(|p| p.0).collect();
        let y: Vec<f64> = pts.iter().map(|p| p.1).collect();
        let w: Vec<f64> = pts.iter().map(|p| p.2).collect();
        c = nn_poly_fit(&x, &y, &w, usize::from(pts.len() >= 2));
        c.resize(2, 0.0);
        let keep: Vec<(f64, f64, f64)> =
            pts.iter().copied().filter(|p| p.1 <= 2.0 * poly_eval(&c, p.0) + 1.0).collect();
        if keep.len() == pts.len() {
            break;
        }
        pts = keep;
    }
    [c[0], c[1], 0.0]
}

/// Per-frame noise variance as one robust line in (level − black) for every position, through
/// the level groups' median pixel variances of all four (`medians`, per `pos * GROUPS + group`,
/// NaN where a group has too few pixels; weighted by the groups' pixel counts `pixels`), over
/// the groups that lie wholly below `below` (DN above black): the law of a burst that
/// saturated, without the levels the ceiling cut ([`crate::calibrate::saturated`]). A median is
/// not moved by the chart's edges where it moved between frames (a minority of any populated
/// level), which the frame differences' line reads. The positions share the line: their noise
/// against the level above black is one sensor's, and on a short held-out burst a line per
/// position put the margin below one ceiling at 1.72–2.27 true SDs (seed 0 of the random
/// family, EV +2, `tests/e2e/tests/full_well.rs`).
pub fn median_variance_fits_below(
    medians: &[f64],
    pixels: &[usize],
    groups: &Groups,
    below: f64,
) -> [[f64; 3]; POSITIONS] {
    let pts: Vec<(f64, f64, f64)> = (0..POSITIONS)
        .flat_map(|pos| {
            let span = (groups.white as f64 - groups.black[pos] as f64).max(1.0);
            (0..GROUPS).filter(move |&g| (g + 1) as f64 / GROUPS as f64 * span <= below).filter_map(move |g| {
                let (v, n) = (medians[pos * GROUPS + g], pixels[pos * GROUPS + g]);
                v.is_finite().then(|| (groups.center(pos, g), v, n as f64))
            })
        })
        .collect();
    [robust_line(pts); POSITIONS]
}

/// What the flat test found.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FlatReport {
    /// Flat pixels per position.
    pub flat: [u64; POSITIONS],
    /// Pixels per position considered (inside the region of interest).
    pub considered: [u64; POSITIONS],
    /// Fitted variance of the clean image per position: `[c0, c1, c2]` in (level − black).
    pub clean_variance: [[f64; 3]; POSITIONS],
    /// Its temporal part alone, the variance of the mean of the burst's frames (the clean
    /// image's own error; zero for a one-frame burst): `[c0, c1, c2]` in (level − black).
    pub mean_noise: [[f64; 3]; POSITIONS],
    /// The same per level group ([`GROUPS`] per position, [`Groups::group`]) where the group
    /// had enough differences (NaN elsewhere): near a saturated level it falls to nothing.
    pub mean_noise_groups: Vec<f32>,
    /// Pixels per position left out because their own spread over the burst is beyond what the
    /// noise at their level allows ([`unsteady_limit`]): motion, moving dust, a flickering LED.
    pub unsteady: [u64; POSITIONS],
    /// Flat pixels per position left out because the reference burst saturated there (a full
    /// well below white, or white): their clean level is the ceiling, not their brightness
    /// ([`crate::calibrate::saturated`]). Not kept in checkpoints (the clean levels are; a
    /// resumed session reports 0 here).
    #[serde(skip)]
    pub saturated: [u64; POSITIONS],
    /// Flat pixels per position left out because the noise is sub-DN and their clean code is
    /// most likely wrong, at a code whose mean such pixels would shift
    /// ([`crate::calibrate::half_code`]). Not kept in checkpoints, as `saturated`.
    #[serde(skip)]
    pub half_code: [u64; POSITIONS],
    /// Per position, the lowest clean level the saturation rule left out (DN), `None` where it
    /// found no ceiling. Not kept in checkpoints, as `saturated`.
    #[serde(skip)]
    pub saturation_cut: [Option<u16>; POSITIONS],
}

/// The largest ratio of a pixel's variance over an `m`-frame burst to the noise variance at its
/// level that pure noise exceeds once in a thousand pixels (Gaussian noise: `(m − 1)·s²/σ²` is
/// χ² with `m − 1` degrees of freedom; its 99.9 % quantile by Wilson–Hilferty, within 3 % for
/// one degree of freedom and closer above). A pixel beyond it did not hold still.
pub fn unsteady_limit(m: u32) -> f64 {
    let k = m.saturating_sub(1).max(1) as f64;
    let z = 3.090_232; // the standard normal's 99.9 % quantile
    let c = 2.0 / (9.0 * k);
    (1.0 - c + z * c.sqrt()).powi(3)
}

impl FlatReport {
    /// The variance of the clean image's error at `level` (DN, black included): the robust
    /// line, or less where the level's own group measured less (a saturated reference).
    pub fn mean_noise_at(&self, groups: &Groups, pos: usize, level: f64) -> f64 {
        let line = poly_eval(&self.mean_noise[pos], (level - groups.black[pos] as f64).max(0.0)).max(0.0);
        let g = groups.group(pos, level as f32);
        match self.mean_noise_groups.get(pos * GROUPS + g) {
            Some(&v) if v.is_finite() => line.min(v as f64),
            _ => line,
        }
    }
}

impl FlatReport {
    pub fn total_flat(&self) -> u64 {
        self.flat.iter().sum()
    }
}

/// Inputs of the flat test.
#[derive(Debug)]
pub struct CleanInputs<'a> {
    pub sum: &'a [u32],
    /// The burst's first frame.
    pub first: &'a [u16],
    /// Per pixel, Σ(frame − first frame)² (saturating).
    pub squares: &'a [u32],
    pub frames: u32,
    pub width: usize,
    pub height: usize,
    pub black: [f32; POSITIONS],
    pub white: u16,
    pub temporal: &'a TemporalStats,
    pub roi: Option<Roi>,
    /// Threshold in standard deviations of a neighbour difference.
    pub k: f64,
}

/// Values per (position, level group) that `fill` gathers row by row over `rows`: the rows in
/// parallel, a run of them per task. [`Grouped::joined`] gives each group's values in row order,
/// the same values in the same order as one pass over the rows would give.
fn grouped_by_rows(rows: &[usize], fill: impl Fn(usize, &mut Vec<Vec<f32>>) + Sync) -> Grouped {
    const RUN: usize = 16;
    let parts: Vec<Vec<Vec<f32>>> = rows
        .par_chunks(RUN)
        .map(|run| {
            let mut part = vec![Vec::new(); POSITIONS * GROUPS];
            for &y in run {
                fill(y, &mut part);
            }
            part
        })
        .collect();
    Grouped { parts }
}

/// [`grouped_by_rows`]' values, per run of rows. A group's values are joined only when asked
/// for, one group at a time into the caller's buffer: joining every group into vectors of its
/// own put a fresh copy of all of them (12 MB at 12 MP) into pages faulted in for it.
struct Grouped {
    /// Per run of rows, in row order: the values per (position, level group).
    parts: Vec<Vec<Vec<f32>>>,
}

impl Grouped {
    /// How many values group `g` holds.
    fn len(&self, g: usize) -> usize {
        self.parts.iter().map(|p| p[g].len()).sum()
    }

    /// Group `g`'s values in row order, in `buf` (cleared first).
    fn joined<'b>(&self, g: usize, buf: &'b mut Vec<f32>) -> &'b mut [f32] {
        buf.clear();
        for p in &self.parts {
            buf.extend_from_slice(&p[g]);
        }
        buf
    }
}

/// What the flat test gives ([`clean_and_mask`]).
#[derive(Debug)]
pub struct FlatImage {
    /// The rounded clean image, [`NOT_FLAT`] where a pixel is not on a flat region.
    pub clean: Vec<u16>,
    /// The burst's mean at every pixel, `clamp(round(sum / frames), 0, white)`.
    pub mean: Vec<u16>,
    pub report: FlatReport,
}

/// The flat test of a burst: its clean image, rounded mean and report.
pub fn clean_and_mask(inp: &CleanInputs<'_>) -> FlatImage {
    let (w, h) = (inp.width, inp.height);
    let m = inp.frames.max(1) as f64;
    let mean = |i: usize| inp.sum[i] as f64 / m;
    let groups = Groups { black: inp.black, white: inp.white };

    // Variance of the clean image per position: temporal part (noise of the mean) …
    let temporal = inp.temporal.variance_fits(&groups);
    let robust = inp.temporal.robust_variance_fits(&groups);
    let temporal_of = |pos: usize, x: f64| -> f64 {
        match &temporal[pos] {
            Some(c) if inp.frames >= 2 => poly_eval(c, x).max(0.0) / m,
            _ => 0.0,
        }
    };
    // … plus a spatial part (fixed pattern; or everything for a one-frame burst) measured as the
    // robust spread of horizontal neighbour differences on well-populated levels (patch interiors
    // dominate those; edges are spread thin over many levels).
    let row_step = if h > 512 { 4 } else { 1 };
    let sampled: Vec<usize> = (0..h).step_by(row_step * 2).flat_map(|y| [y, y + 1]).filter(|&y| y < h).collect();
    let diffs = grouped_by_rows(&sampled, |y, diffs| {
        for x in 0..w.saturating_sub(2) {
            let i = y * w + x;
            let pos = position(y, x);
            let a = mean(i);
            let d = (a - mean(i + 2)).abs() as f32;
            diffs[pos * GROUPS + groups.group(pos, a as f32)].push(d);
        }
    });
    let mut report = FlatReport::default();
    let mut spatial: [Vec<f64>; POSITIONS] = Default::default();
    let mut buf = Vec::new();
    for pos in 0..POSITIONS {
        let total: usize = (0..GROUPS).map(|g| diffs.len(pos * GROUPS + g)).sum();
        let (mut xs, mut ys, mut ws) = (Vec::new(), Vec::new(), Vec::new());
        for g in 0..GROUPS {
            let len = diffs.len(pos * GROUPS + g);
            if len < 32 || (len as f64) < 0.01 * total as f64 {
                continue;
            }
            let v = diffs.joined(pos * GROUPS + g, &mut buf);
            let mid = v.len() / 2;
            let (_, med, _) = v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
            let sigma = 1.4826 * *med as f64;
            let x = groups.center(pos, g);
            xs.push(x);
            ys.push(sigma * sigma / 2.0 - temporal_of(pos, x));
            ws.push((v.len() as f64).sqrt());
        }
        let fit = if xs.is_empty() {
            vec![0.0; 3]
        } else {
            let mut c = nn_poly_fit(&xs, &ys, &ws, if xs.len() >= 3 { 2 } else { 0 });
            c.resize(3, 0.0);
            c
        };
        let t = temporal[pos].clone().unwrap_or_default();
        if inp.frames >= 2 {
            report.mean_noise[pos] = robust[pos].map(|c| c / m);
            if report.mean_noise_groups.is_empty() {
                report.mean_noise_groups = vec![f32::NAN; POSITIONS * GROUPS];
            }
            for g in 0..GROUPS {
                let [n, s1, s2] = inp.temporal.acc[pos * GROUPS + g];
                if n >= 64.0 {
                    let mu = s1 / n;
                    report.mean_noise_groups[pos * GROUPS + g] = (((s2 / n - mu * mu) / 2.0).max(0.0) / m) as f32;
                }
            }
        }
        report.clean_variance[pos] =
            std::array::from_fn(|k| fit[k] + t.get(k).copied().unwrap_or(0.0) / if inp.frames >= 2 { m } else { 1.0 });
        spatial[pos] = fit;
    }
    drop(diffs);

    // Threshold per (position, level) as a lookup over integer levels. Its temporal part is the
    // robust line: frame-to-frame differences at edges that moved inflate the plain fit, and
    // an inflated threshold takes the edges for flat.
    let robust_of =
        |pos: usize, x: f64| -> f64 { if inp.frames >= 2 { poly_eval(&robust[pos], x).max(0.0) / m } else { 0.0 } };
    let thresholds: Vec<Vec<f32>> = (0..POSITIONS)
        .map(|pos| {
            (0..=inp.white as u32)
                .map(|l| {
                    let x = (l as f64 - inp.black[pos] as f64).max(0.0);
                    let var = robust_of(pos, x) + poly_eval(&spatial[pos], x).max(0.0);
                    (inp.k * (2.0 * var).sqrt() + 0.5) as f32
                })
                .collect()
        })
        .collect();
    // A pixel's own variance over the burst may exceed its level's noise variance by at most
    // `unsteady_limit`. The level's noise variance is the median of its pixels' burst variances
    // (per position and level group; edges that moved are a minority of any populated level)
    // over the median of χ²ₖ/k; where a group holds few pixels, the robust line of the
    // frame-to-frame differences (at least a quarter DN², quantisation's scale).
    let k = inp.frames.saturating_sub(1).max(1) as f64;
    let median_factor = (1.0 - 2.0 / (9.0 * k)).powi(3);
    let limit = unsteady_limit(inp.frames);
    let pixel_var = |i: usize| -> f64 { burst_variance(inp.sum[i], inp.first[i], inp.squares[i], inp.frames) };
    let mut group_medians = vec![f64::NAN; POSITIONS * GROUPS];
    let mut group_pixels = vec![0usize; POSITIONS * GROUPS];
    if inp.frames >= 2 {
        let vars = grouped_by_rows(&sampled, |y, vars| {
            for x in 0..w {
                let i = y * w + x;
                let pos = position(y, x);
                vars[pos * GROUPS + groups.group(pos, mean(i) as f32)].push(pixel_var(i) as f32);
            }
        });
        for (g, (gm, n)) in group_medians.iter_mut().zip(group_pixels.iter_mut()).enumerate() {
            *n = vars.len(g);
            if *n >= 32 {
                let v = vars.joined(g, &mut buf);
                let mid = v.len() / 2;
                let (_, med, _) = v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
                *gm = *med as f64 / median_factor;
            }
        }
    }
    // As a lookup over integer levels per position, like the thresholds.
    let spread_limits: Vec<Vec<SpreadLimit>> = (0..POSITIONS)
        .map(|pos| {
            (0..=inp.white as u32)
                .map(|l| {
                    let level = l as f64;
                    let var = match group_medians[pos * GROUPS + groups.group(pos, l as f32)] {
                        v if v.is_finite() => v,
                        _ => report.mean_noise_at(&groups, pos, level) * m,
                    };
                    SpreadLimit::new((limit * var.max(0.0625)) as f32, inp.frames)
                })
                .collect()
        })
        .collect();

    // Blocks of rows in parallel, each counting its own pixels (considered, unsteady, flat per
    // position); the counts are summed in block order afterwards, so the report is the same on
    // any thread count. The levels `clamp(round(mean), 0, white)` of a block's rows are taken
    // once, as the block starts (those of the two rows above and below it, which its neighbour
    // tests read, into a scratch of the thread's): a neighbour test reads the level of the
    // larger mean of a pair, which is the larger of their levels (rounding and clamping never
    // reverse an order), and they are the burst's rounded mean, which the clean image keeps
    // (`mean`, returned). A pass of its own over the sums before this one read the 12 MP image's
    // sums (48 MB) twice.
    const BLOCK_ROWS: usize = 32;
    let top = inp.white as usize;
    // The levels from the sums without a division each, and the neighbour test on the sums'
    // difference where that decides it (as the means would).
    let level_of = RoundedQuotient::new(inp.frames.max(1));
    let level_at = |s: u32| (level_of.of(s).max(0) as usize).min(top) as u16;
    let neighbour_limits: Vec<Vec<NeighbourLimit>> =
        thresholds.iter().map(|t| t.iter().map(|&t| NeighbourLimit::new(t, inp.frames.max(1))).collect()).collect();
    // Every pixel of both is written below (a fresh zeroed buffer's pages are first touched
    // there, not filled beforehand).
    let mut mean = vec![0u16; w * h];
    let mut clean = vec![0u16; w * h];
    let block_len = (w * BLOCK_ROWS).max(1);
    let row_counts: Vec<[[u64; POSITIONS]; 3]> = clean
        .par_chunks_mut(block_len)
        .zip(mean.par_chunks_mut(block_len))
        .enumerate()
        .map_init(Vec::new, |halo: &mut Vec<u16>, (block, (clean_rows, mean_rows))| {
            let y0 = block * BLOCK_ROWS;
            let y1 = y0 + clean_rows.len() / w.max(1);
            let (lo, hi) = (y0.saturating_sub(2), (y1 + 2).min(h));
            for (l, &s) in mean_rows.iter_mut().zip(&inp.sum[y0 * w..y1 * w]) {
                *l = level_at(s);
            }
            halo.clear();
            halo.extend(inp.sum[lo * w..y0 * w].iter().chain(&inp.sum[y1 * w..hi * w]).map(|&s| level_at(s)));
            let (halo, mean_rows): (&[u16], &[u16]) = (halo, mean_rows);
            // Row `yy`'s sums and levels (`lo ≤ yy < hi`).
            let row = |yy: usize| {
                let levels = if yy < y0 {
                    &halo[(yy - lo) * w..(yy - lo + 1) * w]
                } else if yy < y1 {
                    &mean_rows[(yy - y0) * w..(yy - y0 + 1) * w]
                } else {
                    let r = y0 - lo + yy - y1;
                    &halo[r * w..(r + 1) * w]
                };
                (&inp.sum[yy * w..(yy + 1) * w], levels)
            };
            let mut counts = [[0u64; POSITIONS]; 3];
            let [considered, unsteady, flat_count] = &mut counts;
            for (r, clean_row) in clean_rows.chunks_mut(w.max(1)).enumerate() {
                let y = y0 + r;
                let (sums, levels) = row(y);
                let up = (y >= 2).then(|| row(y - 2));
                let down = (y + 2 < h).then(|| row(y + 2));
                let (first, squares) = (&inp.first[y * w..(y + 1) * w], &inp.squares[y * w..(y + 1) * w]);
                for x in 0..w {
                    let pos = position(y, x);
                    if inp.roi.is_some_and(|r| !r.contains(x, y)) {
                        clean_row[x] = NOT_FLAT;
                        continue;
                    }
                    considered[pos] += 1;
                    let (sa, la) = (sums[x], levels[x]);
                    let level = la.min(NOT_FLAT - 1);
                    let mut neighbours = 0;
                    let mut flat = true;
                    let (limits, thresholds) = (&neighbour_limits[pos], &thresholds[pos]);
                    let mut check = |sb: u32, lb: u16| {
                        neighbours += 1;
                        let l = la.max(lb) as usize;
                        if limits[l].beyond(sa, sb, m, thresholds[l]) {
                            flat = false;
                        }
                    };
                    if x >= 2 {
                        check(sums[x - 2], levels[x - 2]);
                    }
                    if x + 2 < w {
                        check(sums[x + 2], levels[x + 2]);
                    }
                    if let Some((s, l)) = up {
                        check(s[x], l[x]);
                    }
                    if let Some((s, l)) = down {
                        check(s[x], l[x]);
                    }
                    if flat
                        && neighbours >= 2
                        && inp.frames >= 2
                        && spread_limits[pos][level as usize].beyond(sa, first[x], squares[x], inp.frames)
                    {
                        flat = false;
                        unsteady[pos] += 1;
                    }
                    let flat = flat && neighbours >= 2;
                    clean_row[x] = if flat { level } else { NOT_FLAT };
                    flat_count[pos] += flat as u64;
                }
            }
            counts
        })
        .collect();
    for [considered, unsteady, flat_count] in row_counts {
        for pos in 0..POSITIONS {
            report.considered[pos] += considered[pos];
            report.unsteady[pos] += unsteady[pos];
            report.flat[pos] += flat_count[pos];
        }
    }
    let sat = saturated::leave_out(BurstView {
        clean: &mut clean,
        width: w,
        not_flat: NOT_FLAT,
        frames: inp.frames,
        black: inp.black,
        white: inp.white,
        burst_variance: pixel_var,
        law: robust,
        law_below: |below| median_variance_fits_below(&group_medians, &group_pixels, &groups, below),
    });
    for pos in 0..POSITIONS {
        report.flat[pos] -= sat.left_out[pos];
        report.saturated[pos] = sat.left_out[pos];
    }
    report.saturation_cut = sat.cut;
    // Where the noise is sub-DN, the pixels whose code the burst's mean most likely got wrong,
    // at the codes they would bias. The noise is the robust line's, not a level group's own
    // measure, which falls to nothing where the reference saturated (there the code is the
    // ceiling, not uncertain).
    let sds: [Vec<f64>; POSITIONS] = std::array::from_fn(|pos| {
        (0..=inp.white as u32)
            .map(|l| half_code::mean_sd(robust_of(pos, (l as f64 - inp.black[pos] as f64).max(0.0)), inp.frames))
            .collect()
    });
    let uncertain = half_code::leave_out(&mut clean, inp.sum, w, inp.frames, inp.white, NOT_FLAT, &sds);
    for (flat, left) in report.flat.iter_mut().zip(uncertain) {
        *flat -= left;
    }
    report.half_code = uncertain;
    FlatImage { clean, mean, report }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal, StudentT};

    /// Each group joined from the runs of rows holds the values one pass over the rows gives,
    /// in the same order (so its median is the same), for rows of many runs (60 rows: four runs
    /// of 16, the last short) and empty groups; a version that joined the runs out of order, or
    /// dropped the last run, fails on the order or the count.
    #[test]
    fn grouped_is_one_pass_over_the_rows() {
        let rows: Vec<usize> = (0..60).map(|y| 3 * y + 1).collect();
        let fill = |y: usize, groups: &mut Vec<Vec<f32>>| {
            for x in 0..37 {
                let g = (y * 7 + x * 13) % 40;
                groups[g].push((y * 1000 + x) as f32);
            }
        };
        let mut one_pass = vec![Vec::new(); POSITIONS * GROUPS];
        for &y in &rows {
            fill(y, &mut one_pass);
        }
        let grouped = grouped_by_rows(&rows, fill);
        let mut buf = vec![-1.0];
        for (g, want) in one_pass.iter().enumerate() {
            assert_eq!(grouped.len(g), want.len(), "group {g}");
            assert_eq!(grouped.joined(g, &mut buf), &want[..], "group {g}");
        }
        assert!(one_pass.iter().any(|v| v.is_empty()) && one_pass.iter().any(|v| v.len() > 40));
    }

    /// Share of pixels of pure noise (`m` frames each) whose burst variance exceeds
    /// `unsteady_limit(m)` times the noise variance.
    fn false_positives(m: u32, noise: impl Fn(&mut ChaCha8Rng) -> f64, var: f64, pixels: usize) -> f64 {
        let mut rng = ChaCha8Rng::seed_from_u64(m as u64);
        let limit = unsteady_limit(m) * var;
        let mut over = 0;
        for _ in 0..pixels {
            let v: Vec<f64> = (0..m).map(|_| noise(&mut rng)).collect();
            let mean = v.iter().sum::<f64>() / m as f64;
            let s2 = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (m - 1) as f64;
            if s2 > limit {
                over += 1;
            }
        }
        over as f64 / pixels as f64
    }

    /// `Groups::group` is the floor's group for every f32 level: random levels over and beyond
    /// the range, every integer level, the group boundaries and their neighbouring f32 values,
    /// and the specials. A truncation that went toward zero without the clamp below (or a
    /// rounding instead of a floor) misplaces the levels within one group of black or of each
    /// boundary; the test counts every level it compared.
    #[test]
    fn group_is_the_floor_group() {
        let floor_group = |g: &Groups, pos: usize, level: f32| {
            let span = (g.white as f32 - g.black[pos]).max(1.0);
            let v = ((level - g.black[pos]) / span * GROUPS as f32).floor();
            if v <= 0.0 { 0 } else { (v as usize).min(GROUPS - 1) }
        };
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut compared = 0usize;
        for (black, white) in
            [([64.0f32, 64.5, 63.0, 0.0], 1023u16), ([512.0; 4], 16383), ([0.0; 4], 0), ([800.0; 4], 700)]
        {
            let g = Groups { black, white };
            for pos in 0..POSITIONS {
                let span = (white as f32 - black[pos]).max(1.0);
                let mut levels: Vec<f32> = (0..=white as u32 + 2).map(|l| l as f32).collect();
                for k in -2..=(GROUPS as i32 + 2) {
                    let edge = black[pos] + k as f32 * span / GROUPS as f32;
                    levels.extend([edge.next_down(), edge, edge.next_up()]);
                }
                levels.extend((0..20_000).map(|_| rand::RngExt::random_range(&mut rng, -2000.0f32..70_000.0)));
                levels.extend([f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.0, 0.0, f32::MAX, f32::MIN]);
                for &l in &levels {
                    assert_eq!(g.group(pos, l), floor_group(&g, pos, l), "level {l} at {pos}, black {black:?}");
                    compared += 1;
                }
            }
        }
        assert!(compared > 100_000, "{compared}");
    }

    #[test]
    fn unsteady_pixels_of_pure_noise_are_one_in_a_thousand() {
        // Gaussian noise: the limit is χ²'s 99.9 % point (Wilson–Hilferty), so 0.1 % of pixels
        // (400 000 pixels: SD 0.005 %) exceed it at every burst length.
        for m in [2u32, 3, 4, 8, 16, 32] {
            let g = Normal::new(0.0, 3.0).expect("normal");
            let fp = false_positives(m, |r| g.sample(r), 9.0, 400_000);
            assert!((0.0007..0.0013).contains(&fp), "M = {m}: {fp:.5} of pure Gaussian noise left out");
        }
        // Heavy tails (Student-t, 5 dof, excess kurtosis 6, unit variance) leave more out:
        // 2.4 % of a 16-frame burst's pixels (measured), under 3 %.
        let t = StudentT::new(5.0).expect("t");
        let fp = false_positives(16, |r| t.sample(r) / (5.0f64 / 3.0).sqrt(), 1.0, 200_000);
        assert!(fp < 0.03, "Student-t: {fp:.4}");
        // A pixel on an edge that moved by ±0.3 px with a gradient of 10 σ/px is caught.
        let g = Normal::new(0.0, 1.0).expect("normal");
        let moved =
            false_positives(8, |r| g.sample(r) + if rand::RngExt::random::<bool>(r) { 3.0 } else { -3.0 }, 1.0, 20_000);
        assert!(moved > 0.95, "a moving edge pixel is left out: {moved:.3}");
    }
}
