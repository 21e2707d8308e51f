//! Target frames folded into one ISO's samples (method.md, "Calibration" 4–6): for every flat
//! pixel, `n = noisy − clean` into the histogram of (fold, CFA position, bin of the clean level),
//! the output code into the code counts, the clean image's selection into its sums, and the
//! frame's brightness into the gain-ratio sums. One pass over the frame, nothing of it kept.

use multiversion::multiversion;
use serde::{Deserialize, Serialize};

use crate::calibrate::drift::{BrightnessSums, Transform};
use crate::calibrate::estimate::FOLDS;
use crate::calibrate::flat::NOT_FLAT;
use crate::calibrate::flat_levels::FlatLevels;
use crate::calibrate::frame::FrameView;
use crate::calibrate::line_base::in_lines;
use crate::calibrate::motion::{FrameMotion, MotionProbe, NEGLIGIBLE_MOTION_PX};
use crate::calibrate::reference::CleanImage;
use crate::calibrate::structure::{CELLS, FrameSums, StructureAccumulator};
use crate::calibrate::window_counts::{LaneCounts, Outside, WindowCounts, count_pairs};

use crate::model::histogram::NoiseHistogram;
use crate::model::layout::{Binning, POSITIONS};

/// Target frames that moved further than this (pixels) against their reference bursts are
/// reported in the pack's warnings.
pub const MOTION_WORTH_SAYING_PX: f64 = 0.05;

/// Everything one target ISO has accumulated.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct IsoAccumulator {
    /// `folds[k][pos][bin]`: target frame `i` of this ISO goes to fold `i mod FOLDS`.
    pub(crate) folds: Vec<Vec<Vec<NoiseHistogram>>>,
    pub(crate) frames: u64,
    pub(crate) samples: u64,
    pub(crate) drift_frames: u64,
    /// `shift[k][pos][bin]`: `[Σδ, Σδ², Σa]` of the selection over the samples of fold `k`.
    pub(crate) shift: Vec<Vec<Vec<[f64; 3]>>>,
    /// How often each output code (0 ..= white) occurs in the target frames, per position: the
    /// codes a sensor never writes ([`crate::model::codes`]).
    pub(crate) codes: Vec<Vec<u64>>,
    /// Σ(target − black) and Σ(clean − black) over flat, unclipped pixels, per position.
    pub(crate) target_sum: [f64; POSITIONS],
    pub(crate) reference_sum: [f64; POSITIONS],
    /// Row, column and frame means of the noise, for the structured components.
    pub(crate) structure: StructureAccumulator,
    /// How the target frames moved against their clean images.
    pub(crate) motion: MotionTally,
}

/// How the target frames of one ISO moved against their reference bursts, and what that cost.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct MotionTally {
    /// Frames registered.
    pub(crate) frames: u64,
    /// Each registered frame's largest displacement (pixels), in arrival order (at most
    /// [`MotionTally::KEPT`] kept; the maximum is kept apart).
    pub(crate) shifts: Vec<f32>,
    /// The largest displacement of any frame (pixels).
    pub(crate) max_shift: f64,
    /// Flat samples left out because the frame's motion changed their level.
    pub(crate) left_out: u64,
    /// Flat samples offered (kept or left out).
    pub(crate) offered: u64,
}

impl MotionTally {
    /// Displacements kept for the median.
    pub(crate) const KEPT: usize = 4096;

    /// The median displacement of the registered frames (pixels).
    pub(crate) fn median_shift(&self) -> f64 {
        let v: Vec<f64> = self.shifts.iter().map(|&s| s as f64).collect();
        if v.is_empty() { 0.0 } else { crate::math::stats::median(&v) }
    }

    /// The largest displacement (pixels) when the chart moved enough to say so
    /// ([`MOTION_WORTH_SAYING_PX`]).
    pub(crate) fn moved(&self) -> Option<f64> {
        (self.frames > 0 && self.max_shift > MOTION_WORTH_SAYING_PX).then_some(self.max_shift)
    }
}

impl IsoAccumulator {
    pub(crate) fn new(binning: &Binning) -> Self {
        Self {
            shift: (0..FOLDS).map(|_| (0..POSITIONS).map(|p| vec![[0.0; 3]; binning.bins(p)]).collect()).collect(),
            codes: vec![vec![0; binning.white as usize + 1]; POSITIONS],
            folds: (0..FOLDS)
                .map(|_| (0..POSITIONS).map(|p| vec![NoiseHistogram::default(); binning.bins(p)]).collect())
                .collect(),
            frames: 0,
            samples: 0,
            drift_frames: 0,
            target_sum: [0.0; POSITIONS],
            reference_sum: [0.0; POSITIONS],
            structure: StructureAccumulator::default(),
            motion: MotionTally::default(),
        }
    }

