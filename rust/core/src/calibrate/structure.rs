//! Structured noise measured from the target frames already captured (method.md, "Structured
//! noise"): per frame, the mean of `n = noisy − clean` and of the clean level over the flat
//! pixels of every row and every column, split by CFA parity and into two interleaved halves,
//! taken in the same pass that fills the pixel histograms.
//!
//! Every frame of a burst (one EV step, one ISO) sees the same clean image and the same flat
//! pixels, so whatever the clean image gets wrong is the same in each of them: a frame's line
//! mean minus the burst's mean of that line holds only what changed from frame to frame. Per
//! frame only these means are kept until the burst ends (`O(rows + columns)` floats per frame
//! of the current burst); then they are folded into histograms and the burst's buffer is dropped.
//!
//! What changes from frame to frame besides the line offsets is taken out per frame and line
//! parity by a weighted least-squares fit of the deviations on the cells' clean level, with one
//! intercept per CFA position and one common slope: the intercepts (at the black level) are the
//! frame's black-level offsets; the slope is the frame's brightness (exposure or light jitter,
//! flicker), which multiplies the scene and would otherwise pass for row noise wherever a row
//! crosses brighter patches than its neighbours.
//!
//! - Frame offsets: per CFA position, the intercepts, rescaled by `√(k/(k−1))` (removing a mean
//!   of `k` frames shrinks the variance by `(k−1)/k`); their sampling variance is the fit's
//!   sandwich variance, clustered by line (for the significance test, [`frame_test`], with each
//!   line's leverage corrected for: `LevelFit::offset_var`). Where a burst's levels are too narrow to resolve its
//!   frames' brightness changes (a flat field), extrapolating to black would multiply the slope's
//!   noise by the level: the frames' mean deviations per position are taken instead
//!   ([`use_slope`]), and the frames' brightness is taken out of them where the data allows
//!   (`flicker.rs`: the lamp's flicker is reported, not synthesized).
//! - Row offsets (per row parity): the residual of the fit, rescaled the same way. Its variance
//!   is the row component's plus the sampling noise of a mean of `m` pixels. The two halves of a
//!   line (columns `x` with `⌊x/2⌋` even, and odd) share the row's offset but not their pixels'
//!   noise, so the covariance of their residuals is the component's variance, with no model of
//!   the sampling noise at all (fixed patterns, scene edges, clipping or heavy tails in `n` do
//!   not enter it) — but for the fit's own share: the fitted value at a line holds part of that
//!   line's own sampling noise (its leverage, about `2/N` over the `N` lines of a parity), and
//!   both halves' residuals subtract it, so their covariance reads the component less that
//!   share of the line mean's sampling variance. Each line's estimate is the combination of its
//!   halves' product and its own squared residual that cancels the sampling noise exactly
//!   ([`Leverage`]). Uncorrected, a sensor without column noise read `−0.03 DN²` per column
//!   parity (0.1 of the line means' sampling variance, at 27 lines) and a row component as much
//!   low; corrected by an average leverage of `3/N` instead, 45 of 800 null components passed
//!   the 3 SE rule (`tests_structure.rs`).
//! - Column offsets (per column parity): the same along columns (halves by `⌊y/2⌋`).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::calibrate::flicker::{BurstFlicker, FrameDeviation, SlopeSpread, note, separate};
use crate::model::layout::POSITIONS;
use crate::model::structure::{FrameOffsets, IsoStructure, OffsetDistribution, QUANTILES};

/// Fewest flat pixels a row (column) needs for its mean to count; each half needs a quarter.
pub const MIN_LINE_PIXELS: u32 = 32;
/// Frames of one burst kept before the buffer is folded as a group of its own.
pub const MAX_GROUP: usize = 64;
/// Histogram resolution of measured offsets (steps per DN).
const STEPS_PER_DN: f64 = 64.0;
/// Significance of a component: its variance above zero by this many standard errors of its
/// estimate. The bursts' estimates are unbiased under no component (module docs) and each is a
/// mean of hundreds of line products, so the combined estimate over its standard error is close
/// to a standard normal there: a sensor without the component gets it at a rate of 0.13 % per
/// line parity (one-sided), and a component of `5 SE` is found 98 % of the time.
/// `tests_structure.rs` measures both: 1 of 800 null components found; sensor 6's row noise
/// (0.011 DN², about 5 SE on its session) found 80 of 80 times.
const SIGNIFICANCE: f64 = 3.0;
/// Relevance of a component: its variance at least this fraction of the ISO's lowest pixel
/// variance. Row and column offsets matter as soon as they rival the sampling noise of a line
/// mean (a mean of ~500 pixels has 0.2 % of the pixel variance); a frame offset below 1 % of
/// the pixel variance changes nothing anyone measures.
const LINE_RELEVANCE: f64 = 1e-3;
const FRAME_RELEVANCE: f64 = 1e-2;
/// A line component must also exceed this fraction of the line means' sampling variance in the
/// bursts its estimate rests on (weighted as the estimate weighs them): the halves' covariance
/// is unbiased, but what the per-frame fit leaves of brightness changes that are not linear in
/// the level is not. Weighted, not pooled over all bursts: pooled, the bright bursts' sampling
/// variance (0.58 DN² on a 10-bit sensor whose row noise is 0.011 DN², measured 0.0107 ± 0.002
/// from its dark bursts, where the line means' sampling variance is 0.016) refused every row
/// component of every sensor whose session reaches mid-grey. Measured, true components stand at
/// 0.23–0.97 of it, the largest null (column) estimates at 0.03.
const MODEL_MARGIN: f64 = 0.1;

