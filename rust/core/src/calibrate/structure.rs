//! Structured noise measured from the target frames already captured (method.md, "Structured
//! noise"): per frame, the mean of `n = noisy − clean` over the flat pixels of every row, every
//! column and every CFA position, taken in the same pass that fills the pixel histograms.
//!
//! Every frame of a burst (one EV step, one ISO) sees the same clean image and the same flat
//! pixels, so whatever the clean image gets wrong is the same in each of them: a frame's row
//! mean minus the burst's mean of that row is the row's offset in that frame (plus the sampling
//! noise of a mean of `m` pixels), with nothing of the scene left in it. Per frame only these
//! means are kept until the burst ends (`O(rows + columns)` floats per frame of the current
//! burst); then they are folded into histograms and the burst's buffer is dropped.
//!
//! - Frame offsets: per CFA position, the frame's mean minus the burst's, rescaled by
//!   `√(k/(k−1))` (removing a mean of `k` frames shrinks the variance by `(k−1)/k`).
//! - Row offsets (per row parity): the row's deviation minus its frame's deviation over the same
//!   positions, rescaled the same way. Its variance is the row component's plus the sampling
//!   variance `s²/m` of the row mean (`s²` the variance of `n` along the row in that frame); the
//!   latter is summed alongside and taken out at the end ([`fold_offsets`]).
//! - Column offsets (per column parity): the same along columns.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::model::layout::POSITIONS;
use crate::model::structure::{FrameOffsets, IsoStructure, OffsetDistribution, QUANTILES};

/// Fewest flat pixels a row (column) needs for its mean to count.
pub const MIN_LINE_PIXELS: u32 = 32;
/// Frames of one burst kept before the buffer is folded as a group of its own.
pub const MAX_GROUP: usize = 64;
/// Histogram resolution of measured offsets (steps per DN).
const STEPS_PER_DN: f64 = 64.0;
/// Significance of a component: its variance above the sampling variance by this many standard
/// errors of the sampling variance's estimate.
const SIGNIFICANCE: f64 = 3.0;
/// Relevance of a component: its variance at least this fraction of the ISO's lowest pixel
/// variance. Row and column offsets matter as soon as they rival the sampling noise of a line
/// mean (a mean of ~500 pixels has 0.2 % of the pixel variance); a frame offset below 1 % of
/// the pixel variance changes nothing anyone measures.
const LINE_RELEVANCE: f64 = 1e-3;
const FRAME_RELEVANCE: f64 = 1e-2;
/// A line component must exceed this fraction of the line means' sampling variance.
const MODEL_MARGIN: f64 = 0.25;

/// `[Σn, Σn², m]` over a line's flat pixels of one parity.
pub(crate) type LineSums = [i64; 3];

/// One frame's sums: per row `[column parity]`, per column `[row parity]`.
#[derive(Debug, Clone, Default)]
pub(crate) struct FrameSums {
    pub(crate) rows: Vec<[LineSums; 2]>,
    pub(crate) cols: Vec<[LineSums; 2]>,
}

impl FrameSums {
    pub(crate) fn new(w: usize, h: usize) -> Self {
        Self { rows: vec![[[0; 3]; 2]; h], cols: vec![[[0; 3]; 2]; w] }
    }

    /// `[Σn, Σn², m]` per CFA position.
    fn positions(&self) -> [[f64; 3]; POSITIONS] {
        let mut out = [[0.0; 3]; POSITIONS];
        for (y, r) in self.rows.iter().enumerate() {
            for (cp, s) in r.iter().enumerate() {
                let o = &mut out[(y & 1) * 2 + cp];
                for k in 0..3 {
                    o[k] += s[k] as f64;
                }
            }
        }
        out
    }
}

/// One line's means in one frame of the burst (`NaN`: too few pixels).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct FrameMeans {
    /// Per row: mean of n over the row's flat pixels, and `s²/m`.
    rows: Vec<[f32; 2]>,
    cols: Vec<[f32; 2]>,
    /// Per position: mean of n and `s²/N`.
    pos: [[f64; 2]; POSITIONS],
}

