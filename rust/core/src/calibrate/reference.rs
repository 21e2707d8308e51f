//! One reference burst: the frames of an EV step at the reference ISO, summed per pixel into
//! the step's clean image, with the frame-to-frame statistics its flat test and its selection
//! correction need (method.md, "Calibration" 1–3). Memory is O(pixels) whatever the number of
//! frames.
//!
//! [`ReferenceBurst::push`] takes frames; [`ReferenceBurst::close`] gives the [`CleanImage`].
//! A calibration session composes one per step; evaluation and tests use it alone to get the
//! clean image of held-out captures.

use multiversion::multiversion;
use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::calibrate::deselect;
use crate::calibrate::drift::{
    DriftPolicy, DriftTracker, DriftVerdict, FrameBrightness, Transform, brightness_sums, clip_level,
};
use crate::calibrate::flat::{
    CleanInputs, FlatImage, FlatReport, GROUPS, Groups, NOT_FLAT, Roi, TemporalStats, clean_and_mask,
};
use crate::calibrate::flat_levels::FlatLevelsCache;
use crate::calibrate::frame::FrameView;
use crate::calibrate::line_base::LineBaseCache;
use crate::calibrate::meta::FrameMeta;
use crate::calibrate::motion::MotionProbe;
use crate::error::SessionError;
use crate::model::layout::{Binning, POSITIONS, SensorLayout};

/// The most frames one burst takes (its sums are u32).
pub const MAX_REFERENCE_FRAMES: u32 = 60_000;

/// A reference burst being summed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReferenceBurst {
    layout: SensorLayout,
    exposure_ns: u64,
    frames: u32,
    sum: Vec<u32>,
    first: Vec<u16>,
    /// Per pixel, Σ(frame − first frame)² (saturating): the pixel's own spread over the burst.
    squares: Vec<u32>,
    temporal: TemporalStats,
    drift: DriftTracker,
}

/// What [`ReferenceBurst::push`] did with a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReferenceFrame {
    /// The frame's brightness against the burst.
    pub verdict: DriftVerdict,
    /// Its brightness was normalised to the burst's.
    pub normalised: bool,
}

/// The clean image of an EV step, with what calibration needs of it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CleanImage {
    /// Row-major `round(mean)` of the burst, [`NOT_FLAT`] where a pixel is not on a flat region.
    pub levels: Vec<u16>,
    pub width: usize,
    pub height: usize,
    /// Frames in the burst.
    pub frames: u32,
    /// What the flat test found.
    pub flat: FlatReport,
    /// Per position and bin, `[Σδ, Σδ², Σa]` of the clean image's selection over its flat pixels
    /// ([`deselect::bin_sums`]): what one target frame adds to its ISO's sums.
    pub selection: [Vec<[f64; 3]>; POSITIONS],
    /// Per position and clean level, `[δ, a]` of one flat pixel: what a sample left out of a
    /// frame (motion) takes back out of that frame's selection sums.
    pub level_selection: [Vec<[f64; 2]>; POSITIONS],
    /// What registering a target frame on this image, and the motion test, read of it.
    pub probe: MotionProbe,
    /// The clean-image half of the target frames' line sums, computed on first use.
    #[serde(skip)]
    pub(crate) line_base: LineBaseCache,
    /// The levels of the flat pixels per position, computed on first use.
    #[serde(skip)]
    pub(crate) flat_levels: FlatLevelsCache,
}

impl CleanImage {
    /// The clean levels as an image (0 where not flat) and the flat mask.
    pub fn to_arrays(&self) -> (Array2<u16>, Array2<bool>) {
        let shape = (self.height, self.width);
        let levels = self.levels.iter().map(|&c| if c == NOT_FLAT { 0 } else { c }).collect();
        let mask = self.levels.iter().map(|&c| c != NOT_FLAT).collect();
        (
            Array2::from_shape_vec(shape, levels).expect("height × width levels"),
            Array2::from_shape_vec(shape, mask).expect("height × width flags"),
        )
    }
}

