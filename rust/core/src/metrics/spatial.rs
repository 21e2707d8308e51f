//! Spatial measures of noise (method.md, "Evaluation"): what a pixel-independent model cannot make
//! and a histogram JSD cannot see. All are measured on the same flat pixels for real and
//! synthetic noise (`capture − round(clean)`, `synthesized − round(clean)`, one clean image per
//! EV step):
//!
//! - **Row-mean variance**: per frame, the mean of the noise over the flat pixels of each row
//!   (rows with at least [`MIN_LINE_PIXELS`] flat pixels, both CFA columns together), the
//!   frame's mean noise at each CFA position taken out first (a black-level error per position
//!   would make even and odd rows alternate). What is
//!   the same in every frame of a burst (same EV step and ISO) is not row noise but a fixed
//!   pattern — the clean image's own error, DSNU, and above all the noise's mean at each level,
//!   which differs between the patches a row crosses — so each row's mean is taken relative to
//!   its mean over the burst's `k` frames, the frame's values are centred on their mean over
//!   rows (which removes the frame's black-level error) and scaled by `√(k/(k − 1))` (which
//!   restores the variance the burst mean took). The variance across rows (divisor `R − 1`),
//!   averaged over frames, is reported as the ratio synthetic/real: row (banding) noise of RMS
//!   `σ_r` adds `σ_r²` to the real value, while pixel-independent noise of variance `σ²` gives
//!   only `σ²/m` for rows of `m` flat pixels. Its standard error is from the spread of the
//!   per-frame values within bursts (EV steps differ in level, hence in pixel noise, so the
//!   spread across steps is not sampling noise). Bursts of one frame do not count. **Column means**: the same with
//!   columns.
//! - **Row-offset distribution**: those row values of every frame pooled, as a histogram
//!   with a common binning (bins of ¼ of the real values' standard deviation, centred on 0,
//!   everything beyond ±8 SD in the outermost bins), JSD (natural log) synthetic against real.
//!   Its finite-sample floor is two halves of the real frames against each other, scaled like
//!   the pixel JSD floor ([`super::floor_scale`]).
//! - **Frame offsets**: per frame and CFA position, the mean noise over the position's flat
//!   pixels; its variance across the frames of a burst (same EV step and ISO; pooled within
//!   bursts, divisor `k − 1`), summed over positions. Ratio synthetic/real.
//! - **Noise power spectrum (NPS)**: square crops of [`NPS_TILE`]×[`NPS_TILE`] same-colour pixels
//!   (a CFA plane, i.e. 32×32 sensor pixels) that are wholly flat, placed without overlap by a
//!   row-major scan in steps of a quarter tile. Per crop and frame the noise's mean is removed
//!   and the periodogram `|DFT|² / T²` taken (white noise of variance σ² has σ² in every bin);
//!   periodograms are averaged per CFA position (in DN², the curves reported and drawn) and,
//!   for the distances, each divided by its crop's white level (mean power off both axes)
//!   first, so that dark crops, where banding stands out, weigh as much as bright ones. Three curves summarise it: the **row** curve
//!   `P(f_y, f_x = 0)` (row offsets live at zero horizontal frequency), the **column** curve
//!   `P(f_y = 0, f_x)`, and the **radial** mean of the other bins by rounded radius. Each
//!   spectrum is divided by its white level (the radial curve's mean): the noise variance is the
//!   pixel JSDs' business, the spectrum's shape (spatial correlation) is this one's. The NPS
//!   distance is the mean absolute log ratio `|ln(P̂_synth / P̂_real)|` over the points of the
//!   three curves (T/2 + T/2 + 11 = 27 for T = 16), averaged over positions weighted by real
//!   crops; the row and column distances are the same over the row (banding) or column curve
//!   alone. It is 0 for equal shapes, `ln 2 ≈ 0.69` for a factor 2 at every point, and robust:
//!   no point can weigh more than its log ratio. Sampling noise makes each point's log off by about
//!   `1/√(2·crops·frames)`, so the distance of two independent real sets is not 0: its floor is
//!   the halves' distance scaled by `√(floor_scale)` (the distance's bias falls as `1/√n`, not
//!   `1/n` as a JSD's).
//!
//! The spectra themselves (crops, periodograms, curves, distances) are in [`super::nps`].

