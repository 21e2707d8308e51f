//! Frame brightness drift (mains flicker, a mechanical shutter, exposure not truly locked): a
//! frame whose brightness departs from its burst's by more than its noise explains is reported and,
//! by default, normalised to its burst (method.md, "Calibration" 3).
//!
//! - [`brightness_sums`]: a frame against a base image, per row band and per CFA position.
//! - [`DriftTracker`]: the running judgement of one burst.
//! - [`Transform`]: how a frame's raw values map onto the session's black level and brightness.

use multiversion::multiversion;
use serde::{Deserialize, Serialize};

use crate::calibrate::flat::NOT_FLAT;
use crate::calibrate::frame::FrameView;
use crate::calibrate::meta::FrameMeta;
use crate::math::stats::median;
use crate::model::layout::{POSITIONS, SensorLayout};

/// Row bands used to measure a frame's brightness and its standard error.
const BANDS: usize = 16;

/// How a session judges and normalises frame brightness (from its configuration).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftPolicy {
    /// Threshold in standard errors of a frame's brightness.
    pub z: f64,
    /// Threshold floor (relative).
    pub floor: f64,
    /// Largest departure normalised as flicker; beyond it the frame is refused.
    pub max: f64,
    /// Normalise drifted frames (else only report them).
    pub normalise: bool,
}

/// How raw values of a frame map to the session's black level and brightness.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Transform {
    /// Frame black − layout black, per position.
    pub(crate) delta: [f32; POSITIONS],
    pub(crate) black: [f32; POSITIONS],
    pub(crate) scale: f32,
}

impl Transform {
    /// The transform of a frame reported with `meta`, scaled by `scale`.
    pub(crate) fn of(layout: &SensorLayout, meta: &FrameMeta, scale: f64) -> Self {
        let fb = meta.black_or(layout);
        Transform { delta: std::array::from_fn(|p| fb[p] - layout.black[p]), black: layout.black, scale: scale as f32 }
    }

    pub(crate) fn identity(&self) -> bool {
        self.scale == 1.0 && self.delta.iter().all(|&d| d == 0.0)
    }

    #[inline]
    pub(crate) fn apply(&self, pos: usize, x: u16) -> f32 {
        self.black[pos] + (x as f32 - self.black[pos] - self.delta[pos]) * self.scale
    }
}

/// Levels above this (90 % of the range) are left out of brightness ratios: clipping bends them.
pub(crate) fn clip_level(l: &SensorLayout) -> f32 {
    let b = l.black.iter().cloned().fold(f32::INFINITY, f32::min);
    b + 0.9 * (l.white as f32 - b)
}

/// Σ(frame − black) and Σ(base − black) over pixels where the base is flat and unclipped, per CFA
/// position (for gain ratios), and per row band the sums of a straight-line fit of frame on base
/// (for a frame's brightness and its standard error), in one pass over every fourth row pair of
/// large frames.
pub(crate) struct BrightnessSums {
    /// Per band `[n, Σb, Σf, Σb², Σbf]` (`b`, `f`: base and frame above black).
    pub(crate) bands: Vec<[f64; 5]>,
    pub(crate) frame_pos: [f64; POSITIONS],
    pub(crate) base_pos: [f64; POSITIONS],
}

impl BrightnessSums {
    /// The frame's brightness against the base, `None` where the base has nothing to compare.
    pub(crate) fn brightness(&self) -> Option<FrameBrightness> {
        brightness_from_fit(&self.bands)
    }
}

/// The rows brightness is measured on (every row pair, every fourth above 512 rows), each with
/// its band: both ways of summing visit them in this order.
fn sampled_rows(h: usize) -> impl Iterator<Item = (usize, usize)> {
    let rows_per_band = h.div_ceil(BANDS).max(1);
    let step = if h > 512 { 4 } else { 1 };
    (0..h)
        .step_by(2 * step)
        .flat_map(|y| [y, y + 1])
        .filter(move |&y| y < h)
        .map(move |y| (y, (y / rows_per_band).min(BANDS - 1)))
}

pub(crate) fn brightness_sums(
    frame: &FrameView<'_>,
    base: &[u16],
    tf: &Transform,
    clip: f32,
    w: usize,
    h: usize,
) -> BrightnessSums {
    if let Some(sums) = integer_brightness_sums(frame, base, tf, clip, w, h) {
        return sums;
    }
    float_brightness_sums(frame, base, tf, clip, w, h)
}