    /// Whether the accumulator's shape fits a binning (a checkpoint must).
    pub(crate) fn fits(&self, binning: &Binning) -> bool {
        let bins: Vec<usize> = (0..POSITIONS).map(|p| binning.bins(p)).collect();
        let shaped = |lens: Vec<usize>| lens == bins;
        self.folds.len() == FOLDS
            && self.folds.iter().all(|f| shaped(f.iter().map(|h| h.len()).collect()))
            && self.shift.len() == FOLDS
            && self.shift.iter().all(|f| shaped(f.iter().map(|h| h.len()).collect()))
            && self.codes.len() == POSITIONS
            && self.codes.iter().all(|c| c.len() == binning.white as usize + 1)
    }

    /// One position's fold histograms.
    pub(crate) fn folds_of(&self, pos: usize) -> Vec<&[NoiseHistogram]> {
        self.folds.iter().map(|f| f[pos].as_slice()).collect()
    }

    /// One position's selection sums per fold.
    pub(crate) fn shifts_of(&self, pos: usize) -> Vec<&[[f64; 3]]> {
        self.shift.iter().map(|f| f[pos].as_slice()).collect()
    }

    /// One position's histograms summed over folds, trimmed.
    pub(crate) fn histograms(&self, pos: usize) -> Option<Vec<NoiseHistogram>> {
        let mut out = self.folds.first()?.get(pos)?.clone();
        for f in &self.folds[1..] {
            for (o, h) in out.iter_mut().zip(&f[pos]) {
                o.merge(h);
            }
        }
        Some(out.iter().map(|h| h.trimmed()).collect())
    }

    /// Folds one target frame of EV step `step` in, its raw values mapped by `tf`, its
    /// brightness sums already taken (`scale` normalised them), the flat pixels its `motion`
    /// changes left out. Returns the samples added and the flat samples left out.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn add_frame(
        &mut self,
        step: u32,
        frame: &FrameView<'_>,
        image: &CleanImage,
        binning: &Binning,
        tf: &Transform,
        sums: &BrightnessSums,
        scale: f64,
        motion: Option<&FrameMotion>,
    ) -> (u64, u64) {
        let moving = motion.filter(|m| m.max_shift() > NEGLIGIBLE_MOTION_PX);
        if let Some(m) = motion {
            self.motion.frames += 1;
            self.motion.max_shift = self.motion.max_shift.max(m.max_shift());
            if self.motion.shifts.len() < MotionTally::KEPT {
                self.motion.shifts.push(m.max_shift() as f32);
            }
        }

        let (w, h, white) = (image.width, image.height, binning.white);
        let luts: [Vec<u16>; POSITIONS] = std::array::from_fn(|p| binning.lut(p));
        let fold = (self.frames % FOLDS as u64) as usize;
        for (sum, add) in self.shift[fold].iter_mut().zip(&image.selection) {
            for (s, a) in sum.iter_mut().zip(add) {
                for k in 0..3 {
                    s[k] += a[k];
                }
            }
        }
        let clean = &image.levels;
        let (even, odd) = self.folds[fold].split_at_mut(2);
        let (codes_even, codes_odd) = self.codes.split_at_mut(2);
        // Line sums leave out levels near white, where clipping moves lines from frame to frame.
        let black = tf.black.iter().cloned().fold(f32::INFINITY, f32::min);
        let line_top = (black + 0.9 * (white as f32 - black)).clamp(0.0, white as f32) as u16;
        let flat = image.flat_levels.get(clean, w);
        // A frame that moved reads the clean image's gradients (made on the first such frame).
        let moving = moving.map(|m| (m, image.probe.gradients(clean, w)));
        let fold_parity = |parity: usize, hists: &mut [Vec<NoiseHistogram>], codes: &mut [Vec<u64>]| {
            let target = FoldTarget { hists, codes, luts: &luts, flat, white, line_top };
            fold_rows(parity, frame, clean, w, h, target, tf, &image.probe, moving)
        };
        let (r0, r1) = rayon::join(|| fold_parity(0, even, codes_even), || fold_parity(1, odd, codes_odd));
        let samples = r0.samples + r1.samples;
        // A sample left out takes its clean level's selection back out of the frame's sums:
        // they describe exactly the samples the histograms hold.
        let left = r0.left_out.len() + r1.left_out.len();
        for &(pos, level) in r0.left_out.iter().chain(&r1.left_out) {
            let (pos, level) = (pos as usize, level as usize);
            let [d, a] = image.level_selection[pos].get(level).copied().unwrap_or([0.0; 2]);
            let s = &mut self.shift[fold][pos][luts[pos][level] as usize];
            s[0] -= d;
            s[1] -= d * d;
            s[2] -= a;
        }
        self.motion.left_out += left as u64;
        self.motion.offered += samples + left as u64;
        let base = image.line_base.get(clean, w, line_top);
        let mut lines = FrameSums::new(w, h, tf.black);
        for (parity, r) in [(0, &r0), (1, &r1)] {
            for (i, noise) in r.rows.iter().enumerate() {
                let y = parity + 2 * i;
                lines.rows[y] = std::array::from_fn(|cell| {
                    let [level, count] = base.rows[y][cell];
                    [noise[cell], level, count]
                });
            }
        }
        // A column's cell is `row parity | half << 1`.
        for (x, c) in lines.cols.iter_mut().enumerate() {
            *c = std::array::from_fn(|cell| {
                let [level, count] = base.cols[x][cell];
                let r = if cell & 1 == 0 { &r0 } else { &r1 };
                [r.cols[cell >> 1][x], level, count]
            });
        }
        self.structure.add_frame(step, &lines);
        // Brightness sums per position for the gain ratio (after normalisation).
        for p in 0..POSITIONS {
            self.target_sum[p] += sums.frame_pos[p] * scale;
            self.reference_sum[p] += sums.base_pos[p];
        }
        self.frames += 1;
        self.samples += samples;
        (samples, left as u64)
    }
}

