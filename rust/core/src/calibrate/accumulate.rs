//! Target frames folded into one ISO's samples (method.md, "Calibration" 4–6): for every flat
//! pixel, `n = noisy − clean` into the histogram of (fold, CFA position, bin of the clean level),
//! the output code into the code counts, the clean image's selection into its sums, and the
//! frame's brightness into the gain-ratio sums. One pass over the frame, nothing of it kept.

use serde::{Deserialize, Serialize};

use crate::calibrate::drift::{BrightnessSums, Transform};
use crate::calibrate::estimate::FOLDS;
use crate::calibrate::flat::NOT_FLAT;
use crate::calibrate::frame::FrameView;
use crate::calibrate::motion::{FrameMotion, MotionProbe, NEGLIGIBLE_MOTION_PX};
use crate::calibrate::reference::CleanImage;
use crate::calibrate::structure::{CELLS, FrameSums, LineSums, StructureAccumulator};
use crate::model::histogram::NoiseHistogram;
use crate::model::layout::{Binning, POSITIONS};

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
    /// ([`crate::calibrate::assemble::MOTION_WORTH_SAYING_PX`]).
    pub(crate) fn moved(&self) -> Option<f64> {
        (self.frames > 0 && self.max_shift > crate::calibrate::assemble::MOTION_WORTH_SAYING_PX)
            .then_some(self.max_shift)
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
        let ((s0, l0, rows0, cols0), (s1, l1, rows1, cols1)) = rayon::join(
            || fold_rows(0, frame, clean, w, h, &luts, even, codes_even, tf, white, line_top, &image.probe, moving),
            || fold_rows(1, frame, clean, w, h, &luts, odd, codes_odd, tf, white, line_top, &image.probe, moving),
        );
        let samples = s0 + s1;
        // A sample left out takes its clean level's selection back out of the frame's sums:
        // they describe exactly the samples the histograms hold.
        let left = l0.len() + l1.len();
        for &(pos, level) in l0.iter().chain(&l1) {
            let (pos, level) = (pos as usize, level as usize);
            let [d, a] = image.level_selection[pos].get(level).copied().unwrap_or([0.0; 2]);
            let s = &mut self.shift[fold][pos][luts[pos][level] as usize];
            s[0] -= d;
            s[1] -= d * d;
            s[2] -= a;
        }
        self.motion.left_out += left as u64;
        self.motion.offered += samples + left as u64;
        let mut lines = FrameSums::new(w, h, tf.black);
        for (parity, rows) in [(0, rows0), (1, rows1)] {
            for (i, r) in rows.into_iter().enumerate() {
                lines.rows[parity + 2 * i] = r;
            }
        }
        // A column's cell is `row parity | half << 1`.
        for (c, (a, b)) in lines.cols.iter_mut().zip(cols0.into_iter().zip(cols1)) {
            *c = [a[0], b[0], a[1], b[1]];
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

/// What [`fold_rows`] returns: the samples added, the (position, clean level) of each sample
/// left out, the line sums per row (by cell) and per column (by half).
type FoldedRows = (u64, Vec<(u8, u16)>, Vec<[LineSums; CELLS]>, Vec<[LineSums; 2]>);

/// Folds the rows of one parity into that parity's two positions' histograms and code counts.
/// With `motion` (a frame that moved), the flat pixels whose level the motion changes by more
/// than their tolerance are left out of the histograms, and the line sums take the motion's
/// predicted change out of every pixel's `n` (`probe`: the clean image's gradients); the line
/// sums keep every flat pixel, so that every frame of a burst sums the same pixels into each
/// line. Returns the samples, the (position, clean level) of each sample
/// left out, and the sums of `n` and of the clean level per row (by cell) and per column (by
/// half).
#[allow(clippy::too_many_arguments)]
fn fold_rows(
    parity: usize,
    frame: &FrameView<'_>,
    clean: &[u16],
    w: usize,
    h: usize,
    luts: &[Vec<u16>; POSITIONS],
    hists: &mut [Vec<NoiseHistogram>],
    codes: &mut [Vec<u64>],
    tf: &Transform,
    white: u16,
    line_top: u16,
    probe: &MotionProbe,
    motion: Option<&FrameMotion>,
) -> FoldedRows {
    let mut samples = 0u64;
    let mut left_out: Vec<(u8, u16)> = Vec::new();
    let (mut keep, mut correction) = match motion {
        Some(_) => (vec![true; w], vec![0i32; w]),
        None => (Vec::new(), Vec::new()),
    };
    let mut row_sums = Vec::with_capacity(h / 2 + 1);
    // Per column, by half (`⌊y/2⌋` parity).
    let mut cols: Vec<[LineSums; 2]> = vec![[[0; 3]; 2]; w];
    let mut buf = vec![0u16; w];
    let identity = tf.identity();
    let top = white as usize;
    let (h0, h1) = hists.split_at_mut(1);
    let (hist0, hist1) = (&mut h0[0], &mut h1[0]);
    let (c0, c1) = codes.split_at_mut(1);
    let (codes0, codes1) = (&mut c0[0][..], &mut c1[0][..]);
    let (lut0, lut1) = (&luts[parity * 2], &luts[parity * 2 + 1]);
    for y in (parity..h).step_by(2) {
        let row: &[u16] = match frame.row(y) {
            std::borrow::Cow::Borrowed(r) => r,
            std::borrow::Cow::Owned(v) => {
                buf.copy_from_slice(&v);
                &buf
            }
        };
        let crow = &clean[y * w..y * w + w];
        let mut rs: [LineSums; CELLS] = [[0; 3]; CELLS];
        let half = (y >> 1) & 1;
        if let Some(m) = motion {
            // A frame that moved: the pixels its motion changes are left out of the
            // histograms, and its predicted change comes out of the line sums.
            m.row_effects(probe, y, crow, &mut keep, &mut correction);
            for (x, (&v, &c)) in row.iter().zip(crow).enumerate() {
                if c == NOT_FLAT {
                    continue;
                }
                let pos = parity * 2 + (x & 1);
                let t = if identity { v as i32 } else { tf.apply(pos, v).round().clamp(0.0, white as f32) as i32 };
                let n = t - c as i32;
                if c <= line_top {
                    line_add(&mut rs[x & 3], &mut cols[x][half], n - correction[x], c);
                }
                let (hist, lut, codes) =
                    if x & 1 == 0 { (&mut *hist0, lut0, &mut *codes0) } else { (&mut *hist1, lut1, &mut *codes1) };
                codes[(v as usize).min(top)] += 1;
                if !keep[x] {
                    left_out.push((pos as u8, c));
                    continue;
                }
                hist[lut[c as usize] as usize].add(n);
                samples += 1;
            }
        } else {
            // A still frame: every flat pixel goes to the histograms. One loop, written once and
            // expanded for the raw values and for transformed ones, so that the identity case
            // carries no per-pixel branch.
            macro_rules! fold_still {
                ($value:expr) => {
                    for (x, (&v, &c)) in row.iter().zip(crow).enumerate() {
                        if c == NOT_FLAT {
                            continue;
                        }
                        let n = $value(parity * 2 + (x & 1), v) - c as i32;
                        if c <= line_top {
                            line_add(&mut rs[x & 3], &mut cols[x][half], n, c);
                        }
                        if x & 1 == 0 {
                            hist0[lut0[c as usize] as usize].add(n);
                            codes0[(v as usize).min(top)] += 1;
                        } else {
                            hist1[lut1[c as usize] as usize].add(n);
                            codes1[(v as usize).min(top)] += 1;
                        }
                        samples += 1;
                    }
                };
            }
            if identity {
                fold_still!(|_: usize, v: u16| v as i32);
            } else {
                fold_still!(|pos: usize, v: u16| tf.apply(pos, v).round().clamp(0.0, white as f32) as i32);
            }
        }
        row_sums.push(rs);
    }
    (samples, left_out, row_sums, cols)
}

#[inline(always)]
fn line_add(row: &mut LineSums, col: &mut LineSums, n: i32, clean: u16) {
    let (n, c) = (n as i64, clean as i64);
    row[0] += n;
    row[1] += c;
    row[2] += 1;
    col[0] += n;
    col[1] += c;
    col[2] += 1;
}
