//! Motion between frames is not noise (method.md, "Motion between frames").
//!
//! A chart on a tripod moves by a fraction of a pixel between frames (optical stabilisation,
//! shutter and focus shake, a swaying tripod, focus breathing). A flat pixel near a blurred edge
//! then changes by `∇I · u` between frames, which `n = noisy − clean` would count as noise.
//!
//! - [`MotionProbe`]: made when a reference burst closes: the burst's mean at every pixel, a set
//!   of edge samples to register frames on, and each flat pixel's gradient in units of the motion
//!   error it may carry.
//! - [`register`]: a target frame's motion against the clean image, an affine field
//!   `u(p) = t + A·(p − c)` (shift, rotation, scale, shear) with a gain and an offset per CFA
//!   position, by Gauss–Newton on the edge samples (bilinear on each colour's own lattice,
//!   Huber-weighted, then Tukey-weighted around robust row offsets: a glitching pixel is not
//!   motion).
//! - [`FrameMotion::row_effects`]: which flat pixels of a row the frame's motion changes by more
//!   than [`MOTION_TOLERANCE`] of the noise at their level (calibration leaves those samples out
//!   of that frame, never resampling it: interpolation would correlate its noise), and the change
//!   it predicts (taken out of the line sums).

use serde::{Deserialize, Serialize};

use crate::calibrate::drift::Transform;
use crate::calibrate::flat::NOT_FLAT;
use crate::calibrate::frame::FrameView;
use crate::math::fit::{invert, solve};
use crate::math::stats::median;

use crate::model::layout::{POSITIONS, position};
use robust::{Row, demean_rows, median_in_place, robust_weights, tukey};

/// A frame that moved further than this (pixels, anywhere in the image) against its reference
/// burst is refused: a sturdier mount, OIS off or a remote trigger is needed.
pub const MAX_MOTION_PX: f64 = 2.0;

/// A frame that moved further than this (pixels, anywhere in the image) is taken, its moved
/// pixels left out, but its burst is worth taking again (a sturdier mount, OIS off, a remote
/// trigger): past about 0.3 px the pixels left out near edges cost a bin a noticeable share of
/// its samples, and the motion model's own error (15–20 % of the shift) approaches the
/// tolerance. The app's result check says so per burst.
pub const RETAKE_MOTION_PX: f64 = 0.3;

/// Below this (pixels, anywhere in the image) a frame's motion changes nothing worth a pass.
pub const NEGLIGIBLE_MOTION_PX: f64 = 0.005;

/// Gauss–Newton iterations at most (sub-pixel motions converge in 2–4).
const MAX_ITERATIONS: usize = 6;

/// One frame of samples for registration: frame value, position, pixel coordinates.
struct Sample {
    x: usize,
    y: usize,
    pos: usize,
    value: f64,
    /// A reference frame's noise SD at the sample's level, for an anchor (flat pixel).
    anchor_sd: Option<f32>,
}

/// A frame's motion against the clean image: `frame(p) ≈ gain · clean(p + u(p)) + offset` per
/// CFA position, `u(p) = t + A·(p − c)/r` with `c` the image centre and `r` half its diagonal.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameMotion {
    /// Translation at the image centre (pixels, x and y).
    pub t: [f64; 2],
    /// Linear part, per unit of `(p − c)/r`: `[[a_xx, a_xy], [a_yx, a_yy]]` (pixels).
    pub a: [[f64; 2]; 2],
    centre: [f64; 2],
    radius: f64,
    /// Robust standard deviation of the registration's residuals (DN).
    pub residual_sd: f64,
    /// The frame's noise SD over a reference frame's at the same levels (≥ 1; from the flat
    /// anchors' residuals): a target ISO's noise is wider, so its tolerance to motion is too.
    pub noise_scale: f64,
    /// Samples the registration used.
    pub samples: usize,
}

impl FrameMotion {
    /// No motion, for a `width × height` image.
    pub fn still(width: usize, height: usize) -> Self {
        let centre = [width as f64 / 2.0, height as f64 / 2.0];
        let radius = (centre[0].hypot(centre[1])).max(1.0);
        Self { t: [0.0; 2], a: [[0.0; 2]; 2], centre, radius, residual_sd: 0.0, noise_scale: 1.0, samples: 0 }
    }

    /// The displacement at pixel `(x, y)` (pixels).
    #[inline]
    pub fn at(&self, x: f64, y: f64) -> [f64; 2] {
        let (dx, dy) = ((x - self.centre[0]) / self.radius, (y - self.centre[1]) / self.radius);
        [self.t[0] + self.a[0][0] * dx + self.a[0][1] * dy, self.t[1] + self.a[1][0] * dx + self.a[1][1] * dy]
    }