use serde::{Deserialize, Serialize};

use super::line_pixels::LinePixelPart;
use super::nps::{Dft, find_tiles};
pub use super::nps::{NPS_TILE, NpsCurves, nps_log_distance, nps_log_distances};
use crate::model::layout::{POSITIONS, position};

/// A row (column) joins the row-mean (column-mean) statistics with at least this many flat
/// pixels.
pub const MIN_LINE_PIXELS: usize = 16;

/// Bins per real standard deviation of the row-offset histogram.
const BINS_PER_SD: f64 = 4.0;
/// The histogram spans ±this many real standard deviations (outer values go to the end bins).
const SPAN_SD: f64 = 8.0;

/// Where the flat pixels of an image are, fixed per EV step: the pixels the spatial measures
/// use, their rows and columns, and the NPS crops.
#[derive(Debug, Clone, PartialEq)]
pub struct FlatLayout {
    width: usize,
    height: usize,
    /// Row-major indices of the flat pixels.
    flat: Vec<u32>,
    /// Flat pixels per row and per column.
    row_count: Vec<u32>,
    col_count: Vec<u32>,
    /// NPS crops per CFA position: top-left corner (plane row, plane column).
    tiles: [Vec<(u32, u32)>; POSITIONS],
}

impl FlatLayout {
    /// The layout of a `width × height` image whose flat pixels are those where `is_flat(index)`
    /// (row-major index) holds.
    pub fn new(width: usize, height: usize, is_flat: impl Fn(usize) -> bool) -> Self {
        let mut flat = Vec::new();
        let mut row_count = vec![0u32; height];
        let mut col_count = vec![0u32; width];
        let mut mask = vec![false; width * height];
        for y in 0..height {
            for x in 0..width {
                let i = y * width + x;
                if is_flat(i) {
                    flat.push(i as u32);
                    row_count[y] += 1;
                    col_count[x] += 1;
                    mask[i] = true;
                }
            }
        }
        let tiles = std::array::from_fn(|p| find_tiles(width, height, &mask, p));
        Self { width, height, flat, row_count, col_count, tiles }
    }

    /// Image width.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Image height.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Number of flat pixels.
    pub fn flat_pixels(&self) -> usize {
        self.flat.len()
    }

    /// Rows with at least [`MIN_LINE_PIXELS`] flat pixels.
    pub fn rows(&self) -> usize {
        self.row_count.iter().filter(|&&c| c as usize >= MIN_LINE_PIXELS).count()
    }

    /// Columns with at least [`MIN_LINE_PIXELS`] flat pixels.
    pub fn cols(&self) -> usize {
        self.col_count.iter().filter(|&&c| c as usize >= MIN_LINE_PIXELS).count()
    }

    /// NPS crops at a CFA position.
    pub fn tiles(&self, pos: usize) -> usize {
        self.tiles[pos].len()
    }
}

/// The spatial statistics of one set of frames (real, a real half, or one synthetic set).
#[derive(Debug, Clone, PartialEq)]
pub struct SpatialSamples {
    /// Per frame: the variance across rows of the centred row means.
    row_var: Vec<f64>,
    /// Per frame: the variance across columns of the centred column means.
    col_var: Vec<f64>,
    /// `Σ_bursts n_b · s_b²` of the per-frame row (column) values, `s_b²` their variance within
    /// burst `b`: the sampling variance of their sum, free of the differences between EV steps.
    row_var_acc: f64,
    col_var_acc: f64,
    /// Every frame's temporal row offsets (see [`temporal_lines`]).
    row_offsets: Vec<f64>,
    /// Per-frame, per-position mean noise of the current burst.
    burst: Vec<[Option<f64>; POSITIONS]>,
    /// Per-frame row and column means of the current burst.
    burst_rows: Vec<Vec<f64>>,
    burst_cols: Vec<Vec<f64>>,
    /// Within-burst sums of squares of the frame means and their degrees of freedom.
    frame_ss: [f64; POSITIONS],
    frame_dof: [u64; POSITIONS],
    /// Summed periodograms per position (DN², and each divided by its crop's white level) and
    /// how many.
    nps: [Vec<f64>; POSITIONS],
    nps_norm: [Vec<f64>; POSITIONS],
    nps_count: [u64; POSITIONS],
    nps_norm_count: [u64; POSITIONS],
    frames: u64,
    /// The part of the line-mean variances the pixels' own noise makes.
    pub(crate) line_pixels: LinePixelPart,
}