/// `[Σn, Σclean, m]` over one cell of a line: its flat pixels of one parity in one half.
pub(crate) type LineSums = [i64; 3];

/// Cell of a line: `parity | half << 1`; a row's pixel `x` is in cell `x & 3`, a column's
/// pixel `y` in cell `y & 3`.
pub(crate) const CELLS: usize = 4;

/// One frame's sums: per row `[cell]` (column parity, half), per column `[cell]` (row parity,
/// half).
#[derive(Debug, Clone, Default)]
pub(crate) struct FrameSums {
    pub(crate) rows: Vec<[LineSums; CELLS]>,
    pub(crate) cols: Vec<[LineSums; CELLS]>,
    /// The black level per position (the intercepts are taken there).
    pub(crate) black: [f32; POSITIONS],
}

impl FrameSums {
    pub(crate) fn new(w: usize, h: usize, black: [f32; POSITIONS]) -> Self {
        Self { rows: vec![[[0; 3]; CELLS]; h], cols: vec![[[0; 3]; CELLS]; w], black }
    }
}

/// One frame's cell means of `n` (`NaN`: no pixels).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct FrameMeans {
    rows: Vec<[f32; CELLS]>,
    cols: Vec<[f32; CELLS]>,
}

/// A line's cells: pixel count and clean level above black.
type CellLevels = [(u32, f32); CELLS];

/// The cells' pixel counts and clean levels above black (the same in every frame of a burst).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Cells {
    rows: Vec<CellLevels>,
    cols: Vec<CellLevels>,
}

/// Measured offsets of one kind, burst by burst (each burst's histogram and moments).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct OffsetHistogram {
    bursts: Vec<BurstOffsets>,
}

/// One burst's line offsets.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
struct BurstOffsets {
    /// Mean clean level of the lines above black (DN).
    level: f64,
    /// Offsets at 1/64 DN.
    counts: BTreeMap<i32, u64>,
    n: u64,
    /// `Σd, Σd², Σq` and `Σ_lines (Q − k·q̄)²·L/(L−1) + n·q̄²` (`q` a line's estimate in one
    /// frame, `Q` its sum over the burst's `k` frames, `q̄ = Σq/n`): the last makes
    /// [`Self::covariance`]'s standard error the one over lines ([`Self::close`]).
    sums: [f64; 4],
}

impl BurstOffsets {
    /// One line's residual `d` and its estimate `q` of the component's variance (module docs);
    /// whether they were taken (both finite).
    fn add(&mut self, d: f64, q: f64) -> bool {
        if !(d.is_finite() && q.is_finite()) {
            return false;
        }
        let k = (d * STEPS_PER_DN).round().clamp(-1e9, 1e9) as i32;
        *self.counts.entry(k).or_default() += 1;
        self.n += 1;
        self.sums[0] += d;
        self.sums[1] += d * d;
        self.sums[2] += q;
        true
    }

    /// Ends the burst: `per_line` holds each line's `(Σq, k)` over the burst's frames. The
    /// frames' deviations from their burst's mean are not independent (they sum to zero), so
    /// neither are one line's estimates: in a 2-frame burst the second frame's residuals are the
    /// first's negated and its estimates the same numbers. Their spread as `n` independent
    /// values put the standard error `√(k/(k−1))` low (`√2` at two frames), and the 3 SE rule
    /// worked as a 2.1 SE one: random sensor 3 of the moving study (2-frame bursts, row noise
    /// 0.005 DN²) got row components of 0.08–0.19 DN² at 3.1–3.7 of those SE. The standard error
    /// is taken over the lines instead, each line's sum over its frames one value.
    fn close(&mut self, per_line: &[(f64, u32)]) {
        let lines = per_line.iter().filter(|l| l.1 > 0).count() as f64;
        if self.n == 0 || lines < 2.0 {
            return;
        }
        let mean = self.sums[2] / self.n as f64;
        let spread: f64 = per_line.iter().map(|&(q, k)| (q - k as f64 * mean).powi(2)).sum();
        self.sums[3] = spread * lines / (lines - 1.0) + self.n as f64 * mean * mean;
    }

    /// The component's variance as this burst measures it (the halves' covariance, the fit's
    /// share put back) and its standard error.
    fn covariance(&self) -> (f64, f64) {
        let n = self.n as f64;
        let cov = self.sums[2] / n;
        (cov, ((self.sums[3] / n - cov * cov).max(0.0) / n).sqrt())
    }

    /// The line means' variance over this burst less the component's: their sampling variance.
    fn sampling(&self) -> f64 {
        let n = self.n as f64;
        let mean = self.sums[0] / n;
        (self.sums[1] / n - mean * mean - self.covariance().0).max(0.0)
    }
}

impl OffsetHistogram {
    fn push(&mut self, burst: BurstOffsets) {
        if burst.n >= 2 {
            self.bursts.push(burst);
        }
    }