/// [`brightness_sums`] in floating point, each pixel's terms added in turn.
fn float_brightness_sums(
    frame: &FrameView<'_>,
    base: &[u16],
    tf: &Transform,
    clip: f32,
    w: usize,
    h: usize,
) -> BrightnessSums {
    let mut out =
        BrightnessSums { bands: vec![[0.0; 5]; BANDS], frame_pos: [0.0; POSITIONS], base_pos: [0.0; POSITIONS] };
    let mut buf = vec![0u16; w];
    for (y, band) in sampled_rows(h) {
        frame.read_row(y, &mut buf);
        let mut sums = [0.0f64; 5];
        for x in 0..w {
            let c = base[y * w + x];
            if c == NOT_FLAT || c as f32 > clip {
                continue;
            }
            let pos = ((y & 1) << 1) | (x & 1);
            let fv = (tf.apply(pos, buf[x]) - tf.black[pos]) as f64;
            let bv = (c as f32 - tf.black[pos]) as f64;
            sums[0] += 1.0;
            sums[1] += bv;
            sums[2] += fv;
            sums[3] += bv * bv;
            sums[4] += bv * fv;
            out.frame_pos[pos] += fv;
            out.base_pos[pos] += bv;
        }
        for (o, v) in out.bands[band].iter_mut().zip(sums) {
            *o += v;
        }
    }
    out
}

/// [`brightness_sums`] as exact sums of integers, where that gives the same sums to the last
/// bit: a frame not transformed, integer black levels, and sums that cannot reach 2⁵³ (every
/// term, and so every partial sum the floating-point loop forms, is then an integer it holds
/// exactly, and the order of the additions changes nothing). `None` elsewhere.
fn integer_brightness_sums(
    frame: &FrameView<'_>,
    base: &[u16],
    tf: &Transform,
    clip: f32,
    w: usize,
    h: usize,
) -> Option<BrightnessSums> {
    let integral = |b: f32| b.fract() == 0.0 && (0.0..=65535.0).contains(&b);
    if !tf.identity() || !tf.black.iter().all(|&b| integral(b)) || clip.is_nan() || clip < 0.0 {
        return None;
    }
    // The largest base level compared: `c as f32 > clip` is `c > ⌊clip⌋` for an integer `c`.
    let top = clip.min(65535.0).floor() as u16;
    let black: [i64; POSITIONS] = tf.black.map(|b| b as i64);
    // |base − black| ≤ max(top, black), |frame − black| < 2¹⁶ (the mask keeps a base of
    // NOT_FLAT out, so a compared base level is at most 65534).
    let largest_base = black.iter().fold(top as i64, |m, &b| m.max(b)) as u128;
    if (w as u128) * (h as u128) * largest_base * 65536 >= 1u128 << 53 {
        return None;
    }
    let mut bands = vec![[0.0f64; 5]; BANDS];
    let (mut frame_pos, mut base_pos) = ([0.0f64; POSITIONS], [0.0f64; POSITIONS]);
    let mut buf = vec![0u16; w];
    for (y, band) in sampled_rows(h) {
        // The row in place where the frame's memory allows it.
        let row: &[u16] = match frame.row(y) {
            std::borrow::Cow::Borrowed(r) => r,
            std::borrow::Cow::Owned(v) => {
                buf.copy_from_slice(&v);
                &buf
            }
        };
        let crow = &base[y * w..y * w + w];
        let band = &mut bands[band];
        let parity = (y & 1) << 1;
        // Even columns are one position, odd ones the other: one pass over the column pairs.
        let sums = row_sums(crow, row, [black[parity], black[parity | 1]], top);
        for (pos, sums) in [(parity, sums[0]), (parity | 1, sums[1])] {
            for (o, v) in band.iter_mut().zip(sums) {
                *o += v;
            }
            frame_pos[pos] += sums[2];
            base_pos[pos] += sums[1];
        }
    }
    Some(BrightnessSums { bands, frame_pos, base_pos })
}

/// `[n, Σb, Σf, Σb², Σbf]` of the even columns and of the odd ones of one row (base levels
/// `crow`, frame values `row`) over the black levels `black` (integers), the pixels compared
/// being those whose base level is flat and at most `top`. Formed from the row's exact integer
/// sums of the raw values ([`raw_row_sums`]): `Σb = Σc − nB`, `Σb² = Σc² − 2BΣc + nB²`,
/// `Σbf = Σcv − B(Σc + Σv) + nB²`, every one an integer below 2⁵³ (the caller's bound), so the
/// `f64` it becomes is the sum the floating-point loop forms, to the last bit.
#[inline]
fn row_sums(crow: &[u16], row: &[u16], black: [i64; 2], top: u16) -> [[f64; 5]; 2] {
    let raw = raw_row_sums(crow, row, top);
    std::array::from_fn(|p| {
        let [n, c, v, cc, cv] = raw[p].map(|s| s as i64);
        let b = black[p];
        [n, c - n * b, v - n * b, cc - 2 * b * c + n * b * b, cv - b * (c + v) + n * b * b].map(|s| s as f64)
    })
}