impl Default for SpatialSamples {
    fn default() -> Self {
        Self::new()
    }
}

/// Sample variance (divisor n − 1) of values; `None` below two.
fn variance(v: &[f64]) -> Option<f64> {
    if v.len() < 2 {
        return None;
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    Some(v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64)
}

/// Mean of per-frame values and its standard error from `acc` (`Σ n_b · s_b²` over bursts).
fn mean_se(v: &[f64], acc: f64) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let n = v.len() as f64;
    Some((v.iter().sum::<f64>() / n, acc.sqrt() / n))
}

/// Line means of one frame: `NaN` for lines with too few flat pixels.
fn line_means(sum: &[f64], count: &[u32]) -> Vec<f64> {
    sum.iter().zip(count).map(|(s, c)| if *c as usize >= MIN_LINE_PIXELS { s / *c as f64 } else { f64::NAN }).collect()
}

/// The temporal part of a burst's line means: each line's mean minus its mean over the burst's
/// frames, then each frame's values centred on their mean over lines, scaled by `√(k/(k − 1))`
/// (so that their variance estimates the variance of one frame's line offsets). One vector of
/// valid lines per frame; nothing for bursts of fewer than two frames.
fn temporal_lines(frames: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let k = frames.len();
    if k < 2 {
        return Vec::new();
    }
    let n = frames[0].len();
    let burst_mean: Vec<f64> = (0..n).map(|i| frames.iter().map(|f| f[i]).sum::<f64>() / k as f64).collect();
    let scale = (k as f64 / (k as f64 - 1.0)).sqrt();
    frames
        .iter()
        .map(|f| {
            let d: Vec<f64> = f.iter().zip(&burst_mean).filter(|(v, _)| v.is_finite()).map(|(v, m)| v - m).collect();
            if d.is_empty() {
                return d;
            }
            let m = d.iter().sum::<f64>() / d.len() as f64;
            d.into_iter().map(|v| (v - m) * scale).collect()
        })
        .collect()
}

impl SpatialSamples {
    /// An empty set.
    pub fn new() -> Self {
        Self {
            row_var: Vec::new(),
            col_var: Vec::new(),
            row_var_acc: 0.0,
            col_var_acc: 0.0,
            row_offsets: Vec::new(),
            burst: Vec::new(),
            burst_rows: Vec::new(),
            burst_cols: Vec::new(),
            frame_ss: [0.0; POSITIONS],
            frame_dof: [0; POSITIONS],
            nps: std::array::from_fn(|_| vec![0.0; NPS_TILE * NPS_TILE]),
            nps_norm: std::array::from_fn(|_| vec![0.0; NPS_TILE * NPS_TILE]),
            nps_count: [0; POSITIONS],
            nps_norm_count: [0; POSITIONS],
            frames: 0,
            line_pixels: LinePixelPart::default(),
        }
    }