    /// The component's variance and its standard error, from the bursts' covariances.
    ///
    /// A line component of the sensor does not depend on the scene's level; what else moves
    /// lines from frame to frame does, and grows with it: sub-pixel shake moves the scene's
    /// gradients (`∝ level`, so its variance `∝ level²`), clipping near white. So the bursts'
    /// covariances are fitted as `σ² + β·level²` (weights `1/SE²`, `β ≥ 0`) and `σ²` is the
    /// component; with one level only, their weighted mean.
    ///
    /// Also the weight each burst has in it (summing to 1).
    fn component(&self) -> ((f64, f64), Vec<f64>) {
        let pts: Vec<(f64, f64, f64)> = self
            .bursts
            .iter()
            .map(|b| {
                let (c, se) = b.covariance();
                (b.level * b.level, c, 1.0 / se.max(1e-9).powi(2))
            })
            .collect();
        let (sw, swx, swy) = pts.iter().fold((0.0, 0.0, 0.0), |a, &(x, y, w)| (a.0 + w, a.1 + w * x, a.2 + w * y));
        if sw <= 0.0 {
            return ((0.0, f64::INFINITY), vec![0.0; pts.len()]);
        }
        let (mx, my) = (swx / sw, swy / sw);
        let mean = ((my, (1.0 / sw).sqrt()), pts.iter().map(|p| p.2 / sw).collect());
        let sxx: f64 = pts.iter().map(|&(x, _, w)| w * (x - mx).powi(2)).sum();
        let sxy: f64 = pts.iter().map(|&(x, y, w)| w * (x - mx) * (y - my)).sum();
        if pts.len() < 3 || sxx <= 1e-12 * sw * mx.max(1.0).powi(2) {
            return mean;
        }
        // A trend only where the covariances do grow with the level (two standard errors).
        let beta = sxy / sxx;
        if beta <= 2.0 / sxx.sqrt() {
            return mean;
        }
        let sigma2 = my - beta * mx;
        // The intercept's weights: `σ² = Σ wᵢ (1/sw − mx (xᵢ − mx)/sxx) yᵢ`; their magnitudes,
        // normalised, say which bursts it rests on.
        let lever: Vec<f64> = pts.iter().map(|&(x, _, w)| (w * (1.0 / sw - mx * (x - mx) / sxx)).abs()).collect();
        let total: f64 = lever.iter().sum();
        ((sigma2, (1.0 / sw + mx * mx / sxx).sqrt()), lever.iter().map(|l| l / total.max(1e-300)).collect())
    }

    /// The distribution of the component (sampling noise taken out), or `None` without data.
    pub(crate) fn distribution(&self, pixel_var: f64) -> Option<OffsetDistribution> {
        let ((sigma2, se), weights) = self.component();
        // The line means' sampling variance where the estimate was made (MODEL_MARGIN).
        let sampling_at_estimate: f64 = self.bursts.iter().zip(&weights).map(|(b, w)| w * b.sampling()).sum();
        let own = sigma2.max(0.0);
        // The shape from the bursts the level does not disturb (all when none qualifies).
        let clean: Vec<&BurstOffsets> =
            self.bursts.iter().filter(|b| b.covariance().0 <= own + SIGNIFICANCE * b.covariance().1).collect();
        let used: Vec<&BurstOffsets> = if clean.is_empty() { self.bursts.iter().collect() } else { clean };
        let n: u64 = used.iter().map(|b| b.n).sum();
        if n < 2 {
            return None;
        }
        let mut counts: BTreeMap<i32, u64> = BTreeMap::new();
        for b in &used {
            for (&k, &c) in &b.counts {
                *counts.entry(k).or_default() += c;
            }
        }
        let n = n as f64;
        let mean = used.iter().map(|b| b.sums[0]).sum::<f64>() / n;
        let measured_var = (used.iter().map(|b| b.sums[1]).sum::<f64>() / n - mean * mean).max(0.0);
        let own = own.min(measured_var);
        let sampling_var = measured_var - own;
        let significant = own > SIGNIFICANCE * se
            && own > MODEL_MARGIN * sampling_at_estimate
            && own > 0.0
            && own >= LINE_RELEVANCE * pixel_var;
        let shrink = if measured_var > 0.0 { (own / measured_var).sqrt() } else { 0.0 };
        // The quantile function of the histogram (each 1/64 DN cell spread uniformly).
        let cells: Vec<(f64, u64)> = counts.iter().map(|(&k, &c)| (k as f64 / STEPS_PER_DN, c)).collect();
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
        Some(OffsetDistribution { quantiles, count: n as u64, measured_var, sampling_var, significant })
    }
}

/// The structured-noise sums of one ISO.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct StructureAccumulator {
    /// The burst being captured: its step, its cells, its frames' means.
    group: Option<(u32, Cells, Vec<FrameMeans>)>,
    rows: [OffsetHistogram; 2],
    cols: [OffsetHistogram; 2],
    frames: Vec<[f32; POSITIONS]>,
    /// Per frame and position, the offset's sampling variance.
    frame_sampling: Vec<[f32; POSITIONS]>,
    /// Per frame and position, the sampling variance the significance test takes
    /// ([`FrameDeviation::test_var`]).
    frame_test_var: Vec<[f32; POSITIONS]>,
    /// Per frame, the burst it belongs to (numbered from 0 in capture order).
    frame_burst: Vec<u32>,
    /// Frames that were part of a burst of at least two.
    frames_used: u64,
    /// Frames alone at their ISO in their burst (no deviation to measure).
    frames_alone: u64,
    /// Per burst, what its frames showed of the light (`flicker.rs`).
    flicker: Vec<BurstFlicker>,
}