/// What [`fold_rows`] returns for the rows of one parity.
struct FoldedRows {
    /// Samples added to the histograms.
    samples: u64,
    /// The (position, clean level) of each sample left out.
    left_out: Vec<(u8, u16)>,
    /// Per row, the sum of the noise over the line pixels of each cell (`x & 3`).
    rows: Vec<[i64; CELLS]>,
    /// Per half (`⌊y/2⌋` parity), per column, the sum of the noise over its line pixels.
    cols: [Vec<i64>; 2],
}

/// Where the rows of one parity go: that parity's two positions' histograms and code counts.
struct FoldTarget<'a> {
    hists: &'a mut [Vec<NoiseHistogram>],
    codes: &'a mut [Vec<u64>],
    luts: &'a [Vec<u16>; POSITIONS],
    /// The clean image's flat levels.
    flat: &'a FlatLevels,
    white: u16,
    /// The highest clean level of the line sums.
    line_top: u16,
}

/// Folds the rows of one parity into that parity's two positions' histograms and code counts.
/// With `motion` (a frame that moved, and the clean image's gradients), the flat pixels whose level the motion changes by more
/// than their tolerance are left out of the histograms, and the line sums take the motion's
/// predicted change out of every pixel's `n` (`probe`: the tolerances); the line
/// sums keep every flat pixel, so that every frame of a burst sums the same pixels into each
/// line (their clean levels and counts are the image's [`LineBase`](crate::calibrate::line_base::LineBase)).
///
/// Each row is three tight loops: the noise `n = value − clean` of every pixel into a row
/// buffer, its line sums (branch-free, vectorised by the compiler), then the histogram and code
/// counts of each position's flat pixels.
#[allow(clippy::too_many_arguments)]
fn fold_rows(
    parity: usize,
    frame: &FrameView<'_>,
    clean: &[u16],
    w: usize,
    h: usize,
    target: FoldTarget<'_>,
    tf: &Transform,
    probe: &MotionProbe,
    motion: Option<(&FrameMotion, &[[i8; 2]])>,
) -> FoldedRows {
    let FoldTarget { hists, codes, luts, flat, white, line_top } = target;
    let mut samples = 0u64;
    let mut left_out: Vec<(u8, u16)> = Vec::new();
    let (mut keep, mut correction, mut line_noise) = match motion {
        Some(_) => (vec![true; w], vec![0i32; w], vec![0i32; w]),
        None => (Vec::new(), Vec::new(), Vec::new()),
    };
    let mut rows = Vec::with_capacity(h / 2 + 1);
    let mut cols = [vec![0i64; w], vec![0i64; w]];
    // The columns' sums of the still rows since they were last added into `cols`.
    let mut narrow_cols = [vec![0i32; w], vec![0i32; w]];
    let mut narrow_rows = [0usize; 2];
    let mut buf = vec![0u16; w];
    let mut noise = vec![0i32; w];
    let (mut out0, mut out1): (Outside, Outside) = (Vec::new(), Vec::new());
    let identity = tf.identity();
    let top = white as usize;
    let (h0, h1) = hists.split_at_mut(1);
    let (hist0, hist1) = (&mut h0[0], &mut h1[0]);
    let (c0, c1) = codes.split_at_mut(1);
    let (codes_out0, codes_out1) = (&mut c0[0][..], &mut c1[0][..]);
    let (p0, p1) = (parity * 2, parity * 2 + 1);
    // Each position has at most a pixel of every other column of every other row.
    let most = w.div_ceil(2) * h.div_ceil(2);
    // Windows by clean level while they hold at most a sixteenth of the position's flat pixels
    // (a count each, in every lane): clearing and flushing them then costs less than counting
    // the output codes apart.
    let window = |p: usize, hist: &[NoiseHistogram]| {
        WindowCounts::new(hist, &luts[p], &flat.levels[p], most, flat.pixels[p] as usize / 16)
    };
    let (mut window0, mut window1) = (window(p0, hist0), window(p1, hist1));
    // The output codes come from the windows when those are by clean level and the noise is the
    // raw value less the clean level; else they are counted apart.
    let by_level = identity && window0.by_level() && window1.by_level();
    let mut apart = (!by_level).then(|| (LaneCounts::new(top), LaneCounts::new(top)));
    for y in (parity..h).step_by(2) {
        let row: &[u16] = match frame.row(y) {
            std::borrow::Cow::Borrowed(r) => r,
            std::borrow::Cow::Owned(v) => {
                buf.copy_from_slice(&v);
                &buf
            }
        };
        let crow = &clean[y * w..y * w + w];
        let half = (y >> 1) & 1;
        // The noise of every pixel, 0 where not flat (the windows' not-flat level takes 0).
        let mut flat_pixels = 0u32;
        // A still frame not transformed: the noise and its line sums in one pass.
        let fused = identity && motion.is_none();
        if fused {
            let (flat, cells) = noise_and_line_sums(row, crow, line_top, &mut noise, &mut narrow_cols[half]);
            flat_pixels = flat;
            rows.push(cells);
        } else if identity {
            flat_pixels = noise_row(row, crow, &mut noise);
        } else {
            for (x, ((n, &v), &c)) in noise.iter_mut().zip(row).zip(crow).enumerate() {
                let t = tf.apply(parity * 2 + (x & 1), v).round().clamp(0.0, white as f32) as i32;
                let is_flat = c != NOT_FLAT;
                *n = (t - c as i32) & (is_flat as i32).wrapping_neg();
                flat_pixels += is_flat as u32;
            }
        }
        if let Some((m, gradient)) = motion {
            // A frame that moved: its predicted change comes out of the line sums.
            m.row_effects(probe, &gradient[y * w..y * w + w], y, crow, &mut keep, &mut correction);
            for ((l, &n), &k) in line_noise.iter_mut().zip(&noise).zip(&correction) {
                *l = n - k;
            }
            rows.push(line_sums(&line_noise, crow, line_top, &mut cols[half]));
        } else {
            // A still frame's noise is a difference of two values in 0 ..= 65535 (|n| < 2¹⁶):
            // its column sums fit 32 bits over a run of rows, and are then added into the
            // 64-bit ones.
            if !fused {
                rows.push(line_sums_narrow(&noise, crow, line_top, &mut narrow_cols[half]));
            }
            narrow_rows[half] += 1;
            if narrow_rows[half] == NARROW_ROWS {
                widen_into(&mut narrow_cols[half], &mut cols[half]);
                narrow_rows[half] = 0;
            }
        }
        if let Some((codes0, codes1)) = apart.as_mut() {
            count_codes(crow, row, top, codes0, codes1);
        }
        // Even columns are position `2·parity`, odd ones `2·parity + 1`: one pass over the
        // row's column pairs feeds both, each pixel's window found by its clean level.
        if motion.is_some() {
            let mut even =
                PositionCounts::new(p0 as u8, &mut window0, &mut *hist0, by_level.then_some(&mut *codes_out0));
            let mut odd =
                PositionCounts::new(p1 as u8, &mut window1, &mut *hist1, by_level.then_some(&mut *codes_out1));
            let pairs = crow.chunks_exact(2).zip(noise.chunks_exact(2));
            for (j, ((c, n), v)) in pairs.zip(row.chunks_exact(2)).enumerate() {
                let x = 2 * j;
                samples += even.add_kept(c[0], n[0], j, keep[x], v[0], &mut left_out);
                samples += odd.add_kept(c[1], n[1], j, keep[x + 1], v[1], &mut left_out);
            }
            if w % 2 == 1 {
                let x = w - 1;
                samples += even.add_kept(crow[x], noise[x], x >> 1, keep[x], row[x], &mut left_out);
            }
        } else {
            out0.clear();
            out1.clear();
            count_pairs(&mut window0, &mut window1, crow, &noise, [&mut out0, &mut out1]);
            // The samples outside their windows, each position's in column order: a histogram
            // only ever sees its own position's samples, so this is the order of adding in turn.
            let mut even =
                PositionCounts::new(p0 as u8, &mut window0, &mut *hist0, by_level.then_some(&mut *codes_out0));
            for &(level, n) in &out0 {
                even.outside(level as usize, n);
            }
            let mut odd =
                PositionCounts::new(p1 as u8, &mut window1, &mut *hist1, by_level.then_some(&mut *codes_out1));
            for &(level, n) in &out1 {
                odd.outside(level as usize, n);
            }
            samples += flat_pixels as u64;
        }
        // Windows that many samples fell outside of (a histogram's first frame, new levels) are
        // made anew on the ranges their histograms have grown to.
        let row_samples = w as u64 / 2;
        window0.renew_if_outside(row_samples, hist0, by_level.then_some(&mut *codes_out0));
        window1.renew_if_outside(row_samples, hist1, by_level.then_some(&mut *codes_out1));
    }
    for (narrow, wide) in narrow_cols.iter_mut().zip(&mut cols) {
        widen_into(narrow, wide);
    }
    window0.flush(hist0, by_level.then_some(&mut *codes_out0));
    window1.flush(hist1, by_level.then_some(&mut *codes_out1));
    if let Some((codes0, codes1)) = apart {
        codes0.flush(codes_out0);
        codes1.flush(codes_out1);
    }
    FoldedRows { samples, left_out, rows, cols }
}