    /// Adds one frame's noise: `noise` is row-major, `layout`'s size, read at its flat pixels
    /// only. Frames of one burst (same EV step and ISO) come between two [`Self::end_burst`].
    pub fn add_frame(&mut self, layout: &FlatLayout, noise: &[i32]) {
        debug_assert_eq!(noise.len(), layout.width * layout.height);
        let w = layout.width;
        let mut row_sum = vec![0.0f64; layout.height];
        let mut col_sum = vec![0.0f64; w];
        let mut pos_sum = [0.0f64; POSITIONS];
        let mut pos_n = [0u64; POSITIONS];
        for &i in &layout.flat {
            let i = i as usize;
            let p = position(i / w, i % w);
            pos_sum[p] += noise[i] as f64;
            pos_n[p] += 1;
        }
        // Line means of the noise less the frame's mean at each CFA position: a frame offset
        // per position would otherwise alternate between even and odd rows (columns).
        let pos_mean: [f64; POSITIONS] = std::array::from_fn(|p| pos_sum[p] / pos_n[p].max(1) as f64);
        for &i in &layout.flat {
            let i = i as usize;
            let (y, x) = (i / w, i % w);
            let v = noise[i] as f64 - pos_mean[position(y, x)];
            row_sum[y] += v;
            col_sum[x] += v;
        }
        self.line_pixels.add_frame(&layout.flat, w, (&layout.row_count, &layout.col_count), |i| {
            noise[i] as f64 - pos_mean[position(i / w, i % w)]
        });
        self.burst_rows.push(line_means(&row_sum, &layout.row_count));
        self.burst_cols.push(line_means(&col_sum, &layout.col_count));
        self.burst.push(std::array::from_fn(|p| (pos_n[p] > 0).then(|| pos_sum[p] / pos_n[p] as f64)));
        let dft = Dft::new();
        let t = NPS_TILE;
        let mut crop = vec![0.0f64; t * t];
        for p in 0..POSITIONS {
            let (dy, dx) = (p / 2, p % 2);
            for &(ty, tx) in &layout.tiles[p] {
                for yy in 0..t {
                    for xx in 0..t {
                        let (y, x) = (2 * (ty as usize + yy) + dy, 2 * (tx as usize + xx) + dx);
                        crop[yy * t + xx] = noise[y * w + x] as f64;
                    }
                }
                if dft.add_periodogram(&mut crop, &mut self.nps[p], &mut self.nps_norm[p]) {
                    self.nps_norm_count[p] += 1;
                }
                self.nps_count[p] += 1;
            }
        }
        self.frames += 1;
    }

    /// Ends a burst: its frames' row and column means (centred on their burst means) and the
    /// spread of their mean noise join the statistics. A burst needs two frames or more.
    pub fn end_burst(&mut self) {
        for p in 0..POSITIONS {
            let v: Vec<f64> = self.burst.iter().filter_map(|m| m[p]).collect();
            if v.len() >= 2 {
                let m = v.iter().sum::<f64>() / v.len() as f64;
                self.frame_ss[p] += v.iter().map(|x| (x - m).powi(2)).sum::<f64>();
                self.frame_dof[p] += v.len() as u64 - 1;
            }
        }
        self.burst.clear();
        let mut rv = Vec::new();
        for rows in temporal_lines(&self.burst_rows) {
            if let Some(v) = variance(&rows) {
                rv.push(v);
                self.row_offsets.extend(rows);
            }
        }
        let cv: Vec<f64> = temporal_lines(&self.burst_cols).iter().filter_map(|c| variance(c)).collect();
        for (vals, all, acc) in
            [(rv, &mut self.row_var, &mut self.row_var_acc), (cv, &mut self.col_var, &mut self.col_var_acc)]
        {
            if let Some(s2) = variance(&vals) {
                *acc += vals.len() as f64 * s2;
            }
            all.extend(vals);
        }
        self.burst_rows.clear();
        self.burst_cols.clear();
        self.line_pixels.end_burst(MIN_LINE_PIXELS);
    }

    /// Frames added.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Mean over frames of the row-mean variance, and its standard error.
    pub fn row_var(&self) -> Option<(f64, f64)> {
        mean_se(&self.row_var, self.row_var_acc)
    }

    /// Mean over frames of the column-mean variance, and its standard error.
    pub fn col_var(&self) -> Option<(f64, f64)> {
        mean_se(&self.col_var, self.col_var_acc)
    }

    /// Every frame's temporal row offsets (burst- and frame-centred row means).
    pub fn row_offsets(&self) -> &[f64] {
        &self.row_offsets
    }

    /// Within-burst variance of the per-frame mean noise at a position (pooled over bursts).
    pub fn frame_offset_var(&self, pos: usize) -> Option<f64> {
        (self.frame_dof[pos] > 0).then(|| self.frame_ss[pos] / self.frame_dof[pos] as f64)
    }

    /// The NPS curves at a position (`None` without crops).
    pub fn nps(&self, pos: usize) -> Option<NpsCurves> {
        let n = self.nps_count[pos];
        (n > 0).then(|| {
            let p: Vec<f64> = self.nps[pos].iter().map(|v| v / n as f64).collect();
            NpsCurves::from_periodogram(&p, n)
        })
    }

    /// The NPS curves at a position with every crop's periodogram divided by its white level
    /// before averaging (each crop weighs the same, whatever its level): what the distances use.
    pub fn nps_normalised(&self, pos: usize) -> Option<NpsCurves> {
        let n = self.nps_norm_count[pos];
        (n > 0).then(|| {
            let p: Vec<f64> = self.nps_norm[pos].iter().map(|v| v / n as f64).collect();
            NpsCurves::from_periodogram(&p, n)
        })
    }