/// Cell means of one frame's lines, and the cells' counts and levels above black
/// (`position(line, cell)`: the cell's CFA position).
fn cells(
    lines: &[[LineSums; CELLS]],
    black: &[f32; POSITIONS],
    position: impl Fn(usize, usize) -> usize,
) -> (Vec<[f32; CELLS]>, Vec<CellLevels>) {
    lines
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let mut means = [f32::NAN; CELLS];
            let mut cells = [(0u32, 0f32); CELLS];
            for (j, s) in l.iter().enumerate() {
                if s[2] > 0 {
                    let m = s[2] as f64;
                    means[j] = (s[0] as f64 / m) as f32;
                    cells[j] = (s[2] as u32, (s[1] as f64 / m - black[position(i, j)] as f64) as f32);
                }
            }
            (means, cells)
        })
        .unzip()
}

impl StructureAccumulator {
    /// Records one target frame of burst `step`.
    pub(crate) fn add_frame(&mut self, step: u32, sums: &FrameSums) {
        let (rows, row_cells) = cells(&sums.rows, &sums.black, row_position);
        let (cols, col_cells) = cells(&sums.cols, &sums.black, col_position);
        let means = FrameMeans { rows, cols };
        let cells = Cells { rows: row_cells, cols: col_cells };
        let same = matches!(&self.group, Some((s, c, f)) if *s == step && *c == cells && f.len() < MAX_GROUP);
        if !same {
            self.close_group();
            self.group = Some((step, cells, Vec::new()));
        }
        if let Some((_, _, frames)) = self.group.as_mut() {
            frames.push(means);
        }
    }

    /// Folds the current burst's frames into the histograms.
    fn close_group(&mut self) {
        let Some((_, cells, frames)) = self.group.take() else {
            return;
        };
        let k = frames.len();
        if k < 2 {
            self.frames_alone += k as u64;
            return;
        }
        self.frames_used += k as u64;
        let rescale = (k as f64 / (k as f64 - 1.0)).sqrt();
        let (rows, slopes, level) =
            fold_lines(&frames, &cells.rows, |f| &f.rows, row_position, rescale, &mut self.rows);
        fold_lines(&frames, &cells.cols, |f| &f.cols, col_position, rescale, &mut self.cols);
        // Frame offsets: the rows' intercepts or means (each position is in the rows of one
        // parity), the frames' brightness taken out where it can be (`flicker.rs`).
        let mut fitted: Vec<FrameDeviation> = rows
            .into_iter()
            .filter(|r| r.value.iter().chain(&r.var).chain(&r.test_var).all(|v| v.is_finite()))
            .collect();
        self.flicker.extend(separate(&mut fitted, &slopes, level));
        let burst = self.frame_burst.last().map_or(0, |b| b + 1);
        for r in fitted {
            self.frames.push(r.value.map(|v| (v * rescale) as f32));
            self.frame_sampling.push(r.var.map(|v| (v * rescale * rescale) as f32));
            self.frame_test_var.push(r.test_var.map(|v| (v * rescale * rescale) as f32));
            self.frame_burst.push(burst);
        }
    }

    /// A note on the flicker this ISO's bursts showed (the burst in progress included), for the
    /// pack's warnings.
    pub(crate) fn flicker_note(&self, iso: u32) -> Option<String> {
        let mut acc = self.clone();
        acc.close_group();
        note(iso, &acc.flicker)
    }

    /// The measured components (the burst in progress included); `pixel_var` is the ISO's
    /// lowest measured pixel variance (DN²).
    pub(crate) fn structure(&self, iso: u32, pixel_var: f64) -> IsoStructure {
        let mut acc = self.clone();
        acc.close_group();
        let rows = std::array::from_fn(|p| acc.rows[p].distribution(pixel_var));
        let columns = std::array::from_fn(|p| acc.cols[p].distribution(pixel_var));
        // Frames whose intercepts are well determined: a burst far from black extrapolates its
        // intercepts a long way, and their noise would pass for offsets.
        let spread: Vec<f64> = acc.frame_sampling.iter().map(|v| v.iter().map(|&x| x as f64).sum::<f64>()).collect();
        let mut sorted = spread.clone();
        sorted.sort_by(f64::total_cmp);
        let cut = sorted.get(sorted.len() / 10).map_or(0.0, |q| 4.0 * q);
        let kept: Vec<usize> = (0..spread.len()).filter(|&i| spread[i] <= cut).collect();
        let frames = (kept.len() >= 2).then(|| {
            let n = kept.len() as f64;
            let offsets: Vec<[f32; POSITIONS]> = kept.iter().map(|&i| acc.frames[i]).collect();
            let measured_var: [f64; POSITIONS] =
                std::array::from_fn(|p| offsets.iter().map(|o| (o[p] as f64).powi(2)).sum::<f64>() / n);
            // The intercepts' own sampling variance (pixel noise and row offsets left in the fit).
            let sampling_var: [f64; POSITIONS] =
                std::array::from_fn(|p| kept.iter().map(|&i| acc.frame_sampling[i][p] as f64).sum::<f64>() / n);
            // Under no component each position's `Q` is `χ²` with `ν` degrees of freedom
            // ([`frame_test`]); significant above its upper quantile at SIGNIFICANCE (0.13 %).
            let (q, nu) = frame_test(&acc.frames, &acc.frame_test_var, &acc.frame_burst, &kept);
            let critical = chi2_upper(nu, SIGNIFICANCE);
            let significant = nu > 0.0
                && (0..POSITIONS).any(|p| {
                    let own = measured_var[p] - sampling_var[p];
                    q[p] > critical && own > 1e-6 && own >= FRAME_RELEVANCE * pixel_var
                });
            FrameOffsets { offsets, measured_var, sampling_var, significant }
        });
        IsoStructure { iso, rows, columns, frames, frames_used: acc.frames_used, fpn: None }
    }
}