/// `[n, Σd, Σd²]` per (position, group) of one frame as the floating-point sums of its samples
/// in turn, when those are exact: every term is an integer, `|Σd| ≤ Σd²` and `n ≤ Σd²` bound
/// every partial sum, so below 2⁵³ no addition rounds and the order of the additions changes
/// nothing. `None` when a sum reaches 2⁵³, or the integer sums could have overflowed (`pixels`:
/// the frame's).
fn exact_stats(sums: &[[i64; 3]], pixels: usize) -> Option<Vec<[f64; 3]>> {
    const EXACT: i64 = 1 << 53;
    // Σd² < pixels · 2³², within i64 below 2³¹ pixels.
    if pixels >= 1 << 31 || sums.iter().any(|s| s[2] >= EXACT || s[0] >= EXACT) {
        return None;
    }
    Some(sums.iter().map(|s| s.map(|v| v as f64)).collect())
}

/// One row of the sums, of the first frame and of the squares, with its index.
/// A row of a frame after the burst's first (`values`) into the burst's per-pixel sums and
/// squares of the differences from the first frame (`first_row`); the second frame writes the
/// squares rather than adding to them (see the caller). Branch-free, compiled for AVX-512 and
/// AVX2 as well as the baseline, the CPU's best picked at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn add_row(sum_row: &mut [u32], square_row: &mut [u32], values: &[u16], first_row: &[u16], second_frame: bool) {
    for (s, &v) in sum_row.iter_mut().zip(values) {
        *s += v as u32;
    }
    // (v − f0)² of two u16 is below 2³², so the u32 square is exact (no clamp).
    let squares = square_row.iter_mut().zip(values).zip(first_row);
    if second_frame {
        for ((q, &v), &f0) in squares {
            let d = v.abs_diff(f0) as u32;
            *q = d * d;
        }
    } else {
        for ((q, &v), &f0) in squares {
            let d = v.abs_diff(f0) as u32;
            *q = q.saturating_add(d * d);
        }
    }
}

type RowPair<'a> = (usize, &'a mut [u32], &'a mut [u16], &'a mut [u32]);

impl ReferenceBurst {
    /// An empty burst for frames of `layout` taken with `exposure_ns`.
    pub fn new(layout: &SensorLayout, exposure_ns: u64) -> Self {
        let n = layout.pixels();
        Self {
            layout: layout.clone(),
            exposure_ns,
            frames: 0,
            sum: vec![0; n],
            first: vec![0; n],
            squares: vec![0; n],
            temporal: TemporalStats::default(),
            drift: DriftTracker::default(),
        }
    }

    /// The exposure of the burst's frames (ns).
    pub fn exposure_ns(&self) -> u64 {
        self.exposure_ns
    }