    /// Periodograms averaged at a position.
    pub fn periodograms(&self, pos: usize) -> u64 {
        self.nps_count[pos]
    }

    /// Adds another set's statistics (e.g. the seeds of one model, for its NPS curves).
    pub fn merge(&mut self, other: &SpatialSamples) {
        self.row_var.extend_from_slice(&other.row_var);
        self.col_var.extend_from_slice(&other.col_var);
        self.row_var_acc += other.row_var_acc;
        self.col_var_acc += other.col_var_acc;
        self.row_offsets.extend_from_slice(&other.row_offsets);
        for p in 0..POSITIONS {
            self.frame_ss[p] += other.frame_ss[p];
            self.frame_dof[p] += other.frame_dof[p];
            for (a, b) in self.nps[p].iter_mut().zip(&other.nps[p]) {
                *a += b;
            }
            for (a, b) in self.nps_norm[p].iter_mut().zip(&other.nps_norm[p]) {
                *a += b;
            }
            self.nps_count[p] += other.nps_count[p];
            self.nps_norm_count[p] += other.nps_norm_count[p];
        }
        self.frames += other.frames;
        self.line_pixels.merge(&other.line_pixels);
    }
}

/// The common bin width of row-offset histograms: a quarter of the real row offsets' standard
/// deviation (`None` with fewer than two offsets or no spread).
pub fn row_offset_bin_width(real: &SpatialSamples) -> Option<f64> {
    let sd = variance(&real.row_offsets)?.sqrt();
    (sd > 1e-9).then_some(sd / BINS_PER_SD)
}

/// Histogram of values on bins of width `h` centred on 0, values beyond ±8 SD in the end bins.
fn offset_histogram(values: &[f64], h: f64) -> Vec<f64> {
    let k = (SPAN_SD * BINS_PER_SD) as i64;
    let mut out = vec![0.0f64; (2 * k + 1) as usize];
    for &v in values {
        let b = ((v / h).round() as i64).clamp(-k, k);
        out[(b + k) as usize] += 1.0;
    }
    out
}

/// JSD (natural log) of two sets of row offsets on bins of width `h`.
pub fn row_offset_jsd(a: &[f64], b: &[f64], h: f64) -> f64 {
    super::jsd(&offset_histogram(a, h), &offset_histogram(b, h))
}

/// The spatial measures of one set of frames against another (synthetic against real; or one
/// real half against the other).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct SpatialComparison {
    /// Row-mean variance, other / real, and its standard error.
    pub row_var_ratio: Option<f64>,
    pub row_var_ratio_se: Option<f64>,
    /// Column-mean variance, other / real, and its standard error.
    pub col_var_ratio: Option<f64>,
    pub col_var_ratio_se: Option<f64>,
    /// JSD of the row-offset histograms.
    pub row_offset_jsd: Option<f64>,
    /// Within-burst variance of the per-frame mean noise, summed over positions, other / real.
    pub frame_offset_var_ratio: Option<f64>,
    /// Mean absolute log ratio of the white-normalised NPS curves ([`nps_log_distances`]),
    /// weighted over positions by real crops: all points, the row curve alone (banding), the
    /// column curve alone.
    pub nps_distance: Option<f64>,
    #[serde(default)]
    pub nps_row_distance: Option<f64>,
    #[serde(default)]
    pub nps_col_distance: Option<f64>,
    /// Row-mean and column-mean variance with the other set's pixels' own noise swapped for
    /// the real set's, `(L_o − P_o + P_r) / L_r` ([`super::line_pixels`]): what the lines share,
    /// free of a difference in the pixels' frame-to-frame noise (the calibration clean image's
    /// error, which synthesis draws afresh in every frame). Not written to the eval JSON.
    #[serde(skip)]
    pub row_var_ratio_on_real: Option<f64>,
    #[serde(skip)]
    pub col_var_ratio_on_real: Option<f64>,
}