/// A line's pixel counts per parity (the same in every frame of a burst).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Counts {
    rows: Vec<[u32; 2]>,
    cols: Vec<[u32; 2]>,
}

/// Measured offsets of one kind, as a histogram and moments.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct OffsetHistogram {
    /// Offsets at 1/64 DN.
    counts: BTreeMap<i32, u64>,
    n: u64,
    /// `Σd, Σd², Σd⁴, Σv, Σv², Σv·d²` (`v`: the line's `s²/m`).
    sums: [f64; 6],
}

impl OffsetHistogram {
    fn add(&mut self, d: f64, sampling: f64) {
        if !d.is_finite() {
            return;
        }
        let k = (d * STEPS_PER_DN).round().clamp(-1e9, 1e9) as i32;
        *self.counts.entry(k).or_default() += 1;
        self.n += 1;
        self.sums[0] += d;
        self.sums[1] += d * d;
        self.sums[2] += d * d * d * d;
        self.sums[3] += sampling;
        self.sums[4] += sampling * sampling;
        self.sums[5] += sampling * d * d;
    }

    /// The distribution of the component (sampling noise taken out), or `None` without data.
    pub(crate) fn distribution(&self, pixel_var: f64) -> Option<OffsetDistribution> {
        if self.n < 2 {
            return None;
        }
        let n = self.n as f64;
        let mean = self.sums[0] / n;
        let measured_var = (self.sums[1] / n - mean * mean).max(0.0);
        // `s²` along a line also holds what is fixed per pixel (the clean image's error, DSNU),
        // which the deviations from the burst mean do not: only a fraction `c` of `s²/m` is
        // the line mean's sampling variance. Lines differ in `s²/m` (pixels, levels), so
        // `E[d²] = σ² + c·v` is fitted over them; where `v` hardly varies, `c = 1`.
        let v_mean = self.sums[3] / n;
        let v_var = self.sums[4] / n - v_mean * v_mean;
        let cov = self.sums[5] / n - v_mean * self.sums[1] / n;
        let c = if v_var > (0.1 * v_mean).powi(2) && v_var > 0.0 { (cov / v_var).clamp(0.3, 1.2) } else { 1.0 };
        let sampling_var = c * v_mean;
        let own = (measured_var - sampling_var).max(0.0);
        // Under "no component" the measured variance is the sampling variance with a standard
        // error of about √(2/n) of it (means of many pixels are Gaussian).
        // The fit of `c` is a model, not a measurement: a component must also stand above a
        // quarter of the sampling variance (a sensor without row noise measured up to 17 %).
        let significant = own > SIGNIFICANCE * sampling_var * (2.0 / n).sqrt()
            && own > MODEL_MARGIN * sampling_var
            && own > 0.0
            && own >= LINE_RELEVANCE * pixel_var;
        let shrink = if measured_var > 0.0 { (own / measured_var).sqrt() } else { 0.0 };
        // The quantile function of the histogram (each 1/64 DN cell spread uniformly).
        let cells: Vec<(f64, u64)> = self.counts.iter().map(|(&k, &c)| (k as f64 / STEPS_PER_DN, c)).collect();
        let half = 0.5 / STEPS_PER_DN;
        let mut quantiles = Vec::with_capacity(QUANTILES);
        let (mut i, mut below) = (0usize, 0u64);
        for j in 0..QUANTILES {
            let target = j as f64 / (QUANTILES - 1) as f64 * n;
            while i + 1 < cells.len() && (below + cells[i].1) as f64 <= target {
                below += cells[i].1;
                i += 1;
            }
            let (x, c) = cells[i];
            let f = ((target - below as f64) / c as f64).clamp(0.0, 1.0);
            let v = x - half + f * 2.0 * half;
            quantiles.push(((v - mean) * shrink) as f32);
        }
        Some(OffsetDistribution { quantiles, count: self.n, measured_var, sampling_var, significant })
    }
}