/// Per position the statistic `Q = Σ o²·(k−1)/k / s̄` over the kept frames (`o` a frame's
/// rescaled offset, `k` its burst's frames, `s̄` the burst's mean sampling variance at that
/// position), and its degrees of freedom `Σ (k−1)/k`: `χ²` under no component.
fn frame_test(
    offsets: &[[f32; POSITIONS]],
    sampling: &[[f32; POSITIONS]],
    burst: &[u32],
    kept: &[usize],
) -> ([f64; POSITIONS], f64) {
    let bursts = burst.iter().map(|&b| b as usize + 1).max().unwrap_or(0);
    let mut size = vec![0usize; bursts];
    for &b in burst {
        size[b as usize] += 1;
    }
    let mut s_sum = vec![[0.0f64; POSITIONS]; bursts];
    let mut s_n = vec![0usize; bursts];
    for &i in kept {
        let b = burst[i] as usize;
        s_n[b] += 1;
        for p in 0..POSITIONS {
            s_sum[b][p] += sampling[i][p] as f64;
        }
    }
    let mut q = [0.0; POSITIONS];
    let mut nu = 0.0;
    for &i in kept {
        let b = burst[i] as usize;
        let k = size[b] as f64;
        let share = (k - 1.0) / k;
        nu += share;
        for p in 0..POSITIONS {
            let s = s_sum[b][p] / s_n[b] as f64;
            if s > 0.0 {
                q[p] += (offsets[i][p] as f64).powi(2) * share / s;
            }
        }
    }
    (q, nu)
}

/// The upper quantile of `χ²_ν` at the normal deviate `z` (Wilson–Hilferty).
fn chi2_upper(nu: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * nu);
    nu * (1.0 - a + z * a.sqrt()).powi(3)
}

/// The CFA position of cell `j` of row `y` (cells by column parity).
fn row_position(y: usize, j: usize) -> usize {
    (y & 1) * 2 + (j & 1)
}

/// The CFA position of cell `j` of column `x` (cells by row parity).
fn col_position(x: usize, j: usize) -> usize {
    (j & 1) * 2 + (x & 1)
}