/// One position's histogram counts for one frame, as [`fold_rows`] feeds them pixel by pixel.
struct PositionCounts<'a, 'w> {
    pos: u8,
    window: &'a mut WindowCounts<'w>,
    /// The window's level for the pixels that are not flat.
    not_flat: usize,
    hist: &'a mut Vec<NoiseHistogram>,
    /// The output codes, where the window gives them: a sample outside its window, or left out,
    /// is counted here.
    codes: Option<&'a mut [u64]>,
}

impl<'a, 'w> PositionCounts<'a, 'w> {
    fn new(
        pos: u8,
        window: &'a mut WindowCounts<'w>,
        hist: &'a mut Vec<NoiseHistogram>,
        codes: Option<&'a mut [u64]>,
    ) -> Self {
        let not_flat = window.not_flat();
        Self { pos, window, not_flat, hist, codes }
    }

    /// Counts the noise `n` of a pixel of clean level `c` in lane `lane`: a pixel that is not
    /// flat ([`NOT_FLAT`], noise 0) goes to the window's not-flat level.
    #[inline(always)]
    fn add(&mut self, c: u16, n: i32, lane: usize) {
        let level = (c as usize).min(self.not_flat);
        if !self.window.add(level, n, lane) {
            self.outside(level, n);
        }
    }