/// `[n, Σc, Σv, Σc², Σcv]` over the even columns and over the odd ones of one row, of the pixels
/// whose base level `c` is flat and at most `top` (`v`: the frame's value), as exact integers:
/// a product of two u16 is below 2³², a row's sum of them below 2⁴⁸. Eight lanes, each pixel's
/// terms added branch-free (a pixel not compared adds zeros), lane `k` holding the columns
/// `x ≡ k (mod 8)`: the compiler turns it into vector arithmetic (32 × 32 → 64-bit products),
/// compiled for AVX-512 and AVX2 as well as the baseline, the CPU's best picked at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn raw_row_sums(crow: &[u16], row: &[u16], top: u16) -> [[u64; 5]; 2] {
    const LANES: usize = 8;
    let mut acc = [[0u64; LANES]; 5];
    #[inline(always)]
    fn add(acc: &mut [[u64; LANES]; 5], lane: usize, c: u16, v: u16, top: u16) {
        let m = ((c != NOT_FLAT && c <= top) as u32).wrapping_neg();
        let (c, v) = ((c as u32 & m) as u64, (v as u32 & m) as u64);
        acc[0][lane] += (m & 1) as u64;
        acc[1][lane] += c;
        acc[2][lane] += v;
        acc[3][lane] += c * c;
        acc[4][lane] += c * v;
    }
    let n = crow.len().min(row.len());
    let (crow, row) = (&crow[..n], &row[..n]);
    for (c, v) in crow.chunks_exact(LANES).zip(row.chunks_exact(LANES)) {
        for lane in 0..LANES {
            add(&mut acc, lane, c[lane], v[lane], top);
        }
    }
    let done = n / LANES * LANES;
    for x in done..n {
        // Lane `x mod 8`'s parity is the column's.
        add(&mut acc, x - done, crow[x], row[x], top);
    }
    std::array::from_fn(|p| acc.map(|s| s.iter().skip(p).step_by(2).sum()))
}

/// Brightness of one frame against a base image (the clean image, or the burst's first frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameBrightness {
    /// The frame's gain against the base: Σ(frame − black) / Σ(base − black) over the pixels
    /// compared, or (from [`brightness_from_fit`]) the slope of frame on base, which an additive
    /// black-level error of the frame does not move.
    pub ratio: f64,
    /// Standard error of `ratio` from its spread over row bands (includes row noise).
    pub sigma: f64,
}

/// Builds [`FrameBrightness`] from per-band sums of (frame − black) and (base − black).
pub fn brightness_from_bands(frame_sums: &[f64], base_sums: &[f64]) -> Option<FrameBrightness> {
    let f: f64 = frame_sums.iter().sum();
    let b: f64 = base_sums.iter().sum();
    if b.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let ratio = f / b;
    let bands: Vec<f64> = frame_sums.iter().zip(base_sums).filter(|(_, b)| **b > 0.0).map(|(f, b)| f / b).collect();
    let k = bands.len();
    let sigma = if k >= 2 {
        let m = bands.iter().sum::<f64>() / k as f64;
        let var = bands.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (k - 1) as f64;
        (var / k as f64).sqrt()
    } else {
        0.0
    };
    Some(FrameBrightness { ratio, sigma })
}