/// Folds one burst's cell means into the per-parity histograms (module docs): per frame and
/// line parity, the deviations from the burst means are fitted by one intercept per position and
/// one slope on the level; each line's residual goes in with its halves' residuals. Returns per
/// frame the deviations per position (at black, or the frames' means at their level:
/// [`use_slope`]) with their sampling variances; the spread of the slopes of the parities that
/// took them at black; and the burst's mean level above black.
fn fold_lines(
    frames: &[FrameMeans],
    cells: &[[(u32, f32); CELLS]],
    lines: impl Fn(&FrameMeans) -> &Vec<[f32; CELLS]>,
    position: impl Fn(usize, usize) -> usize,
    rescale: f64,
    out: &mut [OffsetHistogram; 2],
) -> (Vec<FrameDeviation>, Vec<SlopeSpread>, f64) {
    let kf = frames.len() as f64;
    // Lines with enough pixels in each half, and their cells' burst means.
    let usable: Vec<usize> = (0..cells.len())
        .filter(|&i| {
            let half = |h: usize| cells[i][2 * h].0 + cells[i][2 * h + 1].0;
            half(0) >= MIN_LINE_PIXELS / 4 && half(1) >= MIN_LINE_PIXELS / 4 && half(0) + half(1) >= MIN_LINE_PIXELS
        })
        .collect();
    let burst_mean: Vec<[f64; CELLS]> = usable
        .iter()
        .map(|&i| std::array::from_fn(|j| frames.iter().map(|f| lines(f)[i][j] as f64).sum::<f64>() / kf))
        .collect();
    let nan = [f64::NAN; POSITIONS];
    let mut intercepts = vec![FrameDeviation { value: nan, var: nan, test_var: nan, level: nan }; frames.len()];
    let mut slopes = Vec::new();
    let (mut level_sum, mut level_weight) = (0.0, 0.0);
    for parity in 0..2 {
        let mut burst = BurstOffsets::default();
        let of_parity: Vec<(usize, usize)> =
            usable.iter().enumerate().filter(|&(_, &i)| i & 1 == parity).map(|(u, &i)| (u, i)).collect();
        if of_parity.len() < 4 {
            continue;
        }
        let (lw, l) = of_parity
            .iter()
            .flat_map(|&(_, i)| cells[i].iter())
            .fold((0.0, 0.0), |a, &(m, level)| (a.0 + m as f64, a.1 + m as f64 * level as f64));
        burst.level = l / lw.max(1.0);
        (level_sum, level_weight) = (level_sum + l, level_weight + lw);
        let mut fits: Vec<(usize, LevelFit)> = Vec::with_capacity(frames.len());
        // Per line: `(Σq, frames)` ([`BurstOffsets::close`]).
        let mut per_line = vec![(0.0, 0u32); of_parity.len()];
        for (fi, f) in frames.iter().enumerate() {
            let fl = lines(f);
            // Points: (intercept index, level, deviation, weight, line) per cell.
            let points: Vec<Point> = of_parity
                .iter()
                .flat_map(|&(u, i)| {
                    let bm = &burst_mean[u];
                    (0..CELLS).filter_map(move |j| {
                        let (m, level) = cells[i][j];
                        let v = fl[i][j] as f64 - bm[j];
                        (m > 0 && v.is_finite()).then_some((j & 1, level as f64, v, m as f64, i))
                    })
                })
                .collect();
            let Some(fit) = LevelFit::new(&points) else { continue };
            // The fit's three parameters take their share of the line residuals' variance.
            let lines_n = of_parity.len() as f64;
            let d_rescale = rescale * (lines_n / (lines_n - 3.0)).sqrt();
            // Per line and half: the residual's `Σ m·r`, and `Σ m`, `Σ m·x` (`x` a cell's row
            // of the design: its parity's intercept, its level).
            let halves: Vec<[(f64, f64, [f64; 3]); 2]> = of_parity
                .iter()
                .map(|&(u, i)| {
                    let bm = &burst_mean[u];
                    let mut acc = [(0.0, 0.0, [0.0; 3]); 2];
                    for j in 0..CELLS {
                        let (m, level) = cells[i][j];
                        let v = fl[i][j] as f64 - bm[j];
                        if m > 0 && v.is_finite() {
                            let (m, level) = (m as f64, level as f64);
                            let h = &mut acc[j >> 1];
                            h.0 += m * (v - fit.at(j & 1, level));
                            h.1 += m;
                            h.2[j & 1] += m;
                            h.2[2] += m * level;
                        }
                    }
                    acc
                })
                .collect();
            let leverage = Leverage::new(&fit.inv, halves.iter().map(|h| add3(h[0].2, h[1].2)));
            for (line, h) in halves.iter().enumerate() {
                let [(sa, ma, ga), (sb, mb, gb)] = *h;
                let d = (sa + sb) / (ma + mb);
                let q = leverage.component(line, [sa / ma, sb / mb, d], (ma, ga), (mb, gb)) * rescale * rescale;
                if burst.add(d * d_rescale, q) {
                    per_line[line].0 += q;
                    per_line[line].1 += 1;
                }
            }
            fits.push((fi, fit));
        }
        burst.close(&per_line);
        // The frame offsets: at black with the slope where the burst's levels tell brightness
        // from offset, else the frames' means at the burst's level (`use_slope`).
        let (with_slope, spread) = use_slope(&fits.iter().map(|(_, f)| f).collect::<Vec<_>>());
        slopes.extend(spread);
        for (fi, fit) in &fits {
            let d = &mut intercepts[*fi];
            for c in 0..2 {
                let p = position(parity, c);
                (d.value[p], d.var[p]) = if with_slope { (fit.coef[c], fit.cov[c][c]) } else { fit.mean[c] };
                d.test_var[p] = fit.offset_var[c];
                d.level[p] = if with_slope { f64::NAN } else { fit.level[c] };
            }
        }
        out[parity].push(burst);
    }
    (intercepts, slopes, level_sum / level_weight.max(1.0))
}

/// Whether a burst's frame offsets are taken at black with the fitted slope (`true`) or as the
/// deviations of its frames' means per position (`false`), whichever has the smaller expected
/// squared error as an estimate of the offset at black.
///
/// Extrapolating to black multiplies the slope's sampling error by the level: a flat field at
/// half scale (levels 1 981 ± 6 DN) gives intercepts with a sampling SD of ~20 DN while its
/// frames' means move by 1 DN. The means carry the frame's brightness change times their level
/// instead, whose variance over the burst is `τ²·L²`, `τ²` the variance of the frames' true
/// slopes: the variance of the fitted slopes less their sampling variance (the slopes are
/// deviations from the burst's, so they sum to zero: `k − 1` degrees of freedom), taken at its
/// lower bound. On 30 simulated flat fields with 0.04 % flicker (25 frames, both row parities) the
/// fitted slopes' spread came out 0.5–2.1× their sandwich variance, so the plain difference chose
/// the slope once and reported 90 DN offsets; the bound needs 2.9× (25 frames).
///
/// Also the slopes' spread, where every frame fitted one.
fn use_slope(fits: &[&LevelFit]) -> (bool, Option<SlopeSpread>) {
    let sloped: Vec<&&LevelFit> = fits.iter().filter(|f| f.with_slope).collect();
    if sloped.len() < 2 || sloped.len() < fits.len() {
        return (false, None);
    }
    let k = sloped.len() as f64;
    let spread = sloped.iter().map(|f| f.coef[2] * f.coef[2]).sum::<f64>() / (k - 1.0);
    let sampling = sloped.iter().map(|f| f.cov[2][2]).sum::<f64>() / k;
    // Its lower bound (three standard errors of the spread): a slope whose frame-to-frame spread
    // is only its sampling noise by chance would extrapolate that noise to black.
    let tau2 = (spread - sampling * (1.0 + SIGNIFICANCE * (2.0 / (k - 1.0)).sqrt())).max(0.0);
    let (mut at_black, mut at_level) = (0.0, 0.0);
    for f in &sloped {
        for c in 0..2 {
            at_black += f.cov[c][c];
            at_level += f.mean[c].1 + tau2 * f.level[c] * f.level[c];
        }
    }
    (at_black < at_level, Some(SlopeSpread { spread, sampling, frames: sloped.len() }))
}