    /// A sample outside its level's window: into its histogram, and its output code (the raw
    /// value `level + n`) into the codes the window would have given.
    #[cold]
    #[inline(never)]
    fn outside(&mut self, level: usize, n: i32) {
        self.hist[self.window.bin(level)].add(n);
        self.window.note_outside();
        if let Some(codes) = self.codes.as_deref_mut() {
            let code = (level as i64 + n as i64).clamp(0, codes.len() as i64 - 1);
            codes[code as usize] += 1;
        }
    }

    /// [`PositionCounts::add`] for a frame that moved: a flat pixel not `kept` (raw value `v`)
    /// goes to `left_out` instead of the histograms. Returns the samples added (0 or 1).
    #[inline(always)]
    fn add_kept(&mut self, c: u16, n: i32, lane: usize, kept: bool, v: u16, left_out: &mut Vec<(u8, u16)>) -> u64 {
        if c == NOT_FLAT {
            return 0;
        }
        if !kept {
            left_out.push((self.pos, c));
            if let Some(codes) = self.codes.as_deref_mut() {
                codes[(v as usize).min(codes.len() - 1)] += 1;
            }
            return 0;
        }
        self.add(c, n, lane);
        1
    }
}

/// Counts the output code `v` (at most `top`) of every flat pixel of a row (clean levels
/// `crow`), even columns into `even`, odd ones into `odd`, each column pair in its own lane.
#[inline]
fn count_codes(crow: &[u16], row: &[u16], top: usize, even: &mut LaneCounts, odd: &mut LaneCounts) {
    for (j, (c, v)) in crow.chunks_exact(2).zip(row.chunks_exact(2)).enumerate() {
        if c[0] != NOT_FLAT {
            even.add((v[0] as usize).min(top), j);
        }
        if c[1] != NOT_FLAT {
            odd.add((v[1] as usize).min(top), j);
        }
    }
    if crow.len() % 2 == 1 {
        let x = crow.len() - 1;
        if crow[x] != NOT_FLAT {
            even.add((row[x] as usize).min(top), x >> 1);
        }
    }
}