    /// Frames summed so far.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// Adds one frame: its brightness is judged against the burst's first frame, and a drift
    /// up to `policy.max` normalised (beyond it the frame is refused and the burst unchanged).
    /// Size and metadata are the caller's to check.
    pub fn push(
        &mut self,
        frame: &FrameView<'_>,
        meta: &FrameMeta,
        policy: &DriftPolicy,
    ) -> Result<ReferenceFrame, SessionError> {
        let (w, h) = (self.layout.width as usize, self.layout.height as usize);
        let white = self.layout.white;
        let groups = Groups { black: self.layout.black, white };
        let clip = clip_level(&self.layout);
        let ident = Transform::of(&self.layout, meta, 1.0);
        if self.first.len() != self.sum.len() {
            return Err(SessionError::ReferenceClosed);
        }
        if self.frames >= MAX_REFERENCE_FRAMES {
            return Err(SessionError::Metadata(format!("reference burst exceeds {MAX_REFERENCE_FRAMES} frames")));
        }
        // Brightness against the burst's first frame.
        let mut verdict = DriftVerdict { departure: 0.0, drifted: false, scale: 1.0 };
        let fb = if self.frames > 0 {
            brightness_sums(frame, &self.first, &ident, clip, w, h).brightness()
        } else {
            Some(FrameBrightness { ratio: 1.0, sigma: 0.0 })
        };
        if let Some(fb) = fb {
            verdict = self.drift.judge(fb, policy.z, policy.floor);
            if verdict.drifted && verdict.departure.abs() > policy.max {
                return Err(SessionError::Drift {
                    kind: "reference",
                    iso: meta.iso,
                    exposure_ns: meta.exposure_ns,
                    departure_pct: verdict.departure * 100.0,
                    max_pct: policy.max * 100.0,
                });
            }
            self.drift.record(fb);
        }
        let scale = if verdict.drifted && policy.normalise { verdict.scale } else { 1.0 };
        let tf = Transform { scale: scale as f32, ..ident };
        let first_frame = self.frames == 0;
        let second_frame = self.frames == 1;
        let stats_rows = if h > 512 { 4 } else { 1 };
        let mut rows: [Vec<RowPair<'_>>; 2] = [Vec::new(), Vec::new()];
        for (y, ((s, f), q)) in
            self.sum.chunks_mut(w).zip(self.first.chunks_mut(w)).zip(self.squares.chunks_mut(w)).enumerate()
        {
            rows[y & 1].push((y, s, f, q));
        }
        let [even_rows, odd_rows] = rows;
        let identity = tf.identity();
        // Each position's level group of every first-frame level up to white (the first frame
        // only keeps its values: it reads no group).
        let group_of: [Vec<u8>; POSITIONS] = if first_frame {
            Default::default()
        } else {
            std::array::from_fn(|pos| (0..=white).map(|f0| groups.group(pos, f0 as f32) as u8).collect())
        };
        let group = |pos: usize, f0: u16| match group_of[pos].get(f0 as usize) {
            Some(&g) => g as usize,
            None => groups.group(pos, f0 as f32),
        };
        // A raw value as the session's code (transformed, rounded, within 0..=white).
        let code = |pos: usize, r: u16| {
            if identity { r as u32 } else { tf.apply(pos, r).round().clamp(0.0, white as f32) as u32 }
        };
        let work = |mut rows: Vec<RowPair<'_>>| {
            // `[n, Σd, Σd²]` per position and group, in integers (see `exact_stats`).
            let mut sums = vec![[0i64; 3]; POSITIONS * GROUPS];
            let mut row_buf = vec![0u16; w];
            let mut codes = vec![0u16; w];
            for (y, sum_row, first_row, square_row) in rows.iter_mut() {
                let y = *y;
                // The row's codes: the frame's row in place where its memory allows and no
                // transform applies, else transformed into `codes` (every code is at most
                // white, so a u16).
                let values: &[u16] = if identity {
                    match frame.row(y) {
                        std::borrow::Cow::Borrowed(r) => r,
                        std::borrow::Cow::Owned(v) => {
                            row_buf.copy_from_slice(&v);
                            &row_buf
                        }
                    }
                } else {
                    frame.read_row(y, &mut row_buf);
                    for (x, (v, &r)) in codes.iter_mut().zip(&row_buf).enumerate() {
                        let pos = ((y & 1) << 1) | (x & 1);
                        *v = code(pos, r) as u16;
                    }
                    &codes
                };
                // The first frame's sums and the second's squares are written, not added to the
                // zeros they would read: a fresh buffer's page read before it is written is
                // faulted twice (the shared zero page, then a page of its own), 120 MB of
                // buffers at 12 MP.
                if first_frame {
                    for (s, &v) in sum_row.iter_mut().zip(values) {
                        *s = v as u32;
                    }
                    first_row.copy_from_slice(&values[..first_row.len()]);
                    continue;
                }
                add_row(sum_row, square_row, values, first_row, second_frame);
                if (y / 2) % stats_rows == 0 {
                    for (x, (&v, &f0)) in values.iter().zip(first_row.iter()).enumerate() {
                        let pos = ((y & 1) << 1) | (x & 1);
                        let di = v as i64 - f0 as i64;
                        let a = &mut sums[pos * GROUPS + group(pos, f0)];
                        a[0] += 1;
                        a[1] += di;
                        a[2] += di * di;
                    }
                }
            }
            exact_stats(&sums, w * h).unwrap_or_else(|| {
                // Sums the floating-point additions would have rounded: those additions, in
                // their order.
                let mut acc = vec![[0.0f64; 3]; POSITIONS * GROUPS];
                for (y, _, first_row, _) in rows.iter().filter(|r| !first_frame && (r.0 / 2) % stats_rows == 0) {
                    frame.read_row(*y, &mut row_buf);
                    for (x, (&r, &f0)) in row_buf.iter().zip(first_row.iter()).enumerate() {
                        let pos = ((y & 1) << 1) | (x & 1);
                        let v = code(pos, r);
                        let d = (v as i64 - f0 as i64) as f64;
                        let a = &mut acc[pos * GROUPS + group(pos, f0)];
                        a[0] += 1.0;
                        a[1] += d;
                        a[2] += d * d;
                    }
                }
                acc
            })
        };
        let (a, b) = rayon::join(|| work(even_rows), || work(odd_rows));
        for part in [&a, &b] {
            for (t, a) in self.temporal.acc.iter_mut().zip(part) {
                for k in 0..3 {
                    t[k] += a[k];
                }
            }
        }
        self.frames += 1;
        Ok(ReferenceFrame { verdict, normalised: scale != 1.0 })
    }