fn add3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|k| a[k] + b[k])
}

fn dot3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|k| a[k] * b[k]).sum()
}

fn mul3(m: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    std::array::from_fn(|r| dot3(&m[r], v))
}

/// What one frame's fit takes from each line's residuals, to undo it (module docs). With `β`
/// the fit's coefficients (weights `m`, the pixels per cell, so `Cov β = s·inv` for a pixel
/// variance `s`), `g` a half's (or line's) mean design row and `G = Σ m x` a line's:
/// - sampling noise: `E[a·b] = −s·gₐᵀ inv g_b`, `E[d²] = s·(1/M − g_dᵀ inv g_d)`;
/// - a line component `σ²`: `E[a·b] = σ²·(1 − gₐᵀ inv G − g_bᵀ inv G + gₐᵀ inv S inv g_b)`,
///   `E[d²] = σ²·(1 − 2 g_dᵀ inv G + g_dᵀ inv S inv g_d)`, `S = Σ_lines G Gᵀ`;
///
/// so the combination of `a·b` and `d²` that cancels `s` is unbiased for `σ²`, line by line.
struct Leverage {
    inv: [[f64; 3]; 3],
    /// `inv · S · inv`.
    isi: [[f64; 3]; 3],
    /// Per line, `inv · G`.
    inv_g: Vec<[f64; 3]>,
}

impl Leverage {
    /// `lines`: each line's `G`, indexed as [`Self::component`] is then called.
    fn new(inv: &[[f64; 3]; 3], lines: impl Iterator<Item = [f64; 3]>) -> Self {
        let mut s = [[0.0; 3]; 3];
        let mut inv_g = Vec::new();
        for g in lines {
            for r in 0..3 {
                for c in 0..3 {
                    s[r][c] += g[r] * g[c];
                }
            }
            inv_g.push(mul3(inv, &g));
        }
        let si: [[f64; 3]; 3] =
            std::array::from_fn(|r| std::array::from_fn(|c| (0..3).map(|k| s[r][k] * inv[k][c]).sum()));
        let isi = std::array::from_fn(|r| std::array::from_fn(|c| (0..3).map(|k| inv[r][k] * si[k][c]).sum()));
        Self { inv: *inv, isi, inv_g }
    }

    /// Line `line`'s unbiased estimate of the component's variance from its halves'
    /// residuals `a`, `b` and its own `d`; the halves' `(M, G)`.
    fn component(&self, line: usize, [a, b, d]: [f64; 3], (ma, ga): (f64, [f64; 3]), (mb, gb): (f64, [f64; 3])) -> f64 {
        let ig = self.inv_g[line];
        let m = ma + mb;
        let ga: [f64; 3] = ga.map(|x| x / ma.max(1e-300));
        let gb: [f64; 3] = gb.map(|x| x / mb.max(1e-300));
        let gd: [f64; 3] = std::array::from_fn(|k| (ma * ga[k] + mb * gb[k]) / m);
        let h_ab = dot3(&ga, &mul3(&self.inv, &gb));
        let c_dd = 1.0 / m - dot3(&gd, &mul3(&self.inv, &gd));
        let alpha_ab = 1.0 - dot3(&ga, &ig) - dot3(&gb, &ig) + dot3(&ga, &mul3(&self.isi, &gb));
        let alpha_dd = 1.0 - 2.0 * dot3(&gd, &ig) + dot3(&gd, &mul3(&self.isi, &gd));
        (c_dd * a * b + h_ab * d * d) / (c_dd * alpha_ab + h_ab * alpha_dd)
    }
}

/// A cell in a line's fit: `(intercept index, level above black, deviation, weight, line)`.
type Point = (usize, f64, f64, f64, usize);

/// Weighted least squares of deviations on `[intercept of cell parity 0, of parity 1, level]`,
/// with cluster-robust (sandwich) covariances, the clusters being the lines: a line's cells share
/// its offset, so they are not independent; and the weighted mean deviation per cell parity
/// (the same fit without the level) with its variance, robust the same way.
struct LevelFit {
    coef: [f64; 3],
    /// `(Σ w x xᵀ)⁻¹` (the slope's row and column 0 without a slope).
    inv: [[f64; 3]; 3],
    cov: [[f64; 3]; 3],
    /// Whether the levels' spread identified the slope (else `coef` holds the means, slope 0).
    with_slope: bool,
    /// Per cell parity: the weighted mean deviation and its variance.
    mean: [(f64, f64); 2],
    /// Per cell parity: the weighted mean level above black.
    level: [f64; 2],
    /// Per cell parity, the frame offset's variance: the intercept's (with a slope) or the
    /// mean's, each line's score corrected for its leverage.
    offset_var: [f64; 2],
}