/// Adds one row's noise over its line pixels (flat, clean level at most `line_top`) into its
/// columns' sums `cols`, and returns its sums per cell (`x & 3`). One branch-free pass over the
/// row's quads, so that the compiler vectorises it (integer sums: any order gives the same).
#[inline]
fn line_sums(noise: &[i32], crow: &[u16], line_top: u16, cols: &mut [i64]) -> [i64; CELLS] {
    let n = noise.len().min(crow.len()).min(cols.len());
    let (noise, crow, cols) = (&noise[..n], &crow[..n], &mut cols[..n]);
    let mut cells = [0i64; CELLS];
    let masked = |n: i32, c: u16| (n & (in_lines(c, line_top) as i32).wrapping_neg()) as i64;
    let quads = noise.chunks_exact(CELLS).zip(crow.chunks_exact(CELLS)).zip(cols.chunks_exact_mut(CELLS));
    for ((qn, qc), qcols) in quads {
        for k in 0..CELLS {
            let m = masked(qn[k], qc[k]);
            qcols[k] += m;
            cells[k] += m;
        }
    }
    let done = n / CELLS * CELLS;
    for (k, ((&v, &c), col)) in noise[done..].iter().zip(&crow[done..]).zip(&mut cols[done..]).enumerate() {
        let m = masked(v, c);
        *col += m;
        cells[k] += m;
    }
    cells
}

/// Rows of one half whose noise [`line_sums_narrow`] sums into 32-bit columns before they are
/// added into the 64-bit ones: `NARROW_ROWS · 2¹⁶ < 2³¹`.
const NARROW_ROWS: usize = 1 << 14;

/// Pixels of a row whose cell sums [`line_sums_narrow`] forms in 32 bits at a time (a lane
/// holds an eighth of them: `2¹¹ · 2¹⁶ < 2³¹`).
const NARROW_RUN: usize = 1 << 14;

/// Adds `narrow` into `wide` and clears it.
fn widen_into(narrow: &mut [i32], wide: &mut [i64]) {
    for (n, w) in narrow.iter_mut().zip(wide) {
        *w += std::mem::take(n) as i64;
    }
}

/// [`line_sums`] of a row whose noise is below 2¹⁶ in magnitude (a still frame: a difference of
/// two u16), into 32-bit column sums `cols` (the caller adds them into its 64-bit ones before
/// [`NARROW_ROWS`] rows could overflow them). The same integer sums, so the same values; in
/// half the width, so twice the pixels per vector instruction.
#[inline]
fn line_sums_narrow(noise: &[i32], crow: &[u16], line_top: u16, cols: &mut [i32]) -> [i64; CELLS] {
    let n = noise.len().min(crow.len()).min(cols.len());
    let mut cells = [0i64; CELLS];
    let runs = noise[..n].chunks(NARROW_RUN).zip(crow[..n].chunks(NARROW_RUN)).zip(cols[..n].chunks_mut(NARROW_RUN));
    for ((noise, crow), cols) in runs {
        // A run starts at a multiple of CELLS: its lane `k` is cell `k mod CELLS`.
        let lanes = narrow_run(noise, crow, line_top, cols);
        for (k, l) in lanes.iter().enumerate() {
            cells[k % CELLS] += *l as i64;
        }
    }
    cells
}

/// The noise `v − c` of every pixel of a row (`row` raw values, `crow` clean levels) into
/// `noise`, 0 where the pixel is not flat; returns the flat pixels. Branch-free, compiled for
/// AVX-512 and AVX2 as well as the baseline, the CPU's best picked at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn noise_row(row: &[u16], crow: &[u16], noise: &mut [i32]) -> u32 {
    let mut flat_pixels = 0u32;
    for ((n, &v), &c) in noise.iter_mut().zip(row).zip(crow) {
        let is_flat = c != NOT_FLAT;
        *n = (v as i32 - c as i32) & (is_flat as i32).wrapping_neg();
        flat_pixels += is_flat as u32;
    }
    flat_pixels
}