    /// The largest displacement anywhere in the image (an affine field is largest at a corner).
    pub fn max_shift(&self) -> f64 {
        let (w, h) = (2.0 * self.centre[0], 2.0 * self.centre[1]);
        [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
            .iter()
            .map(|&(x, y)| {
                let u = self.at(x, y);
                u[0].hypot(u[1])
            })
            .fold(0.0, f64::max)
    }

    /// The rotation (radians, counter-clockwise in image coordinates) of the field.
    pub fn rotation(&self) -> f64 {
        (self.a[1][0] - self.a[0][1]) / (2.0 * self.radius)
    }

    /// The relative scale change of the field (focus breathing).
    pub fn scale(&self) -> f64 {
        (self.a[0][0] + self.a[1][1]) / (2.0 * self.radius)
    }

    /// What this motion does to the flat pixels of row `y` (`row`: the clean levels of that
    /// row; `gradient`: that row of the probe's [`MotionProbe::gradients`]): `keep[x]` is false where it changes the level by more than the pixel's tolerance
    /// ([`MOTION_TOLERANCE`] SD of this frame's noise), and `correction[x]` is the change it
    /// predicts (DN, rounded; 0 where the gradient is beyond the probe's range).
    pub fn row_effects(
        &self,
        probe: &MotionProbe,
        gradient: &[[i8; 2]],
        y: usize,
        row: &[u16],
        keep: &mut [bool],
        correction: &mut [i32],
    ) {
        let u0 = self.at(0.5, y as f64 + 0.5);
        let step = [self.a[0][0] / self.radius, self.a[1][0] / self.radius];
        let units = GRADIENT_UNITS as f64;
        let p0 = (y & 1) * 2;
        for (x, &c) in row.iter().enumerate() {
            keep[x] = true;
            correction[x] = 0;
            if c == NOT_FLAT {
                continue;
            }
            let g = gradient[x];
            let (ux, uy) = (u0[0] + step[0] * x as f64, u0[1] + step[1] * x as f64);
            if g[0] == i8::MIN {
                // More than 16 tolerances per pixel: a motion of 1/16 px matters.
                keep[x] = 16.0 * ux.hypot(uy) <= self.noise_scale;
                continue;
            }
            // The change in units of the reference tolerance.
            let e = (g[0] as f64 * ux + g[1] as f64 * uy) / units;
            keep[x] = e.abs() <= self.noise_scale;
            let tol = probe.tolerance[p0 + (x & 1)].get(c as usize).copied().unwrap_or(0.0) as f64;
            correction[x] = (e * tol).round() as i32;
        }
    }
}

impl MotionProbe {
    /// The mean and its gradient at `(x + ux, y + uy)` on the colour lattice of `(x, y)`
    /// (bilinear between the four nearest same-colour pixels), and the sum of the four
    /// weights' squares (the share of one mean pixel's noise variance the value holds: 1 on a
    /// node, ¼ mid-way between four).
    #[inline]
    fn warp(&self, w: usize, h: usize, x: usize, y: usize, u: [f64; 2]) -> (f64, [f64; 2], f64) {
        let along = |p: usize, d: f64, n: usize| -> (usize, f64) {
            let parity = p & 1;
            let cells = (n - parity - 1) / 2; // lattice points 0..=cells
            let f = ((p as f64 + d) - parity as f64) / 2.0;
            let i = (f.floor().max(0.0) as usize).min(cells.saturating_sub(1));
            (parity + 2 * i, (f - i as f64).clamp(-0.5, 1.5))
        };
        let (x0, a) = along(x, u[0], w);
        let (y0, b) = along(y, u[1], h);
        let (x1, y1) = ((x0 + 2).min(w - 1), (y0 + 2).min(h - 1));
        let v = |yy: usize, xx: usize| self.mean[yy * w + xx] as f64;
        let (v00, v01, v10, v11) = (v(y0, x0), v(y0, x1), v(y1, x0), v(y1, x1));
        let top = v00 + a * (v01 - v00);
        let bottom = v10 + a * (v11 - v10);
        let value = top + b * (bottom - top);
        let gx = ((v01 - v00) * (1.0 - b) + (v11 - v10) * b) / 2.0;
        let gy = (bottom - top) / 2.0;
        let squares = ((1.0 - a).powi(2) + a * a) * ((1.0 - b).powi(2) + b * b);
        (value, [gx, gy], squares)
    }
}

/// Parameters: 6 of the motion field, then gain and offset per position.
const PARAMS: usize = 6 + 2 * POSITIONS;

/// A motion component is kept only when its standard error is at most this (pixels).
const MAX_MOTION_SE: f64 = 0.1;

/// A motion is kept when it is this many times the difference between the two halves' fits.
const HALVES_AGREE: f64 = 2.0;

/// χ²'s 99.9 % points with 1, 2, 4 and 6 degrees of freedom.
const CHI2_1_999: f64 = 10.828;
const CHI2_2_999: f64 = 13.816;
const CHI2_4_999: f64 = 18.467;
const CHI2_6_999: f64 = 22.458;

/// A frame whose [`motion_score`] is below this is still: the motion fit, the likelihood ratio
/// and the halves are skipped. Half the ratio's threshold, so only a frame whose ratio the
/// score's quadratic approximation misses by a factor of two could differ. Compared frame by
/// frame with the full path on the registration tests, the still charts and the moving study
/// (3 224 frames): 663 skipped, none of them one the full path found moving; the lowest score
/// of a frame it found moving was 12.2 (0.027 px), the next 15.7. The bench's still 12 MP chart
/// (2-frame reference) scores 1.4–8.2 (before the clean-noise term: 31–40).
const NO_MOTION_SCORE: f64 = CHI2_6_999 / 2.0;

/// One Gauss–Newton fit of a frame on the clean image.
#[derive(Clone)]
struct Fit {
    motion: FrameMotion,
    gain: [f64; POSITIONS],
    offset: [f64; POSITIONS],
    /// Robust SD of the residuals (DN).
    scale: f64,
    /// The normal matrix of the last iteration.
    normal: Vec<Vec<f64>>,
    /// Per anchor, squared residual over a reference frame's noise variance.
    anchor_ratios: Vec<f64>,
}

/// Into `rows`, per sample at motion `m`, gain and offset: its row, weight 1, Jacobian row (the
/// motion's six columns zero unless `free_motion`) and residual; into `slack` its slack
/// ([`MODEL_SLACK_PX`] times its gradient). Both are cleared first: a fit reuses them at every
/// iteration (at 5 000 samples a fresh `rows` is 0.7 MB of newly mapped, zeroed pages).
#[allow(clippy::too_many_arguments)]
fn rows_at(
    probe: &MotionProbe,
    samples: &[Sample],
    w: usize,
    h: usize,
    m: &FrameMotion,
    gain: &[f64; POSITIONS],
    offset: &[f64; POSITIONS],
    free_motion: bool,
    rows: &mut Vec<Row<PARAMS>>,
    slack: &mut Vec<f64>,
) {
    // Each row has an offset of its own (row noise: one offset per row and frame, several
    // DN at a high ISO): rows are fixed effects, taken out of the residuals and of the
    // Jacobian by demeaning within the row. A vertical motion moves a row's edges, not the
    // row as a whole, so it stays identified where a row crosses both patches and gaps.
    rows.clear();
    slack.clear();
    for s in samples {
        let (dx, dy) = ((s.x as f64 - m.centre[0]) / m.radius, (s.y as f64 - m.centre[1]) / m.radius);
        let u = m.at(s.x as f64, s.y as f64);
        let (v, g, _) = probe.warp(w, h, s.x, s.y, u);
        let r = s.value - (gain[s.pos] * v + offset[s.pos]);
        let (gx, gy) = (gain[s.pos] * g[0], gain[s.pos] * g[1]);
        slack.push(MODEL_SLACK_PX * gx.hypot(gy));
        let mut j = [0.0f64; PARAMS];
        if free_motion {
            j[0] = gx;
            j[1] = gy;
            j[2] = gx * dx;
            j[3] = gx * dy;
            j[4] = gy * dx;
            j[5] = gy * dy;
        }
        j[6 + 2 * s.pos] = v;
        // The row effects hold each row's first position's offset: only the second
        // position's offset (its difference) is a parameter.
        if s.pos & 1 == 1 {
            j[7 + 2 * s.pos] = 1.0;
        }
        rows.push((s.y, 1.0, j, r));
    }
}

/// The weighted normal equations `[JᵀWJ | JᵀWr]` of weighted, row-demeaned `rows` (a tiny
/// ridge keeps fixed parameters and positions without samples, a mono crop, solvable); into
/// `residuals` (cleared first) the absolute residuals, and into `anchor_ratios` each anchor's
/// squared residual over a reference frame's noise variance.
fn normal_equations(
    samples: &[Sample],
    rows: &[Row<PARAMS>],
    residuals: &mut Vec<f64>,
    anchor_ratios: &mut Vec<f64>,
) -> Vec<Vec<f64>> {
    anchor_ratios.clear();
    residuals.clear();
    let mut a = vec![vec![0.0f64; PARAMS + 1]; PARAMS];
    for (k, s) in samples.iter().enumerate() {
        let (_, wgt, j, r) = &rows[k];
        let wgt = *wgt;
        residuals.push(r.abs());
        if let Some(sd) = s.anchor_sd {
            anchor_ratios.push(r * r / (sd as f64 * sd as f64).max(1e-6));
        }
        // A row holds two positions: about 9 of the 14 columns are non-zero.
        let mut nz = [0usize; PARAMS];
        let mut k = 0;
        for (i, &v) in j.iter().enumerate() {
            if v != 0.0 {
                nz[k] = i;
                k += 1;
            }
        }
        let nz = &nz[..k];
        for &r1 in nz {
            let wj = wgt * j[r1];
            for &c1 in nz {
                a[r1][c1] += wj * j[c1];
            }
            a[r1][PARAMS] += wj * r;
        }
    }
    for (k, row) in a.iter_mut().enumerate() {
        row[k] += 1e-9 * (1.0 + row[k]);
    }
    a
}

/// The score statistic of motion at the still fit `still`: the decrease of the weighted squared
/// residuals (in units of the fit's scale) that one Gauss–Newton step with the motion freed
/// predicts, `bᵀA⁻¹b / scale²`, with Huber weights as the motion fit's first steps (Tukey's
/// would give a moved frame's edges, outliers to a still fit, no weight). At no motion a
/// sample's gradient on the lattice, `(mean(x + 2) − mean(x)) / 2`, shares the clean image's
/// noise at `x` with its residual: `b` is taken less that expectation (`gain²·σ²/frames / 2`
/// per sample and direction, `σ²` one reference frame's noise variance at its level), which
/// grows with the number of samples and made a still chart's score 17–40 instead of χ²₆'s 6.
/// For a small motion the score is the likelihood ratio's quadratic approximation: well below
/// the ratio's threshold ([`NO_MOTION_SCORE`]) the frame is still without fitting the motion.
fn motion_score(probe: &MotionProbe, samples: &[Sample], w: usize, h: usize, still: &Fit, frames: u32) -> Option<f64> {
    let (mut rows, mut slack) = (Vec::with_capacity(samples.len()), Vec::with_capacity(samples.len()));
    rows_at(probe, samples, w, h, &still.motion, &still.gain, &still.offset, true, &mut rows, &mut slack);
    robust_weights(&mut rows, &slack, still.scale, false);
    // The clean image's noise in each sample's gradient and residual, weighted, less the share
    // its row's mean takes out.
    let m = &still.motion;
    let mut bias = [0.0f64; 6];
    let mut at = 0;
    for group in rows.chunk_by(|a, b| a.0 == b.0) {
        let wsum: f64 = group.iter().map(|r| r.1).sum();
        for (k, r) in group.iter().enumerate() {
            let s = &samples[at + k];
            let level = r.2[6 + 2 * s.pos].round().max(0.0) as usize;
            let sd = probe.tolerance[s.pos].get(level).copied().unwrap_or(0.0) as f64 / MOTION_TOLERANCE;
            let g = still.gain[s.pos];
            let e = r.1 * (1.0 - r.1 / wsum.max(f64::MIN_POSITIVE)) * g * g * sd * sd / frames.max(1) as f64 / 2.0;
            let (dx, dy) = ((s.x as f64 - m.centre[0]) / m.radius, (s.y as f64 - m.centre[1]) / m.radius);
            for (b, c) in bias.iter_mut().zip([1.0, 1.0, dx, dy, dx, dy]) {
                *b += e * c;
            }
        }
        at += group.len();
    }
    demean_rows(&mut rows);
    let mut a = normal_equations(samples, &rows, &mut Vec::with_capacity(samples.len()), &mut Vec::new());
    for (row, b) in a.iter_mut().zip(bias) {
        row[PARAMS] -= b;
    }
    let b: Vec<f64> = a.iter().map(|r| r[PARAMS]).collect();
    let d = solve(a)?;
    let s = d.iter().zip(&b).map(|(d, b)| d * b).sum::<f64>() / (still.scale * still.scale);
    s.is_finite().then_some(s)
}

/// Fits gain and offset per position and, when `free_motion`, the motion field, starting from
/// `start` (or from no motion, gain 1, offset 0), robustly weighted ([`robust_weights`]) at the previous iteration's
/// robust scale, for at most `iterations` Gauss–Newton steps.
#[allow(clippy::too_many_arguments)]
fn fit(
    probe: &MotionProbe,
    samples: &[Sample],
    w: usize,
    h: usize,
    free_motion: bool,
    start: Option<&Fit>,
    iterations: usize,
) -> Option<Fit> {
    let mut m = start.map_or_else(|| FrameMotion::still(w, h), |f| f.motion);
    let mut gain = start.map_or([1.0; POSITIONS], |f| f.gain);
    let mut offset = start.map_or([0.0; POSITIONS], |f| f.offset);
    let mut scale = start.map_or(f64::INFINITY, |f| f.scale);
    let mut normal = Vec::new();
    let mut anchor_ratios = Vec::new();
    let (mut rows, mut slack) = (Vec::with_capacity(samples.len()), Vec::with_capacity(samples.len()));
    let mut residuals = Vec::with_capacity(samples.len());
    for it in 0..iterations {
        rows_at(probe, samples, w, h, &m, &gain, &offset, free_motion, &mut rows, &mut slack);
        // Huber weights first (the motion is not yet fitted: an edge's residual is its signal),
        // then, once the motion is, redescending ones: a pixel that glitched (hot, flickering,
        // RTS) or did something else (dust, a reflection) weighs nothing, in the fit and in its
        // row's offset.
        let redescend = it >= if free_motion { 2 } else { 1 };
        robust_weights(&mut rows, &slack, scale, redescend);
        demean_rows(&mut rows);
        let a = normal_equations(samples, &rows, &mut residuals, &mut anchor_ratios);
        normal = a.iter().map(|r| r[..PARAMS].to_vec()).collect();
        let d = solve(a)?;
        m.t[0] += d[0];
        m.t[1] += d[1];
        m.a[0][0] += d[2];
        m.a[0][1] += d[3];
        m.a[1][0] += d[4];
        m.a[1][1] += d[5];
        for p in 0..POSITIONS {
            gain[p] += d[6 + 2 * p];
            offset[p] += d[7 + 2 * p];
        }
        if !residuals.is_empty() {
            scale = (1.4826 * median_in_place(&mut residuals)).max(0.25);
        }
        if !m.t.iter().chain(m.a.iter().flatten()).chain(&gain).chain(&offset).all(|v| v.is_finite()) {
            return None;
        }
        let change = d[..6]
            .iter()
            .chain(&d[6..].iter().step_by(2).copied().collect::<Vec<_>>())
            .fold(0.0f64, |a, v| a.max(v.abs()));
        if change < 1e-3 && redescend {
            break;
        }
    }
    m.residual_sd = scale;
    m.samples = samples.len();
    Some(Fit { motion: m, gain, offset, scale, normal, anchor_ratios })
}

/// How far (pixels) the motion model may miss at an edge (a bilinear warp on a colour's 2-px
/// lattice pulls a sub-pixel shift by up to 15–20 %): a sample's residual is judged against
/// the noise and this much motion along its gradient, so a steep edge the model misses is not
/// taken for a glitch.
const MODEL_SLACK_PX: f64 = 0.15;

/// The robust objective of a fit at `scale` (Tukey's biweight), each row's robust offset taken
/// out, with each sample's share of the clean image's noise made the same at every motion: a
/// warp between lattice nodes averages the mean's noise (`mean_var`: per sample, one reference
/// frame's noise variance over the burst's frames, times the gain squared), so without that
/// term any motion lowers the objective of a still frame by up to ¾ of it per sample and the
/// likelihood ratio finds motion on a chart whose edges move few pixels (hard 1-px steps).
fn objective(probe: &MotionProbe, samples: &[Sample], w: usize, h: usize, f: &Fit, scale: f64, frames: u32) -> f64 {
    let mut slack = Vec::with_capacity(samples.len());
    let mut smoothed = Vec::with_capacity(samples.len());
    let mut rows: Vec<Row<PARAMS>> = samples
        .iter()
        .map(|s| {
            let u = f.motion.at(s.x as f64, s.y as f64);
            let (v, g, squares) = probe.warp(w, h, s.x, s.y, u);
            let gain = f.gain[s.pos];
            slack.push(MODEL_SLACK_PX * gain * g[0].hypot(g[1]));
            let level = v.round().max(0.0) as usize;
            let sd = probe.tolerance[s.pos].get(level).copied().unwrap_or(0.0) as f64 / MOTION_TOLERANCE;
            smoothed.push(gain * gain * sd * sd / frames.max(1) as f64 * (1.0 - squares));
            (s.y, 1.0, [0.0; PARAMS], s.value - (gain * v + f.offset[s.pos]))
        })
        .collect();
    robust_weights(&mut rows, &slack, scale, true);
    demean_rows(&mut rows);
    rows.iter()
        .zip(&slack)
        .zip(&smoothed)
        .map(|((r, sl), sm)| {
            let cost = tukey(r.3, scale.hypot(*sl));
            // An outlier's cost is capped whatever the noise: only inliers get the term.
            if r.1 > 0.0 { cost + 0.5 * sm } else { cost }
        })
        .sum()
}

/// A frame's motion against the clean image whose probe is `probe` (`None` when the clean image
/// has no edges to register on, or the fit is singular). `tf` maps the frame's raw values onto
/// the session's black level; values above `clip` are not used; `frames`: the reference burst's
/// frames (the clean image's noise is one frame's over their number).
///
/// Motion is claimed only where the frame shows it: the fit with motion must beat the fit
/// without (gain and offset alone) by a likelihood ratio beyond χ²₆'s 99.9 % point; then the
/// translation and the linear part (rotation, scale, shear) are each kept when their Wald
/// statistic passes χ²'s 99.9 % point and when they are at least twice the difference between
/// fits on the two halves of the samples (alternate row pairs). A noisy frame on a small chart
/// otherwise "moves" by its noise: a still 96 × 72 session at 50 × its base ISO registered up to
/// 1 px in a few frames by the Wald test alone, and a still 128 × 96 session with heavy-tailed
/// read noise and row noise passed the likelihood ratio in most frames (its residuals are not
/// independent: row noise), with motions of 0.2–1.7 px that left samples out for nothing.
pub(crate) fn register(
    probe: &MotionProbe,
    frame: &FrameView<'_>,
    tf: &Transform,
    width: usize,
    height: usize,
    clip: f32,
    frames: u32,
) -> Option<FrameMotion> {
    let (w, h) = (width, height);
    if probe.samples.len() < 64 {
        return None;
    }
    let mut samples: Vec<Sample> = probe
        .samples
        .iter()
        .enumerate()
        .filter_map(|(k, &i)| {
            let (y, x) = (i as usize / w, i as usize % w);
            let pos = position(y, x);
            let value = tf.apply(pos, frame.get(y, x)) as f64;
            let anchor_sd = k.checked_sub(probe.anchors_from).and_then(|a| probe.anchor_sd.get(a).copied());
            (value < clip as f64).then_some(Sample { x, y, pos, value, anchor_sd })
        })
        .collect();
    // Rows together: each row's offset is a fixed effect of the fits.
    samples.sort_by_key(|s| (s.y, s.x));
    // Without motion the model is linear in gain and offset: two passes (the second at the
    // residuals' own scale) fit it.
    let still = fit(probe, &samples, w, h, false, None, 2)?;
    let score = motion_score(probe, &samples, w, h, &still, frames);
    if score.is_some_and(|s| s < NO_MOTION_SCORE) {
        return Some(with_noise_scale(still).motion);
    }
    let moved = fit(probe, &samples, w, h, true, Some(&still), MAX_ITERATIONS)?;
    let s0 = still.scale;
    let ratio = 2.0
        * (objective(probe, &samples, w, h, &still, s0, frames) - objective(probe, &samples, w, h, &moved, s0, frames))
        / (s0 * s0);
    let significant = ratio > CHI2_6_999;

    let mut out = if significant { moved } else { still.clone() };
    if significant {
        // The same motion must show in both halves of the samples (alternate row pairs: their
        // row noise, and any other misfit of the model, is their own), each found from no
        // motion: started from the whole's, both halves stayed in its basin when that was a
        // local optimum (a still sensor with 8 DN of row noise "moved" 2.2 px).
        let (even, odd): (Vec<Sample>, Vec<Sample>) = samples.into_iter().partition(|s| (s.y / 2) % 2 == 0);
        let (half_a, half_b) = rayon::join(
            || fit(probe, &even, w, h, true, Some(&still), MAX_ITERATIONS),
            || fit(probe, &odd, w, h, true, Some(&still), MAX_ITERATIONS),
        );
        let (half_a, half_b) = (half_a?, half_b?);
        let m = &mut out.motion;
        let corners = [(0.0, 0.0), (w as f64, 0.0), (0.0, h as f64), (w as f64, h as f64)];
        let linear = |f: &FrameMotion, x: f64, y: f64| {
            let u = f.at(x, y);
            [u[0] - f.t[0], u[1] - f.t[1]]
        };
        let dist = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
        let t_gap = dist(half_a.motion.t, half_b.motion.t);
        let a_gap = corners
            .iter()
            .map(|&(x, y)| dist(linear(&half_a.motion, x, y), linear(&half_b.motion, x, y)))
            .fold(0.0, f64::max);
        let a_size = corners.iter().map(|&(x, y)| dist(linear(m, x, y), [0.0; 2])).fold(0.0, f64::max);
        let cov = invert(&out.normal)?;
        let sc = out.scale;
        let cov = |i: usize, j: usize| cov[i][j] * sc * sc;
        let m = &mut out.motion;
        let theta = [m.t[0], m.t[1], m.a[0][0], m.a[0][1], m.a[1][0], m.a[1][1]];
        let wald = |idx: &[usize]| -> f64 {
            let sub: Vec<Vec<f64>> = idx.iter().map(|&i| idx.iter().map(|&j| cov(i, j)).collect()).collect();
            match invert(&sub) {
                Some(inv) => idx
                    .iter()
                    .enumerate()
                    .map(|(r, &i)| idx.iter().enumerate().map(|(c, &j)| theta[i] * inv[r][c] * theta[j]).sum::<f64>())
                    .sum(),
                None => 0.0,
            }
        };
        // The halves' difference has twice the variance of one half's, four times the whole's:
        // the whole's error is about half the gap, and a motion is kept at twice the gap.
        let keep_t = wald(&[0, 1]) >= CHI2_2_999 && m.t[0].hypot(m.t[1]) >= HALVES_AGREE * t_gap;
        let keep_a = wald(&[2, 3, 4, 5]) >= CHI2_4_999 && a_size >= HALVES_AGREE * a_gap;
        // And each component on its own: a scene whose edges all run one way (vertical bands)
        // says nothing of a motion along them, and that component, free in the fit, is noise
        // whatever the others show (a still ramp of bands "moved" 2.6 px along them).
        let (ha, hb) = (&half_a.motion, &half_b.motion);
        let halves = [ha.t[0], ha.t[1], ha.a[0][0], ha.a[0][1], ha.a[1][0], ha.a[1][1]];
        let halves_b = [hb.t[0], hb.t[1], hb.a[0][0], hb.a[0][1], hb.a[1][0], hb.a[1][1]];
        // A component is kept only when the frame pins it within 0.1 px (its standard error).
        // Along a direction the scene does not vary in, the fit drifts on the clean image's own
        // noise — its gradient correlates with the residual that holds the same error — and is
        // "significant" by every test above: a still ramp of horizontal bands moved 2.4 px down
        // in both halves, with a standard error of 0.36 px.
        let alone: [bool; 6] = std::array::from_fn(|k| {
            let var = cov(k, k);
            var > 0.0
                && var <= MAX_MOTION_SE * MAX_MOTION_SE
                && theta[k] * theta[k] / var >= CHI2_1_999
                && theta[k].abs() >= HALVES_AGREE * (halves[k] - halves_b[k]).abs()
        });
        let kept: [f64; 6] = std::array::from_fn(|k| {
            let block = if k < 2 { keep_t } else { keep_a };
            if block && alone[k] { theta[k] } else { 0.0 }
        });
        m.t = [kept[0], kept[1]];
        m.a = [[kept[2], kept[3]], [kept[4], kept[5]]];
    }
    Some(with_noise_scale(out).motion)
}

/// `f` with its motion's noise scale set from the anchors' squared residuals over a reference
/// frame's noise variance: their median is 0.455 of the variance ratio for Gaussian noise
/// (χ²₁'s median), and the same ratio holds for any one shape of noise at both ISOs.
fn with_noise_scale(mut f: Fit) -> Fit {
    if f.anchor_ratios.len() >= 32 {
        f.motion.noise_scale = (median(&f.anchor_ratios) / 0.455).sqrt().clamp(1.0, 1e3);
    }
    f
}

mod anchor_bits;
mod probe;
use probe::GRADIENT_UNITS;
pub use probe::{MOTION_TOLERANCE, MotionProbe};
mod robust;
#[cfg(test)]
mod still_charts;

#[cfg(test)]
mod tests {
    use super::probe::sobel;
    use super::*;
    use crate::calibrate::flat::{FlatReport, Groups};
    use crate::model::layout::SensorLayout;