/// The structured-noise sums of one ISO.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct StructureAccumulator {
    /// The burst being captured: its step, its counts, its frames' means.
    group: Option<(u32, Counts, Vec<FrameMeans>)>,
    rows: [OffsetHistogram; 2],
    cols: [OffsetHistogram; 2],
    frames: Vec<[f32; POSITIONS]>,
    /// Per position `Σ` of the frame means' sampling variance (pixels only).
    frame_sampling: [f64; POSITIONS],
    /// Frames that were part of a burst of at least two.
    frames_used: u64,
    /// Frames alone at their ISO in their burst (no deviation to measure).
    frames_alone: u64,
}

fn mean_and_sampling(s: &LineSums) -> Option<(f64, f64)> {
    let m = s[2] as f64;
    if s[2] < MIN_LINE_PIXELS as i64 {
        return None;
    }
    let mean = s[0] as f64 / m;
    let var = ((s[1] as f64 - s[0] as f64 * mean) / (m - 1.0)).max(0.0);
    Some((mean, var / m))
}

fn line_means(lines: &[[LineSums; 2]]) -> (Vec<[f32; 2]>, Vec<[u32; 2]>) {
    lines
        .iter()
        .map(|l| {
            let both = [l[0][0] + l[1][0], l[0][1] + l[1][1], l[0][2] + l[1][2]];
            let m = match mean_and_sampling(&both) {
                Some((mean, v)) => [mean as f32, v as f32],
                None => [f32::NAN, f32::NAN],
            };
            (m, [l[0][2] as u32, l[1][2] as u32])
        })
        .unzip()
}

impl StructureAccumulator {
    /// Records one target frame of burst `step`.
    pub(crate) fn add_frame(&mut self, step: u32, sums: &FrameSums) {
        let (rows, row_counts) = line_means(&sums.rows);
        let (cols, col_counts) = line_means(&sums.cols);
        let pos = sums.positions().map(|[s, s2, m]| {
            if m < 2.0 {
                return [f64::NAN, 0.0];
            }
            let mean = s / m;
            [mean, ((s2 - s * mean) / (m - 1.0)).max(0.0) / m / m]
        });
        let means = FrameMeans { rows, cols, pos };
        let counts = Counts { rows: row_counts, cols: col_counts };
        let same = matches!(&self.group, Some((s, c, f)) if *s == step && *c == counts && f.len() < MAX_GROUP);
        if !same {
            self.close_group();
            self.group = Some((step, counts, Vec::new()));
        }
        if let Some((_, _, frames)) = self.group.as_mut() {
            frames.push(means);
        }
    }

    /// Folds the current burst's frames into the histograms.
    fn close_group(&mut self) {
        let Some((_, counts, frames)) = self.group.take() else {
            return;
        };
        let k = frames.len();
        if k < 2 {
            self.frames_alone += k as u64;
            return;
        }
        self.frames_used += k as u64;
        let kf = k as f64;
        let rescale = (kf / (kf - 1.0)).sqrt();
        let avg = |get: &dyn Fn(&FrameMeans) -> f64| frames.iter().map(get).sum::<f64>() / kf;
        let pos_mean: [f64; POSITIONS] = std::array::from_fn(|p| avg(&|f: &FrameMeans| f.pos[p][0]));
        // Frame offsets.
        let dpos: Vec<[f64; POSITIONS]> =
            frames.iter().map(|f| std::array::from_fn(|p| f.pos[p][0] - pos_mean[p])).collect();
        for (f, d) in frames.iter().zip(&dpos) {
            if d.iter().all(|v| v.is_finite()) {
                self.frames.push(d.map(|v| (v * rescale) as f32));
                for p in 0..POSITIONS {
                    self.frame_sampling[p] += f.pos[p][1];
                }
            }
        }
        // Rows: row y of parity r holds positions 2r (even columns) and 2r + 1.
        fold_lines(
            &frames,
            &dpos,
            &counts.rows,
            |f| &f.rows,
            |y| [(y & 1) * 2, (y & 1) * 2 + 1],
            rescale,
            &mut self.rows,
        );
        // Columns: column x of parity c holds positions c (even rows) and 2 + c.
        fold_lines(&frames, &dpos, &counts.cols, |f| &f.cols, |x| [x & 1, 2 + (x & 1)], rescale, &mut self.cols);
    }