/// [`noise_row`] and then [`line_sums_narrow`] of its noise, in one pass over the row: the noise
/// `v − c` of every pixel into `noise` (0 where not flat), its line pixels' noise into the
/// 32-bit column sums `cols`; returns the flat pixels and the row's sums per cell (`x & 3`).
/// The same integers as the two in turn, with the row and its clean levels read once.
#[inline]
fn noise_and_line_sums(
    row: &[u16],
    crow: &[u16],
    line_top: u16,
    noise: &mut [i32],
    cols: &mut [i32],
) -> (u32, [i64; CELLS]) {
    let n = row.len().min(crow.len()).min(noise.len()).min(cols.len());
    let mut cells = [0i64; CELLS];
    let mut flat = 0u32;
    let runs = row[..n]
        .chunks(NARROW_RUN)
        .zip(crow[..n].chunks(NARROW_RUN))
        .zip(noise[..n].chunks_mut(NARROW_RUN))
        .zip(cols[..n].chunks_mut(NARROW_RUN));
    for (((row, crow), noise), cols) in runs {
        // A run starts at a multiple of CELLS: its lane `k` is cell `k mod CELLS`.
        let (f, lanes) = noise_lines_run(row, crow, line_top, noise, cols);
        flat += f;
        for (k, l) in lanes.iter().enumerate() {
            cells[k % CELLS] += *l as i64;
        }
    }
    (flat, cells)
}

/// One run of [`noise_and_line_sums`] (at most [`NARROW_RUN`] pixels): returns its flat pixels
/// and its line sums per lane `x mod 16` (a vector of 32-bit lanes under AVX-512). Branch-free,
/// compiled for AVX-512 and AVX2 as well as the baseline, the CPU's best picked at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn noise_lines_run(row: &[u16], crow: &[u16], line_top: u16, noise: &mut [i32], cols: &mut [i32]) -> (u32, [i32; 16]) {
    const LANES: usize = 16;
    let n = row.len().min(crow.len()).min(noise.len()).min(cols.len());
    let (row, crow, noise, cols) = (&row[..n], &crow[..n], &mut noise[..n], &mut cols[..n]);
    let mut lanes = [0i32; LANES];
    let mut flat = [0u32; LANES];
    // The noise is 0 where not flat, so the line mask needs only the line top.
    #[inline(always)]
    fn one(v: u16, c: u16, line_top: u16, noise: &mut i32, col: &mut i32, lane: &mut i32, flat: &mut u32) {
        let is_flat = c != NOT_FLAT;
        let d = (v as i32 - c as i32) & (is_flat as i32).wrapping_neg();
        *noise = d;
        let m = d & ((c <= line_top) as i32).wrapping_neg();
        *col += m;
        *lane += m;
        *flat += is_flat as u32;
    }
    let steps = row
        .chunks_exact(LANES)
        .zip(crow.chunks_exact(LANES))
        .zip(noise.chunks_exact_mut(LANES))
        .zip(cols.chunks_exact_mut(LANES));
    for (((qv, qc), qn), qcols) in steps {
        for k in 0..LANES {
            one(qv[k], qc[k], line_top, &mut qn[k], &mut qcols[k], &mut lanes[k], &mut flat[k]);
        }
    }
    let done = n / LANES * LANES;
    for k in 0..n - done {
        let x = done + k;
        one(row[x], crow[x], line_top, &mut noise[x], &mut cols[x], &mut lanes[k], &mut flat[k]);
    }
    (flat.iter().sum(), lanes)
}