impl LevelFit {
    fn new(points: &[Point]) -> Option<Self> {
        let row = |c: usize, l: f64| -> [f64; 3] { [(c == 0) as u8 as f64, (c == 1) as u8 as f64, l] };
        let mut xtx = [[0.0; 3]; 3];
        let mut xty = [0.0; 3];
        for &(c, l, v, w, _) in points {
            let x = row(c, l);
            for a in 0..3 {
                xty[a] += w * x[a] * v;
                for b in 0..3 {
                    xtx[a][b] += w * x[a] * x[b];
                }
            }
        }
        if xtx[0][0] <= 0.0 || xtx[1][1] <= 0.0 {
            return None;
        }
        let means = [xty[0] / xtx[0][0], xty[1] / xtx[1][1]];
        let level = [xtx[0][2] / xtx[0][0], xtx[1][2] / xtx[1][1]];
        // Without a spread of levels the slope is not identified: intercepts alone.
        let spread = xtx[2][2] - xtx[0][2].powi(2) / xtx[0][0] - xtx[1][2].powi(2) / xtx[1][1];
        let with_slope = spread > 1e-9 * xtx[2][2].max(1e-300);
        let inv = if with_slope {
            invert3(&xtx)?
        } else {
            [[1.0 / xtx[0][0], 0.0, 0.0], [0.0, 1.0 / xtx[1][1], 0.0], [0.0, 0.0, 0.0]]
        };
        let coef: [f64; 3] = std::array::from_fn(|a| (0..3).map(|b| inv[a][b] * xty[b]).sum());
        let fitted = |c: usize, l: f64| -> f64 { (0..3).map(|a| row(c, l)[a] * coef[a]).sum() };
        // Sandwich: inv · Σ_lines s sᵀ · inv, `s` a line's score `Σ w r x`; the means' the same
        // with `r` the deviation from the mean.
        let mut meat = [[0.0; 3]; 3];
        let mut mean_meat = [0.0; 2];
        let mut score = [0.0; 3];
        let mut mean_score = [0.0; 2];
        // The same with each line's score scaled by `1/√(1 − h)`, `h` its leverage (`CR2`,
        // the trace of its block of the hat matrix): the residuals are the fit's, which took
        // most from the lines that weigh most in it (the darkest and brightest, for an
        // intercept extrapolated to black).
        let mut meat2 = [[0.0; 3]; 3];
        let mut mean_meat2 = [0.0; 2];
        let mut lev = [0.0; 3];
        let mut flush = |score: &mut [f64; 3], mean_score: &mut [f64; 2], lev: &mut [f64; 3]| {
            let keep = |h: f64| 1.0 / (1.0 - h.min(0.9));
            for a in 0..3 {
                for b in 0..3 {
                    meat[a][b] += score[a] * score[b];
                    meat2[a][b] += score[a] * score[b] * keep(lev[0]);
                }
            }
            for c in 0..2 {
                mean_meat[c] += mean_score[c] * mean_score[c];
                mean_meat2[c] += mean_score[c] * mean_score[c] * keep(lev[1 + c]);
            }
            *score = [0.0; 3];
            *mean_score = [0.0; 2];
            *lev = [0.0; 3];
        };
        let mut line = points.first().map_or(0, |p| p.4);
        for &(c, l, v, w, i) in points {
            if i != line {
                flush(&mut score, &mut mean_score, &mut lev);
                line = i;
            }
            let x = row(c, l);
            let r = v - fitted(c, l);
            for a in 0..3 {
                score[a] += w * r * x[a];
            }
            mean_score[c] += w * (v - means[c]);
            lev[0] += w * dot3(&x, &mul3(&inv, &x));
            lev[1 + c] += w / xtx[c][c];
        }
        flush(&mut score, &mut mean_score, &mut lev);
        let cov: [[f64; 3]; 3] = std::array::from_fn(|a| {
            std::array::from_fn(|d| {
                (0..3).map(|b| (0..3).map(|c| inv[a][b] * meat[b][c] * inv[c][d]).sum::<f64>()).sum::<f64>()
            })
        });
        let mean = std::array::from_fn(|c| (means[c], mean_meat[c] / (xtx[c][c] * xtx[c][c])));
        let offset_var = std::array::from_fn(|c| {
            if with_slope {
                (0..3).map(|b| (0..3).map(|d| inv[c][b] * meat2[b][d] * inv[d][c]).sum::<f64>()).sum::<f64>()
            } else {
                mean_meat2[c] / (xtx[c][c] * xtx[c][c])
            }
        });
        Some(Self { coef, inv, cov, with_slope, mean, level, offset_var })
    }

    fn at(&self, c: usize, level: f64) -> f64 {
        self.coef[c] + self.coef[2] * level
    }
}

/// Inverse of a symmetric 3×3 matrix (`None` when singular).
fn invert3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let c = |a: usize, b: usize| {
        let (a1, a2) = ((a + 1) % 3, (a + 2) % 3);
        let (b1, b2) = ((b + 1) % 3, (b + 2) % 3);
        m[a1][b1] * m[a2][b2] - m[a1][b2] * m[a2][b1]
    };
    let det = m[0][0] * c(0, 0) + m[0][1] * c(0, 1) + m[0][2] * c(0, 2);
    if !det.is_finite() || det.abs() < 1e-300 {
        return None;
    }
    Some(std::array::from_fn(|a| std::array::from_fn(|b| c(b, a) / det)))
}