    /// A smooth test scene: a grid of blurred rectangular patches (edges in x and y, a row
    /// crossing patches and gaps), at `(x, y)`.
    fn scene(x: f64, y: f64) -> f64 {
        let edge = |t: f64, at: f64| 0.5 * (1.0 + ((t - at) / 1.2).tanh());
        let band = |t: f64, at: f64| edge(t, at) - edge(t, at + 10.0);
        let mut v = 200.0;
        for i in 0..8 {
            for j in 0..6 {
                let level = 150.0 + 40.0 * ((i * 5 + j * 3) % 7) as f64;
                v += level * band(x, 10.0 + 20.0 * i as f64) * band(y, 13.0 + 20.0 * j as f64);
            }
        }
        v
    }

    fn probe_of(w: usize, h: usize) -> (MotionProbe, Groups) {
        let mean: Vec<u16> =
            (0..h).flat_map(|y| (0..w).map(move |x| scene(x as f64, y as f64).round() as u16)).collect();
        let levels = mean.clone();
        let groups = Groups { black: [0.0; POSITIONS], white: 1023 };
        let mut flat = FlatReport::default();
        flat.mean_noise = [[1.0 / 8.0, 0.0, 0.0]; POSITIONS];
        flat.mean_noise_groups = vec![f32::NAN; POSITIONS * crate::calibrate::flat::GROUPS];
        (MotionProbe::new(mean, &levels, w, h, 8, &flat, &groups, 1000.0), groups)
    }