    /// The measured components (the burst in progress included); `pixel_var` is the ISO's
    /// lowest measured pixel variance (DN²), `row_counts` the sensor's rows.
    pub(crate) fn structure(&self, iso: u32, row_counts: usize, pixel_var: f64) -> IsoStructure {
        let mut acc = self.clone();
        acc.close_group();
        let rows = std::array::from_fn(|p| acc.rows[p].distribution(pixel_var));
        let columns = std::array::from_fn(|p| acc.cols[p].distribution(pixel_var));
        let frames = (acc.frames.len() >= 2).then(|| {
            let n = acc.frames.len() as f64;
            let measured_var: [f64; POSITIONS] =
                std::array::from_fn(|p| acc.frames.iter().map(|o| (o[p] as f64).powi(2)).sum::<f64>() / n);
            // A frame's mean also averages its rows' and columns' offsets.
            let line_var = |d: &Option<OffsetDistribution>| d.as_ref().map_or(0.0, |d| d.variance());
            let sampling_var: [f64; POSITIONS] = std::array::from_fn(|p| {
                let lines = row_counts.max(1) as f64 / 2.0;
                acc.frame_sampling[p] / n + line_var(&rows[p >> 1]) / lines
            });
            let significant = (0..POSITIONS).any(|p| {
                let own = measured_var[p] - sampling_var[p];
                own > SIGNIFICANCE * sampling_var[p] * (2.0 / n).sqrt()
                    && own > 1e-6
                    && own >= FRAME_RELEVANCE * pixel_var
            });
            FrameOffsets { offsets: acc.frames.clone(), measured_var, sampling_var, significant }
        });
        IsoStructure { iso, rows, columns, frames, frames_used: acc.frames_used }
    }
}

/// Folds one burst's line means into the per-parity histograms: each line's deviation from its
/// burst mean, minus its frame's deviation over the line's two positions (weighted by the
/// line's pixels there), rescaled for the mean's removal.
fn fold_lines(
    frames: &[FrameMeans],
    dpos: &[[f64; POSITIONS]],
    counts: &[[u32; 2]],
    lines: impl Fn(&FrameMeans) -> &Vec<[f32; 2]>,
    positions: impl Fn(usize) -> [usize; 2],
    rescale: f64,
    out: &mut [OffsetHistogram; 2],
) {
    let kf = frames.len() as f64;
    for (i, c) in counts.iter().enumerate() {
        let m = (c[0] + c[1]) as f64;
        if m < MIN_LINE_PIXELS as f64 {
            continue;
        }
        let mean = frames.iter().map(|f| lines(f)[i][0] as f64).sum::<f64>() / kf;
        if !mean.is_finite() {
            continue;
        }
        let [pa, pb] = positions(i);
        // The line's sampling variance averaged over the burst: one frame's `s²` is itself noisy,
        // and a noisy regressor would bias the fit of `c` (and the component) upwards.
        let v_line = frames.iter().map(|f| lines(f)[i][1] as f64).sum::<f64>() / kf;
        for (f, d) in frames.iter().zip(dpos) {
            let [x, _] = lines(f)[i];
            let v = v_line;
            let d = d.map(|v| if v.is_finite() { v } else { 0.0 });
            let frame_part = (c[0] as f64 * d[pa] + c[1] as f64 * d[pb]) / m;
            out[i & 1].add((x as f64 - mean - frame_part) * rescale, v);
        }
    }
}