/// Builds [`FrameBrightness`] from per-band sums of a straight-line fit `f = a·b + δ`
/// (`[n, Σb, Σf, Σb², Σbf]` per band): the ratio is the slope `a`, so that a frame whose black level is off by `δ` (a real sensor's per-frame offset,
/// several per cent of a dark step's signal) is not taken for a brighter frame. Standard error by
/// the jackknife over bands. Where the base's levels hardly vary (a flat field: slope and offset
/// cannot be told apart), or the fitted offset is within three (jackknife) standard errors of
/// zero, the plain ratio is used.
pub fn brightness_from_fit(bands: &[[f64; 5]]) -> Option<FrameBrightness> {
    let total = bands.iter().fold([0.0; 5], |mut a, b| {
        for k in 0..5 {
            a[k] += b[k];
        }
        a
    });
    let slope = |s: &[f64; 5]| -> Option<f64> {
        let n = s[0];
        if n < 2.0 {
            return None;
        }
        let sbb = s[3] - s[1] * s[1] / n;
        let sbf = s[4] - s[1] * s[2] / n;
        let mean_b = s[1] / n;
        // The base must spread over at least a tenth of its mean level (and over 1 DN).
        (sbb > 0.0 && sbb / n > (0.1 * mean_b).powi(2).max(1.0)).then(|| sbf / sbb)
    };
    let ratio = || {
        let f: Vec<f64> = bands.iter().map(|b| b[2]).collect();
        let b: Vec<f64> = bands.iter().map(|b| b[1]).collect();
        brightness_from_bands(&f, &b)
    };
    let Some(a) = slope(&total) else {
        return ratio();
    };
    let used: Vec<usize> = (0..bands.len()).filter(|&i| bands[i][0] > 0.0).collect();
    let k = used.len();
    // The offset `δ` the slope allows for: `mean f − a · mean b`.
    let offset = |s: &[f64; 5], a: f64| (s[2] - a * s[1]) / s[0];
    let (sigma, offset_se) = if k >= 2 {
        let jack: Vec<(f64, f64)> = used
            .iter()
            .filter_map(|&i| {
                let mut s = total;
                for j in 0..5 {
                    s[j] -= bands[i][j];
                }
                slope(&s).map(|a| (a, offset(&s, a)))
            })
            .collect();
        let sd = |v: &dyn Fn(&(f64, f64)) -> f64| {
            let m = jack.iter().map(v).sum::<f64>() / jack.len().max(1) as f64;
            ((k - 1) as f64 / k as f64 * jack.iter().map(|x| (v(x) - m).powi(2)).sum::<f64>()).sqrt()
        };
        (sd(&|x| x.0), sd(&|x| x.1))
    } else {
        (0.0, f64::INFINITY)
    };
    // Without a measurable offset the plain ratio is the better estimate (its noise is a
    // fraction of the slope's, and a noisy scale would widen what it normalises).
    if offset(&total, a).abs() <= 3.0 * offset_se {
        return ratio();
    }
    Some(FrameBrightness { ratio: a, sigma })
}

/// What the tracker decided for one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftVerdict {
    /// Relative departure from the burst's running median brightness.
    pub departure: f64,
    /// Departure beyond what the noise explains.
    pub drifted: bool,
    /// Multiply (frame − black) by this to bring it to the burst's brightness (1 when not drifted).
    pub scale: f64,
}

/// Running robust brightness of one burst.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DriftTracker {
    ratios: Vec<f64>,
}

impl DriftTracker {
    /// Judges a frame against the running median of the burst (this frame included), with a
    /// threshold of `z` standard errors (from the frame itself and the burst's spread) and at least
    /// `floor` relative, and records it.
    #[cfg(test)]
    pub fn assess(&mut self, b: FrameBrightness, z: f64, floor: f64) -> DriftVerdict {
        let v = self.judge(b, z, floor);
        self.record(b);
        v
    }

    /// [`assess`](Self::assess) without recording the frame (for a frame that may be refused).
    pub fn judge(&self, b: FrameBrightness, z: f64, floor: f64) -> DriftVerdict {
        let mut ratios = self.ratios.clone();
        ratios.push(b.ratio);
        let med = median(&ratios);
        let departure = b.ratio / med - 1.0;
        let spread = if ratios.len() >= 5 {
            let dev: Vec<f64> = ratios.iter().map(|r| (r / med - 1.0).abs()).collect();
            1.4826 * median(&dev)
        } else {
            0.0
        };
        let threshold = floor.max(z * (b.sigma / med)).max(z * spread);
        let drifted = departure.abs() > threshold;
        DriftVerdict { departure, drifted, scale: if drifted { med / b.ratio } else { 1.0 } }
    }