    /// The transform of an RGGB 10-bit frame at black 0 and the session's own brightness.
    fn identity_transform(w: usize, h: usize) -> Transform {
        let layout = SensorLayout {
            width: w as u32,
            height: h as u32,
            cfa: crate::CfaPattern::Rggb,
            black: [0.0; POSITIONS],
            white: 1023,
        };
        let meta = crate::FrameMeta { iso: 100, exposure_ns: 1, black: None };
        Transform::of(&layout, &meta, 1.0)
    }

    #[test]
    fn registration_recovers_shifts_rotation_and_gain() {
        let (w, h) = (160usize, 128usize);
        let (probe, _) = probe_of(w, h);
        let tf = identity_transform(w, h);
        for (tx, ty, rot, gain) in
            [(0.3, -0.2, 0.0, 1.0), (-0.55, 0.45, 0.002, 1.05), (0.0, 0.0, 0.0, 0.97), (1.1, -0.8, -0.001, 1.0)]
        {
            let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
            let frame: Vec<u16> = (0..h)
                .flat_map(|y| {
                    (0..w).map(move |x| {
                        let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                        let (ux, uy) = (tx - rot * dy, ty + rot * dx);
                        (gain * scene(x as f64 + ux, y as f64 + uy)).round() as u16
                    })
                })
                .collect();
            let view = FrameView::from_u16(&frame, w, h, w).expect("view");
            let m = register(&probe, &view, &tf, w, h, 1000.0, 8).expect("registered");
            let u = m.at(cx, cy);
            // Bilinear interpolation on a colour's 2-px lattice pulls a shift towards the
            // lattice: within 15 % (+ 0.01 px) of the truth.
            let tol = |t: f64| 0.15 * t.abs() + 0.01;
            assert!((u[0] - tx).abs() < tol(tx) && (u[1] - ty).abs() < tol(ty), "shift {u:?} vs ({tx}, {ty})");
            // A rotation is found, or — beside a shift of a pixel, whose lattice pull is as
            // large as the rotation's 0.1 px at the corners — left out; never invented.
            let dropped = m.rotation() == 0.0 && tx.hypot(ty) > 1.0;
            assert!(dropped || (m.rotation() - rot).abs() < 3e-4, "rotation {} vs {rot}", m.rotation());
            let corner = m.at(0.0, 0.0);
            let want = [tx - rot * (-cy), ty + rot * (-cx)];
            let slack = if dropped { 0.04 + rot.abs() * cx.hypot(cy) } else { 0.04 };
            assert!(
                (corner[0] - want[0]).abs() < tol(want[0]) + slack
                    && (corner[1] - want[1]).abs() < tol(want[1]) + slack,
                "{corner:?} vs {want:?}"
            );
        }
    }

