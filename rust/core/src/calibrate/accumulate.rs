//! Target frames folded into one ISO's samples (method.md, "Calibration" 4–6): for every flat
//! pixel, `n = noisy − clean` into the histogram of (fold, CFA position, bin of the clean level),
//! the output code into the code counts, the clean image's selection into its sums, and the
//! frame's brightness into the gain-ratio sums. One pass over the frame, nothing of it kept.

use serde::{Deserialize, Serialize};

use crate::calibrate::drift::{BrightnessSums, Transform};
use crate::calibrate::estimate::FOLDS;
use crate::calibrate::flat::NOT_FLAT;
use crate::calibrate::flat_levels::FlatLevels;
use crate::calibrate::frame::FrameView;
use crate::calibrate::line_sums::{
    NARROW_ROWS, line_sums, line_sums_narrow, noise_and_line_sums, noise_row, widen_into,
};
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
        // Even columns are position `2·parity`, odd ones `2·parity + 1`: the row feeds both,
        // each pixel's window found by its clean level (a moved frame in one pass over the
        // column pairs, a still one in a pass per position, `count_pairs`).
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