    /// The burst's clean image: `round(mean)`, the flat test (`roi`, threshold `flat_k`), and
    /// the selection sums per bin of `binning`. Errors when the burst is empty or nothing is
    /// flat.
    pub fn close(&self, binning: &Binning, roi: Option<Roi>, flat_k: f64) -> Result<CleanImage, SessionError> {
        self.close_parts(binning, roi, flat_k).map(|parts| self.finish(parts))
    }

    /// [`ReferenceBurst::close`] for a burst that is dropped once closed (a calibration
    /// session's): its first frame is freed as it closes. On an error the burst is unchanged;
    /// after success it has no first frame, and refuses more frames and a second close
    /// ([`SessionError::ReferenceClosed`]).
    pub fn close_spending(
        &mut self,
        binning: &Binning,
        roi: Option<Roi>,
        flat_k: f64,
    ) -> Result<CleanImage, SessionError> {
        if self.first.len() != self.sum.len() {
            return Err(SessionError::ReferenceClosed);
        }
        // The flat test reads the first frame: it is taken only once the test has passed.
        self.close_parts(binning, roi, flat_k).map(|parts| {
            self.first = Vec::new();
            self.finish(parts)
        })
    }

    /// What a clean image holds besides the mean and what is made of it: the flat levels, the
    /// flat test's report and the selection sums.
    fn close_parts(&self, binning: &Binning, roi: Option<Roi>, flat_k: f64) -> Result<ClosedParts, SessionError> {
        let (w, h) = (self.layout.width as usize, self.layout.height as usize);
        if self.frames == 0 {
            return Err(SessionError::NoReference { iso: 0, exposure_ns: self.exposure_ns, reference: 0 });
        }
        let FlatImage { clean: levels, mean, report: flat } = clean_and_mask(&CleanInputs {
            sum: &self.sum,
            first: &self.first,
            squares: &self.squares,
            frames: self.frames,
            width: w,
            height: h,
            black: self.layout.black,
            white: self.layout.white,
            temporal: &self.temporal,
            roi,
            k: flat_k,
        });
        if flat.total_flat() == 0 {
            return Err(SessionError::NoFlatPixels);
        }
        let luts: [Vec<u16>; POSITIONS] = std::array::from_fn(|p| binning.lut(p));
        let groups = Groups { black: self.layout.black, white: self.layout.white };
        let (selection, level_selection) =
            deselect::bin_sums(&levels, w, NOT_FLAT, |pos, c| flat.mean_noise_at(&groups, pos, c), &luts);
        Ok(ClosedParts { levels, mean, flat, selection, level_selection })
    }

    /// The clean image of `parts` (the rounded mean is the flat test's, not taken again).
    fn finish(&self, parts: ClosedParts) -> CleanImage {
        let ClosedParts { levels, mean, flat, selection, level_selection } = parts;
        let (w, h) = (self.layout.width as usize, self.layout.height as usize);
        let groups = Groups { black: self.layout.black, white: self.layout.white };
        let probe = MotionProbe::new(mean, &levels, w, h, self.frames, &flat, &groups, clip_level(&self.layout));
        CleanImage {
            levels,
            width: w,
            height: h,
            frames: self.frames,
            flat,
            selection,
            level_selection,
            probe,
            line_base: LineBaseCache::default(),
            flat_levels: FlatLevelsCache::default(),
        }
    }
}