/// One run of [`line_sums_narrow`] (at most [`NARROW_RUN`] pixels): the masked noise into its
/// columns' sums, and its sums per lane `x mod 8`. Branch-free, so that the compiler vectorises
/// it; compiled for AVX-512 and AVX2 as well as the baseline, the CPU's best picked at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn narrow_run(noise: &[i32], crow: &[u16], line_top: u16, cols: &mut [i32]) -> [i32; 8] {
    const LANES: usize = 8;
    let n = noise.len().min(crow.len()).min(cols.len());
    let (noise, crow, cols) = (&noise[..n], &crow[..n], &mut cols[..n]);
    let mut lanes = [0i32; LANES];
    let masked = |n: i32, c: u16| n & (in_lines(c, line_top) as i32).wrapping_neg();
    let steps = noise.chunks_exact(LANES).zip(crow.chunks_exact(LANES)).zip(cols.chunks_exact_mut(LANES));
    for ((qn, qc), qcols) in steps {
        for k in 0..LANES {
            let m = masked(qn[k], qc[k]);
            qcols[k] += m;
            lanes[k] += m;
        }
    }
    let done = n / LANES * LANES;
    for (k, ((&v, &c), col)) in noise[done..].iter().zip(&crow[done..]).zip(&mut cols[done..]).enumerate() {
        let m = masked(v, c);
        *col += m;
        lanes[k] += m;
    }
    lanes
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The narrow line sums are the 64-bit ones exactly: noise up to ±65535, pixels not flat or
    /// above the line top among them, rows shorter than the lanes, and a row of many runs with
    /// a tail past the lanes whose cell sums pass 2³¹ (so a version that summed a whole row in
    /// 32 bits fails, as does one that put a run's lane into the wrong cell or dropped the
    /// tail), columns already holding sums.
    #[test]
    fn narrow_line_sums_are_the_wide_ones() {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let line_top = 60_000u16;
        for w in [7usize, 37, NARROW_RUN * 18 + 13] {
            let mut wide_cols: Vec<i64> = (0..w).map(|_| (next() % 1000) as i64 - 500).collect();
            let mut narrow_cols = vec![0i32; w];
            let start = wide_cols.clone();
            for _row in 0..3 {
                let crow: Vec<u16> = (0..w)
                    .map(|_| match next() % 8 {
                        0 => NOT_FLAT,
                        1 => 60_001 + (next() % 5000) as u16,
                        _ => (next() % 60_001) as u16,
                    })
                    .collect();
                // Mostly the top, so that the sums are large.
                let noise: Vec<i32> = crow
                    .iter()
                    .map(|&c| match (c == NOT_FLAT, next() % 4) {
                        (true, _) => 0,
                        (false, 0) => (next() % 131_071) as i32 - 65_535,
                        _ => 65_535,
                    })
                    .collect();
                let wide = line_sums(&noise, &crow, line_top, &mut wide_cols);
                let narrow = line_sums_narrow(&noise, &crow, line_top, &mut narrow_cols);
                assert_eq!(wide, narrow, "width {w}");
                if w > NARROW_RUN {
                    assert!(narrow.iter().any(|c| c.abs() > i32::MAX as i64), "sums past 32 bits");
                }
            }
            let mut from_narrow = start.clone();
            widen_into(&mut narrow_cols, &mut from_narrow);
            assert_eq!(from_narrow, wide_cols, "width {w}");
            assert!(narrow_cols.iter().all(|&c| c == 0), "the narrow sums were cleared");
        }
    }

    /// The one-pass noise and line sums are [`noise_row`] then [`line_sums_narrow`] exactly: the
    /// same noise, column sums, cell sums and flat count, on rows with pixels not flat and above
    /// the line top, raw values far from their clean levels (noise up to ±65535), widths below
    /// the lanes, off the lanes and over many runs with a tail, columns already holding sums. A
    /// version that put lane `k` into cell `k mod 8`'s place, dropped the tail, or kept the noise
    /// of a pixel that is not flat differs in the cell sums, the columns or the noise.
    #[test]
    fn noise_and_line_sums_are_noise_then_line_sums() {
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let line_top = 60_000u16;
        for w in [3usize, 16, 37, NARROW_RUN * 3 + 21] {
            let start: Vec<i32> = (0..w).map(|_| (next() % 1000) as i32 - 500).collect();
            let (mut two_cols, mut one_cols) = (start.clone(), start.clone());
            for _row in 0..3 {
                let crow: Vec<u16> = (0..w)
                    .map(|_| match next() % 8 {
                        0 => NOT_FLAT,
                        1 => 60_001 + (next() % 5000) as u16,
                        _ => (next() % 60_001) as u16,
                    })
                    .collect();
                let row: Vec<u16> = crow
                    .iter()
                    .map(|&c| match next() % 4 {
                        0 => (next() % 65_536) as u16,
                        _ => c.saturating_add((next() % 25) as u16).saturating_sub(12),
                    })
                    .collect();
                let (mut two_noise, mut one_noise) = (vec![7i32; w], vec![-7i32; w]);
                let flat = noise_row(&row, &crow, &mut two_noise);
                let cells = line_sums_narrow(&two_noise, &crow, line_top, &mut two_cols);
                let (one_flat, one_cells) = noise_and_line_sums(&row, &crow, line_top, &mut one_noise, &mut one_cols);
                assert_eq!(one_noise, two_noise, "width {w}");
                assert_eq!((one_flat, one_cells), (flat, cells), "width {w}");
                assert_eq!(one_cols, two_cols, "width {w}");
                assert!(cells.iter().any(|&c| c != 0), "width {w}: line sums that say something");
            }
        }
    }
}