fn ratio_se(a: Option<(f64, f64)>, b: Option<(f64, f64)>) -> (Option<f64>, Option<f64>) {
    match (a, b) {
        (Some((ma, sa)), Some((mb, sb))) if ma > 0.0 => {
            let r = mb / ma;
            let se = r * ((sa / ma).powi(2) + if mb > 0.0 { (sb / mb).powi(2) } else { 0.0 }).sqrt();
            (Some(r), se.is_finite().then_some(se))
        }
        _ => (None, None),
    }
}

/// `other` against `real` (see the module docs); `bin_width` is the common binning of the
/// row-offset histograms ([`row_offset_bin_width`] of the full real set).
pub fn compare_spatial(real: &SpatialSamples, other: &SpatialSamples, bin_width: Option<f64>) -> SpatialComparison {
    let (row_var_ratio, row_var_ratio_se) = ratio_se(real.row_var(), other.row_var());
    let (col_var_ratio, col_var_ratio_se) = ratio_se(real.col_var(), other.col_var());
    let row_offset_jsd = bin_width
        .filter(|_| !real.row_offsets.is_empty() && !other.row_offsets.is_empty())
        .map(|h| row_offset_jsd(&real.row_offsets, &other.row_offsets, h));
    let (mut fr, mut fo) = (0.0, 0.0);
    let mut any = false;
    for p in 0..POSITIONS {
        if let (Some(a), Some(b)) = (real.frame_offset_var(p), other.frame_offset_var(p)) {
            fr += a;
            fo += b;
            any = true;
        }
    }
    let frame_offset_var_ratio = (any && fr > 0.0).then(|| fo / fr);
    let (mut acc, mut wsum) = ([0.0; 3], 0.0);
    for p in 0..POSITIONS {
        if let (Some(a), Some(b)) = (real.nps_normalised(p), other.nps_normalised(p))
            && let Some(d) = nps_log_distances(&a, &b)
        {
            for (s, v) in acc.iter_mut().zip(d) {
                *s += v * a.periodograms as f64;
            }
            wsum += a.periodograms as f64;
        }
    }
    let [nps_distance, nps_row_distance, nps_col_distance] = acc.map(|v| (wsum > 0.0).then(|| v / wsum));
    let on_real = |l_r: Option<(f64, f64)>, l_o: Option<(f64, f64)>, p_r: &[f64], p_o: &[f64]| {
        let (l_r, l_o) = (l_r?.0, l_o?.0);
        let (p_r, p_o) = (LinePixelPart::mean(p_r)?, LinePixelPart::mean(p_o)?);
        (l_r > 0.0).then(|| (l_o - p_o + p_r) / l_r)
    };
    let (rp, op) = (&real.line_pixels, &other.line_pixels);
    SpatialComparison {
        row_var_ratio_on_real: on_real(real.row_var(), other.row_var(), &rp.rows, &op.rows),
        col_var_ratio_on_real: on_real(real.col_var(), other.col_var(), &rp.cols, &op.cols),
        row_var_ratio,
        row_var_ratio_se,
        col_var_ratio,
        col_var_ratio_se,
        row_offset_jsd,
        frame_offset_var_ratio,
        nps_distance,
        nps_row_distance,
        nps_col_distance,
    }
}

/// The mean of several comparisons (one per synthetic set), field by field over the sets that
/// have it; standard errors are averaged too (each set is as large as the real one).
pub fn mean_comparison(v: &[SpatialComparison]) -> SpatialComparison {
    let mean = |f: &dyn Fn(&SpatialComparison) -> Option<f64>| {
        let xs: Vec<f64> = v.iter().filter_map(f).collect();
        (!xs.is_empty()).then(|| xs.iter().sum::<f64>() / xs.len() as f64)
    };
    SpatialComparison {
        row_var_ratio: mean(&|c| c.row_var_ratio),
        row_var_ratio_se: mean(&|c| c.row_var_ratio_se),
        col_var_ratio: mean(&|c| c.col_var_ratio),
        col_var_ratio_se: mean(&|c| c.col_var_ratio_se),
        row_offset_jsd: mean(&|c| c.row_offset_jsd),
        frame_offset_var_ratio: mean(&|c| c.frame_offset_var_ratio),
        nps_distance: mean(&|c| c.nps_distance),
        nps_row_distance: mean(&|c| c.nps_row_distance),
        nps_col_distance: mean(&|c| c.nps_col_distance),
        row_var_ratio_on_real: mean(&|c| c.row_var_ratio_on_real),
        col_var_ratio_on_real: mean(&|c| c.col_var_ratio_on_real),
    }
}