    /// Adds a frame's brightness to the burst.
    pub fn record(&mut self, b: FrameBrightness) {
        self.ratios.push(b.ratio);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flicker_frame_is_flagged_and_scaled_back() {
        let mut t = DriftTracker::default();
        let fb = |r: f64| FrameBrightness { ratio: r, sigma: 0.0005 };
        for r in [1.0, 1.0004, 0.9997, 1.0002, 0.9999] {
            assert!(!t.assess(fb(r), 5.0, 0.001).drifted);
        }
        let v = t.assess(fb(1.03), 5.0, 0.001);
        assert!(v.drifted);
        assert!((v.scale * 1.03 - 1.0).abs() < 0.002);
        assert!(!t.assess(fb(1.0001), 5.0, 0.001).drifted);
    }

    #[test]
    fn noisy_dark_frames_are_not_flagged() {
        let mut t = DriftTracker::default();
        // 2 % noise on the ratio: a 3 % departure is within 5 σ.
        for r in [1.0, 1.02, 0.98, 1.03, 0.99] {
            assert!(!t.assess(FrameBrightness { ratio: r, sigma: 0.02 }, 5.0, 0.001).drifted);
        }
    }

    #[test]
    fn a_black_level_offset_is_not_a_brightness_drift() {
        // Base levels 5 … 60 DN above black over 16 bands; the frame adds a 0.6 DN offset
        // (12 % of the darkest level), or is 3 % brighter.
        let bands = |gain: f64, offset: f64| -> Vec<[f64; 5]> {
            (0..16)
                .map(|i| {
                    let mut s = [0.0; 5];
                    for j in 0..200 {
                        let b = 5.0 + ((i * 7 + j) % 12) as f64 * 5.0;
                        let f = gain * b + offset + 0.3 * (((i * 31 + j * 17) % 11) as f64 - 5.0) / 5.0;
                        s[0] += 1.0;
                        s[1] += b;
                        s[2] += f;
                        s[3] += b * b;
                        s[4] += b * f;
                    }
                    s
                })
                .collect()
        };
        let plain = brightness_from_fit(&bands(1.0, 0.0)).unwrap();
        let offset = brightness_from_fit(&bands(1.0, 0.6)).unwrap();
        let brighter = brightness_from_fit(&bands(1.03, 0.0)).unwrap();
        assert!((offset.ratio - plain.ratio).abs() < 0.002, "{offset:?} vs {plain:?}");
        assert!((brighter.ratio / plain.ratio - 1.03).abs() < 0.002, "{brighter:?}");
        assert!(plain.sigma > 0.0 && plain.sigma < 0.005, "{plain:?}");
        // A flat field: no spread of levels, the plain ratio.
        let flat = vec![[100.0, 1000.0, 1100.0, 10000.0, 11000.0]; 4];
        assert!((brightness_from_fit(&flat).unwrap().ratio - 1.1).abs() < 1e-12);
    }

    /// The integer sums are the floating-point ones to the last bit, on a frame whose flat,
    /// unclipped pixels mix at random with pixels that are not flat or are above the clip: a
    /// 10-bit frame with base levels on both sides of the black levels, and a 16-bit one whose
    /// values reach 65535 (products near 2³², which a sum in 32 bits, or a product formed in
    /// 16, gets wrong), each on a width that leaves a tail past the vector lanes. A sum that
    /// took a pixel's term in the wrong column's position, or dropped the tail, fails it.
    #[test]
    fn integer_sums_are_the_floating_point_sums() {
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        // (width, height, lowest base level, base levels' range, noise, black levels, clip)
        let cases = [
            (37, 1030, 40u64, 1000u64, 20i64, [64.0, 60.0, 64.0, 48.0], 900.0f32),
            (45, 600, 0, 65535, 300, [4096.0, 4000.0, 4096.0, 3072.0], 65535.0),
        ];
        for (w, h, low, range, noise, black, clip) in cases {
            let base: Vec<u16> = (0..w * h)
                .map(|_| match next() % 5 {
                    0 => NOT_FLAT,
                    _ => (low + next() % range).min(65534) as u16,
                })
                .collect();
            let frame = ndarray::Array2::from_shape_fn((h, w), |(y, x)| {
                let c = base[y * w + x];
                let n = (next() % (2 * noise as u64 + 1)) as i64 - noise;
                if c == NOT_FLAT { (next() % 65536) as u16 } else { (c as i64 + n).clamp(0, 65535) as u16 }
            });
            let frame = FrameView::from_array(&frame).expect("view");
            let tf = Transform { delta: [0.0; POSITIONS], black, scale: 1.0 };
            let int = integer_brightness_sums(&frame, &base, &tf, clip, w, h).expect("integer sums");
            let float = float_brightness_sums(&frame, &base, &tf, clip, w, h);
            assert!(int.bands.iter().map(|b| b[0]).sum::<f64>() > 1000.0);
            assert_eq!(int.bands, float.bands, "{w}×{h}");
            assert_eq!(int.frame_pos, float.frame_pos, "{w}×{h}");
            assert_eq!(int.base_pos, float.base_pos, "{w}×{h}");
        }
    }

    #[test]
    fn bands_give_ratio_and_error() {
        let b = brightness_from_bands(&[101.0, 99.0, 102.0, 98.0], &[100.0; 4]).unwrap();
        assert!((b.ratio - 1.0).abs() < 1e-12);
        assert!(b.sigma > 0.005 && b.sigma < 0.02);
        assert!(brightness_from_bands(&[1.0], &[0.0]).is_none());
    }
}