    /// A frame of the test scene moved by `(tx, ty)`, with Gaussian noise of SD `sd` and `share`
    /// of its pixels (chosen by a hash, afresh per `seed`) off by ±`jump` DN: hot, flickering or
    /// RTS pixels, which change from frame to frame but do not move.
    fn glitched_frame(w: usize, h: usize, tx: f64, ty: f64, sd: f64, share: f64, jump: f64, seed: u64) -> Vec<u16> {
        let hash = |y: usize, x: usize, k: u64| {
            ((y as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (x as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F) ^ k)
                .wrapping_mul(0x2545_F491_4F6C_DD1D)
                .rotate_left(29)
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        };
        let unit = |v: u64| ((v >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
        (0..h)
            .flat_map(|y| {
                (0..w).map(move |x| {
                    let (u1, u2) = (unit(hash(y, x, seed)), unit(hash(y, x, seed ^ 0x5555)));
                    let gauss = (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
                    let mut v = scene(x as f64 + tx, y as f64 + ty) + sd * gauss;
                    let g = hash(y, x, seed.wrapping_add(0xABCD));
                    if unit(g) < share {
                        v += if g & (1 << 7) == 0 { jump } else { -jump };
                    }
                    v.round().clamp(0.0, 1023.0) as u16
                })
            })
            .collect()
    }

    #[test]
    fn glitching_pixels_are_not_motion_and_a_real_shift_is_still_found() {
        let (w, h) = (160usize, 128usize);
        let (probe, _) = probe_of(w, h);
        let tf = identity_transform(w, h);
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        let mut worst_still: f64 = 0.0;
        for seed in 0..8u64 {
            // Still, 4 % of pixels ±120 DN (120 SD) off: no motion beyond a few hundredths px.
            let frame = glitched_frame(w, h, 0.0, 0.0, 1.0, 0.04, 120.0, seed);
            let view = FrameView::from_u16(&frame, w, h, w).expect("view");
            let m = register(&probe, &view, &tf, w, h, 1000.0, 8).expect("registered");
            worst_still = worst_still.max(m.max_shift());
            // Moved by a known shift, with the same glitches: found as without them.
            let (tx, ty) = (0.3 - 0.07 * seed as f64, -0.25 + 0.05 * seed as f64);
            let frame = glitched_frame(w, h, tx, ty, 1.0, 0.04, 120.0, seed + 100);
            let view = FrameView::from_u16(&frame, w, h, w).expect("view");
            let m = register(&probe, &view, &tf, w, h, 1000.0, 8).expect("registered");
            let u = m.at(cx, cy);
            let tol = |t: f64| 0.15 * t.abs() + 0.02;
            assert!(
                (u[0] - tx).abs() < tol(tx) && (u[1] - ty).abs() < tol(ty),
                "seed {seed}: shift {u:?} vs ({tx}, {ty}) among glitching pixels"
            );
        }
        assert!(worst_still <= 0.03, "a still frame with glitching pixels moved {worst_still:.3} px");
    }

    #[test]
    fn moved_pixels_are_those_whose_level_the_motion_changes() {
        let (w, h) = (160usize, 128usize);
        let (probe, _) = probe_of(w, h);
        let mut m = FrameMotion::still(w, h);
        // Row 18 is mid-way down a row of patches (5 px from its horizontal edges); the patches'
        // vertical edges cross it.
        let y = 18;
        let row: Vec<u16> = probe.mean[y * w..(y + 1) * w].to_vec();
        let (mut keep, mut correction) = (vec![true; w], vec![0i32; w]);
        let left_out = |keep: &[bool]| keep.iter().filter(|&&k| !k).count();
        let gradient = &probe.gradients(&probe.mean, w)[y * w..(y + 1) * w];
        m.row_effects(&probe, gradient, y, &row, &mut keep, &mut correction);
        assert_eq!(left_out(&keep), 0, "a still frame leaves nothing out");
        assert!(correction.iter().all(|&c| c == 0), "and corrects nothing");
        m.t = [0.5, 0.0];
        m.row_effects(&probe, gradient, y, &row, &mut keep, &mut correction);
        let left = left_out(&keep);
        // Per-frame noise SD 1 DN, tolerance 0.25 DN: a pixel is left out when its x-gradient
        // exceeds 0.5 DN/px; the Sobel gradient of the scene decides which.
        let mut want = 0;
        for x in 0..w {
            let g = sobel(&probe.mean, w, h, x, y);
            if (g[0] * 0.5).abs() > 0.25 * 1.01 {
                want += 1;
            }
        }
        assert!(left > 10, "edges cross row {y}");
        assert!((left as i64 - want as i64).abs() <= 4, "left out {left}, gradient says {want}");
        // A kept pixel's correction is its predicted change, within rounding and the gradient's
        // quantisation (1/64 of the tolerance per px).
        for x in 0..w {
            if keep[x] {
                let g = sobel(&probe.mean, w, h, x, y);
                assert!(
                    (correction[x] as f64 - g[0] * 0.5).abs() <= 0.5 + 0.01,
                    "x {x}: {} vs {}",
                    correction[x],
                    g[0] * 0.5
                );
            }
        }
    }
}