/// The finite-sample floor of the spatial measures: one real half against the other, with the
/// factors that carry the JSD and the NPS distance to the comparison's sample sizes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SpatialFloor {
    /// The halves' measures as measured (ratios of half B over half A: ≈ 1 within their SE).
    pub halves: SpatialComparison,
    /// [`super::floor_scale`] of the row offsets (halves against the full real set).
    pub row_offset_scale: f64,
    /// `√(floor_scale)` of the NPS periodograms.
    pub nps_scale: f64,
}

impl SpatialFloor {
    /// The floor of `a` against `b` for a comparison of `real` against as many synthetic frames.
    pub fn measure(
        a: &SpatialSamples,
        b: &SpatialSamples,
        real: &SpatialSamples,
        bin_width: Option<f64>,
    ) -> Option<Self> {
        if a.frames == 0 || b.frames == 0 {
            return None;
        }
        let halves = compare_spatial(a, b, bin_width);
        let (na, nb, n) = (a.row_offsets.len() as u64, b.row_offsets.len() as u64, real.row_offsets.len() as u64);
        let row_offset_scale = if na > 0 && nb > 0 && n > 0 { super::floor_scale(na, nb, n) } else { 1.0 };
        let sum = |s: &SpatialSamples| s.nps_count.iter().sum::<u64>();
        let (pa, pb, p) = (sum(a), sum(b), sum(real));
        let nps_scale = if pa > 0 && pb > 0 && p > 0 { super::floor_scale(pa, pb, p).sqrt() } else { 1.0 };
        Some(Self { halves, row_offset_scale, nps_scale })
    }

    /// The row-offset JSD floor at the comparison's sample sizes.
    pub fn row_offset_jsd_scaled(&self) -> Option<f64> {
        self.halves.row_offset_jsd.map(|j| j * self.row_offset_scale)
    }

    /// The NPS distance floor at the comparison's sample sizes.
    pub fn nps_distance_scaled(&self) -> Option<f64> {
        self.halves.nps_distance.map(|d| d * self.nps_scale)
    }

    /// The NPS row-curve distance floor at the comparison's sample sizes.
    pub fn nps_row_distance_scaled(&self) -> Option<f64> {
        self.halves.nps_row_distance.map(|d| d * self.nps_scale)
    }

    /// The NPS column-curve distance floor at the comparison's sample sizes.
    pub fn nps_col_distance_scaled(&self) -> Option<f64> {
        self.halves.nps_col_distance.map(|d| d * self.nps_scale)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn gauss(rng: &mut ChaCha8Rng) -> f64 {
        // Box–Muller from two uniforms.
        let (u, v): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random::<f64>());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }

    /// Frames of white noise (σ) plus row offsets (σ_r) on an all-flat `w × h` image.
    fn frames(w: usize, h: usize, n: usize, sigma: f64, row_sd: f64, seed: u64) -> (FlatLayout, SpatialSamples) {
        let layout = FlatLayout::new(w, h, |_| true);
        let mut s = SpatialSamples::new();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        for _ in 0..n {
            let mut img = vec![0i32; w * h];
            for y in 0..h {
                let r = row_sd * gauss(&mut rng);
                for x in 0..w {
                    img[y * w + x] = (sigma * 64.0 * gauss(&mut rng) + 64.0 * r).round() as i32;
                }
            }
            s.add_frame(&layout, &img);
        }
        s.end_burst();
        (layout, s)
    }

    #[test]
    fn white_noise_has_a_flat_spectrum_and_the_row_mean_variance_of_a_mean() {
        let (layout, s) = frames(96, 64, 12, 1.0, 0.0, 1);
        assert_eq!((layout.rows(), layout.cols()), (64, 96));
        // 48×32 planes: two 16×16 crops per row of crops, two rows.
        assert_eq!(layout.tiles(0), 6);
        let (rv, se) = s.row_var().expect("row var");
        let want = 64.0 * 64.0 / 96.0; // σ²/m in DN² (σ = 64 DN)
        assert!((rv / want - 1.0).abs() < 4.0 * se / want + 0.02, "{rv} vs {want} ± {se}");
        let nps = s.nps(0).expect("nps");
        assert_eq!((nps.row.len(), nps.col.len(), nps.radial.len()), (8, 8, 11));
        let mean = nps.points().sum::<f64>() / 27.0;
        assert!((mean / 4096.0 - 1.0).abs() < 0.1, "white level {mean}");
    }