/// A closing burst's clean levels, flat report and selection sums ([`ReferenceBurst::close`]).
struct ClosedParts {
    levels: Vec<u16>,
    /// The burst's rounded mean, `clamp(round(sum / frames), 0, white)`.
    mean: Vec<u16>,
    flat: FlatReport,
    selection: [Vec<[f64; 3]>; POSITIONS],
    level_selection: [Vec<[f64; 2]>; POSITIONS],
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::layout::CfaPattern;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A session's default drift policy (`SessionConfig::new`), written out: the session's file
    /// uses this one, so this one does not use it (`tests/layers.rs`, no circles between files).
    fn policy() -> DriftPolicy {
        DriftPolicy { z: 5.0, floor: 0.002, max: 0.05, normalise: true }
    }

    /// A burst of 4 frames of a chart (flat patches, noise of a few DN).
    fn burst() -> (ReferenceBurst, SensorLayout) {
        let layout = SensorLayout { width: 48, height: 32, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 };
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut b = ReferenceBurst::new(&layout, 1_000_000);
        let policy = policy();
        for _ in 0..4 {
            let f = ndarray::Array2::from_shape_fn((32, 48), |(y, x)| {
                100 + 200 * ((y / 8) * 6 + x / 8) as u16 % 900 + rng.random_range(0..5)
            });
            b.push(&FrameView::from_array(&f).expect("view"), &FrameMeta::new(100, 1_000_000), &policy).expect("frame");
        }
        (b, layout)
    }

    /// The sums, first frame and squares of a burst are the per-pixel sums of its frames
    /// written out, for bursts of 1, 2 and 3 frames of codes over the whole 16-bit range (the
    /// first frame's sums and the second's squares are stored, not added): a burst that kept
    /// a previous frame's sums, or stored every frame's squares, is off at every pixel.
    #[test]
    fn sums_and_squares_are_the_frames_sums() {
        let layout = SensorLayout { width: 20, height: 12, cfa: CfaPattern::Rggb, black: [0.0; 4], white: 65535 };
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let frames: Vec<ndarray::Array2<u16>> =
            (0..3).map(|_| ndarray::Array2::from_shape_fn((12, 20), |_| rng.random_range(0..=u16::MAX))).collect();
        // No drift normalisation, so the codes are the frames' values.
        let policy = DriftPolicy { z: 5.0, floor: 0.002, max: 1e9, normalise: false };
        for n in 1..=3 {
            let mut b = ReferenceBurst::new(&layout, 1_000_000);
            for f in &frames[..n] {
                b.push(&FrameView::from_array(f).expect("view"), &FrameMeta::new(100, 1_000_000), &policy)
                    .expect("frame");
            }
            let first: Vec<u16> = frames[0].iter().copied().collect();
            let sum: Vec<u32> = (0..first.len())
                .map(|i| frames[..n].iter().map(|f| f.as_slice().expect("contiguous")[i] as u32).sum())
                .collect();
            let squares: Vec<u32> = (0..first.len())
                .map(|i| {
                    frames[1..n].iter().fold(0u32, |q, f| {
                        let d = f.as_slice().expect("contiguous")[i].abs_diff(first[i]) as u32;
                        q.saturating_add(d * d)
                    })
                })
                .collect();
            assert_eq!(b.first, first, "{n} frames: first frame");
            assert_eq!(b.sum, sum, "{n} frames: sums");
            assert_eq!(b.squares, squares, "{n} frames: squares");
        }
    }

