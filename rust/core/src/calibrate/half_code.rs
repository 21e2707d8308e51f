//! Flat pixels whose clean code is uncertain at sub-DN noise (method.md, "Selection by the
//! clean image", issue 21).
//!
//! The clean code is `round(mean)` of an M-frame burst, whose error has the SD `σ_e`. Where the
//! noise is sub-DN, `σ_e` is a tenth of a DN or two, and a pixel whose mean lies near a half
//! code is rounded to the other code with a probability up to one half: it lands there with a
//! sample one whole code off, and on a ladder of flat steps the codes between the steps hold
//! little else. The selection correction cannot see a rounding (its kernel is at least 0.5 DN
//! wide over whole codes). Such pixels leave the flat set: a pixel whose mean is within
//! [`HALF_CODE_SES`] standard errors of a half code.
//!
//! With the means spread evenly over a code the rule leaves out `2·K·σ_e` of the pixels
//! (K = [`HALF_CODE_SES`]); of those, `(2·K − 0.78)·σ_e` of all had the right code (false
//! exclusions: the band's wrong codes are `2·σ_e·∫₀^K Φ(−u) du`, `0.78·σ_e` at K = 2), and the
//! wrong codes kept fall from `2·σ_e·∫₀^∞ Φ(−u) du = 0.80·σ_e` to `2·σ_e·∫_K^∞ Φ(−u) du =
//! 0.017·σ_e` of the pixels (flat prior). The rule applies where the per-frame noise variance
//! is below [`SUB_DN_VARIANCE`] and `σ_e` at most [`MAX_MEAN_SD`]: where the mean's error is a
//! sizeable part of a code, wrong codes are not near the half codes only, and the band would
//! take a whole code (a random-family sensor with per-frame variance 0.8–1 DN² at 8 frames,
//! `σ_e` 0.3 DN: a band 1.2 DN wide). Elsewhere nothing changes.

use crate::model::layout::{POSITIONS, position};

/// How many standard errors of the mean a kept pixel's mean must be from a half code.
pub(crate) const HALF_CODE_SES: f64 = 2.0;

/// The per-frame noise variance (DN²) from which on a level's codes are left as they are: the
/// rule is for sub-DN noise only.
pub(crate) const SUB_DN_VARIANCE: f64 = 1.0;

/// The largest SD of the clean image's error (DN) at which the rule applies: its band then
/// leaves at least a fifth of a code (`1 − 2·K·0.2`).
pub(crate) const MAX_MEAN_SD: f64 = 0.2;

/// The half-width (DN) of the band around each half code whose pixels leave the flat set, for a
/// level whose clean image's error has the variance `mean_variance` (of an `frames`-frame
/// burst): [`HALF_CODE_SES`] standard errors where the per-frame noise is sub-DN and the
/// error's SD at most [`MAX_MEAN_SD`], else 0.
pub(crate) fn band(mean_variance: f64, frames: u32) -> f64 {
    let per_frame = mean_variance * frames as f64;
    let applies =
        frames >= 2 && per_frame < SUB_DN_VARIANCE && mean_variance > 0.0 && mean_variance <= MAX_MEAN_SD * MAX_MEAN_SD;
    if applies { HALF_CODE_SES * mean_variance.sqrt() } else { 0.0 }
}