    #[test]
    fn row_offsets_raise_the_row_curve_and_the_row_mean_variance() {
        let (_, plain) = frames(96, 64, 12, 1.0, 0.0, 2);
        let (_, rows) = frames(96, 64, 12, 1.0, 0.3, 3);
        let c = compare_spatial(&rows, &plain, row_offset_bin_width(&rows));
        // Real row variance 64²(0.09 + 1/96), synthetic 64²/96: ratio ≈ 0.104.
        let r = c.row_var_ratio.expect("ratio");
        assert!((0.07..0.15).contains(&r), "{r}");
        assert!(c.col_var_ratio.expect("col") > 0.7);
        let j = c.row_offset_jsd.expect("jsd");
        assert!(j > 0.1, "{j}");
        let (a, b) = (rows.nps(0).expect("nps"), plain.nps(0).expect("nps"));
        // The row curve holds σ² + T·σ_r² (×64²): 1 + 16·0.09 ≈ 2.4 times white.
        let lift = a.row.iter().sum::<f64>() / b.row.iter().sum::<f64>();
        assert!((2.0..2.9).contains(&lift), "{lift}");
        let radial = a.radial.iter().sum::<f64>() / b.radial.iter().sum::<f64>();
        assert!((0.9..1.1).contains(&radial), "{radial}");
        assert!(c.nps_distance.expect("nps") > 0.15);
        assert!(c.nps_row_distance.expect("nps rows") > 0.6);
        assert!(c.nps_col_distance.expect("nps cols") < 0.2);
    }

    #[test]
    fn a_pattern_fixed_across_frames_is_not_row_noise() {
        let (w, h) = (64usize, 48usize);
        let layout = FlatLayout::new(w, h, |_| true);
        let mut s = SpatialSamples::new();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let pattern: Vec<i32> = (0..h).map(|y| (y as i32 % 5) * 40 - 80).collect();
        for _ in 0..3 {
            for _ in 0..4 {
                let img: Vec<i32> =
                    (0..w * h).map(|i| pattern[i / w] + (64.0 * gauss(&mut rng)).round() as i32).collect();
                s.add_frame(&layout, &img);
            }
            s.end_burst();
        }
        let (rv, se) = s.row_var().expect("row var");
        let want = 64.0 * 64.0 / w as f64;
        assert!((rv - want).abs() < 4.0 * se + 0.05 * want, "{rv} vs {want} ± {se}");
        assert_eq!(s.row_offsets().len(), 12 * h);
    }

    #[test]
    fn frame_offsets_are_the_spread_of_frame_means_within_bursts() {
        let layout = FlatLayout::new(32, 32, |_| true);
        let mut s = SpatialSamples::new();
        for (burst, offs) in [[0, 4, 8], [100, 96, 104]].iter().enumerate() {
            for &o in offs.iter() {
                s.add_frame(&layout, &vec![o + burst as i32; 32 * 32]);
            }
            s.end_burst();
        }
        // Each burst: deviations ±4 → sum of squares 32, dof 2; pooled 64 / 4 = 16.
        assert_eq!(s.frame_offset_var(0), Some(16.0));
        assert_eq!(s.frame_offset_var(3), Some(16.0));
        // Constant frames: no row or column spread.
        assert_eq!(s.row_var().map(|v| v.0), Some(0.0));
        assert_eq!(s.row_offsets().len(), 6 * 32);
    }

    #[test]
    fn crops_stay_inside_flat_regions() {
        // A flat square of 40×40 sensor pixels in a 100×80 image: one 16×16 crop per plane.
        let layout = FlatLayout::new(100, 80, |i| {
            let (y, x) = (i / 100, i % 100);
            (20..60).contains(&y) && (30..70).contains(&x)
        });
        for p in 0..POSITIONS {
            assert_eq!(layout.tiles(p), 1, "position {p}");
        }
        assert_eq!(layout.rows(), 40);
        assert_eq!(layout.cols(), 40);
        assert!(FlatLayout::new(20, 20, |_| true).tiles(0) == 0);
    }
}