    /// The clean image's rounded mean (taken once, by the flat test) is
    /// `clamp(round(sum / frames), 0, white)` at every pixel, on a chart burst of 70 rows (two
    /// blocks of the flat test and a part block) whose values partly lie above white and
    /// whose means fall on halves: a mean truncated, not clamped, or taken for the wrong rows
    /// of a block differs at thousands of pixels.
    #[test]
    fn the_mean_is_the_rounded_mean_everywhere() {
        let (w, h) = (48, 70);
        let layout =
            SensorLayout { width: w as u32, height: h as u32, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 };
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut b = ReferenceBurst::new(&layout, 1_000_000);
        let policy = DriftPolicy { z: 5.0, floor: 0.002, max: 1e9, normalise: false };
        let mut sums = vec![0u32; w * h];
        for _ in 0..4 {
            let f = ndarray::Array2::from_shape_fn((h, w), |(y, x)| {
                let v = 100 + 150 * ((y / 8) * 6 + x / 8) as u16 % 1000 + rng.random_range(0..4);
                if rng.random_bool(0.05) { rng.random_range(0..1400) } else { v }
            });
            for (s, &v) in sums.iter_mut().zip(f.iter()) {
                *s += v as u32;
            }
            b.push(&FrameView::from_array(&f).expect("view"), &FrameMeta::new(100, 1_000_000), &policy).expect("frame");
        }
        let image = b.close(&Binning::new(&layout, 4), None, 4.5).expect("close");
        let want: Vec<u16> = sums.iter().map(|&s| (s as f64 / 4.0).round().clamp(0.0, 1023.0) as u16).collect();
        assert_eq!(image.probe.mean.len(), want.len());
        let wrong = image.probe.mean.iter().zip(&want).filter(|(a, b)| a != b).count();
        assert_eq!(wrong, 0, "{wrong} of {} pixels' means differ", want.len());
        assert!(want.iter().filter(|&&v| v == 1023).count() > 10, "some means clamped at white");
        assert!(sums.iter().filter(|&&s| s % 4 == 2).count() > 100, "some means on halves");
        assert!(image.flat.total_flat() > 1000, "{:?}", image.flat.flat);
        // Every pixel of the clean image is written: outside a region of interest, not flat.
        let roi = Roi { x0: 5, y0: 9, x1: 40, y1: 50 };
        let inside = b.close(&Binning::new(&layout, 4), Some(roi), 4.5).expect("close");
        let outside = (0..w * h).filter(|&i| !roi.contains(i % w, i / w));
        assert!(outside.clone().all(|i| inside.levels[i] == NOT_FLAT));
        assert!(outside.count() > 1000);
        assert_eq!(inside.levels.iter().filter(|&&l| l != NOT_FLAT).count() as u64, inside.flat.total_flat());
    }

    /// Closing a burst that is dropped afterwards gives the clean image `close` gives (the
    /// mean written over the first frame instead of a buffer of its own); the spent burst then
    /// refuses frames and a second close, and a close that fails leaves the burst as it was.
    #[test]
    fn close_spending_is_close() {
        let (mut b, layout) = burst();
        let binning = Binning::new(&layout, 4);
        let want = b.close(&binning, None, 4.5).expect("close");
        assert!(want.flat.total_flat() > 500, "{:?}", want.flat.flat);
        // Nothing inside the region of interest: no flat pixel, the burst unchanged.
        let nothing = Some(Roi { x0: 0, y0: 0, x1: 0, y1: 0 });
        let before = b.clone();
        assert!(matches!(b.close_spending(&binning, nothing, 4.5), Err(SessionError::NoFlatPixels)));
        assert_eq!(b, before);
        let got = b.close_spending(&binning, None, 4.5).expect("close");
        // NaN marks level groups without differences: compared as printed, NaN as NaN.
        assert!(format!("{got:?}") == format!("{want:?}"), "close_spending differs from close");
        assert_eq!(got.probe.mean, want.probe.mean);
        assert_eq!(got.levels, want.levels);
        assert!(matches!(b.close_spending(&binning, None, 4.5), Err(SessionError::ReferenceClosed)));
        let f = ndarray::Array2::<u16>::from_elem((32, 48), 500);
        let policy = policy();
        let pushed = b.push(&FrameView::from_array(&f).expect("view"), &FrameMeta::new(100, 1_000_000), &policy);
        assert!(matches!(pushed, Err(SessionError::ReferenceClosed)));
    }
}