/// Leaves out of `clean` (row-major, `width` wide, `not_flat` where not flat) the flat pixels
/// whose burst mean `sum / frames` is within `bands[pos][level]` DN of a half code of their
/// level (below it unless the level is 0, above it unless it is `white`). Returns the pixels
/// left out per position.
pub(crate) fn leave_out(
    clean: &mut [u16],
    sum: &[u32],
    width: usize,
    frames: u32,
    white: u16,
    not_flat: u16,
    bands: &[Vec<f64>; POSITIONS],
) -> [u64; POSITIONS] {
    let mut left = [0u64; POSITIONS];
    if frames < 2 || width == 0 || bands.iter().all(|b| b.iter().all(|&x| x <= 0.0)) {
        return left;
    }
    let m = frames as f64;
    for (i, (c, &s)) in clean.iter_mut().zip(sum).enumerate() {
        if *c == not_flat {
            continue;
        }
        let pos = position(i / width, i % width);
        let b = bands[pos].get(*c as usize).copied().unwrap_or(0.0);
        if b <= 0.0 {
            continue;
        }
        let mean = s as f64 / m;
        let level = *c as f64;
        let below = if *c > 0 { mean - (level - 0.5) } else { f64::INFINITY };
        let above = if *c < white { (level + 0.5) - mean } else { f64::INFINITY };
        if below.min(above) < b {
            *c = not_flat;
            left[pos] += 1;
        }
    }
    left
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::special::erfc;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
        let (u, v): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }

    /// The band is zero where the noise is 1 DN or more (nothing changes there), where the
    /// mean's error passes [`MAX_MEAN_SD`], and for a one-frame burst; K standard errors of the
    /// mean elsewhere.
    #[test]
    fn band_only_at_sub_dn_noise() {
        assert_eq!(band(1.0 / 8.0, 8), 0.0);
        assert_eq!(band(4.0 / 16.0, 16), 0.0);
        assert_eq!(band(0.3, 1), 0.0);
        assert_eq!(band(0.0, 8), 0.0);
        // Sub-DN noise, but the mean's error a third of a code.
        assert_eq!(band(0.9 / 8.0, 8), 0.0);
        assert!((band(0.25 / 8.0, 8) - HALF_CODE_SES * (0.25f64 / 8.0).sqrt()).abs() < 1e-12);
    }

    /// `∫_k^∞ Φ(−u) du = φ(k) − k·Φ(−k)`.
    fn phi_tail(k: f64) -> f64 {
        (-k * k / 2.0).exp() / std::f64::consts::TAU.sqrt() - k * 0.5 * erfc(k / std::f64::consts::SQRT_2)
    }

    /// Means spread evenly over the codes, a 64-frame burst with σ 0.4 DN (the means' error
    /// `σ_e` is that of rounded frames, `√((σ² + 1/12)/M)` = 0.062 DN, as the flat test
    /// measures it from frame differences; 64 frames put the means on a lattice of 1/64 DN,
    /// fine against the band): the rule leaves out `2·K·σ_e` of the pixels (within 20 %: the
    /// sums of rounded frames are not quite Gaussian, 0.88× in numpy), and of the pixels kept
    /// within a factor 2 of `2·σ_e·∫_K^∞ Φ(−u) du / (1 − 2·K·σ_e)` have a code that is not
    /// their clean level's (0.14 %; 1.65× in numpy; without the rule `0.80·σ_e`, 4.9 %, checked
    /// within 10 %). A band of one standard error keeps 10× the wrong codes; a rule that
    /// measured the distance from the code rather than the half code leaves out as many but
    /// keeps the wrong codes; one that used σ rather than σ_e leaves out every pixel.
    #[test]
    fn leaves_out_the_uncertain_codes_and_keeps_few_wrong_ones() {
        let (frames, sd, n) = (64u32, 0.4f64, 400_000usize);
        let se = ((sd * sd + 1.0 / 12.0) / frames as f64).sqrt();
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let truth: Vec<f64> = (0..n).map(|_| 20.0 + 10.0 * rng.random::<f64>()).collect();
        let sums: Vec<u32> =
            truth.iter().map(|&c| (0..frames).map(|_| (c + sd * gaussian(&mut rng)).round() as u32).sum()).collect();
        let mut clean: Vec<u16> = sums.iter().map(|&s| (s as f64 / frames as f64).round() as u16).collect();
        let wrong_before = clean.iter().zip(&truth).filter(|(c, t)| **c as f64 != t.round()).count() as f64 / n as f64;
        let b = band(se * se, frames);
        let bands: [Vec<f64>; POSITIONS] = std::array::from_fn(|_| vec![b; 256]);
        let left: u64 = leave_out(&mut clean, &sums, 100, frames, 255, u16::MAX, &bands).iter().sum();
        let frac = left as f64 / n as f64;
        assert!((frac / (2.0 * b) - 1.0).abs() < 0.2, "left out {frac:.4}, expected {:.4}", 2.0 * b);
        let kept: Vec<(u16, f64)> =
            clean.iter().zip(&truth).filter(|(c, _)| **c != u16::MAX).map(|(c, t)| (*c, *t)).collect();
        let wrong = kept.iter().filter(|(c, t)| *c as f64 != t.round()).count() as f64 / kept.len() as f64;
        let expected_before = 2.0 * se * phi_tail(0.0);
        assert!(
            (wrong_before / expected_before - 1.0).abs() < 0.1,
            "wrong codes {wrong_before:.4} vs {expected_before:.4}"
        );
        let expected = 2.0 * se * phi_tail(HALF_CODE_SES) / (1.0 - 2.0 * b);
        assert!(
            wrong > 0.5 * expected && wrong < 2.0 * expected,
            "wrong codes kept {wrong:.5}, expected {expected:.5}"
        );
    }
}
