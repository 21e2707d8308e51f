//! Reference pixels at the sensor's ceiling (method.md, "Calibration" 2, *Saturated reference
//! pixels*): where the reference burst saturated — a full well that fills below the white level,
//! or white itself — a pixel's clean level is the ceiling, not its brightness. At a target ISO
//! whose gain is not the reference's times the ISO ratio (or whose well does not fill) such a
//! pixel's output follows its true brightness, so `target − clean` is the scene, not noise: on
//! a 12-bit sensor whose well fills at 4 058 DN a bin at that level drew 145 000 DN² of "noise"
//! per pixel against 6 900 DN² real. Such pixels leave the flat set.
//!
//! **Per pixel.** A saturated pixel keeps only the noise behind the ceiling (the read noise after
//! a full well, nothing at white): its variance over the burst is far below what the noise law
//! of the burst gives at its level. It is *flagged* when its burst variance `s²` over `m` frames
//! is below `q·σ²(l)`, `q` the [`FALSE_POSITIVE`] quantile of `χ²ₘ₋₁/(m − 1)`: pure Gaussian noise
//! is flagged once in a hundred pixels. Integer codes add the pixels whose frames all gave one
//! code; the expected count under pure noise counts them ([`false_positive_rate`]).
//!
//! **Where flagged pixels crowd.** A burst of 2–4 frames flags only part of its saturated pixels (a 3-frame
//! burst with 8.7 DN² of read noise behind a well where the law gives 3 000 DN²: about a
//! third), and a pixel a little below the ceiling has its mean pulled down by the frames that
//! reached it. So the ceiling is found where flagged pixels crowd, over all CFA positions at
//! once (levels above black: the well and the ADC are shared): a level group (upper half of the
//! range only: a full well fills above it on every sensor this tool meets) whose flagged count
//! exceeds what pure noise gives by [`EXCESS_SIGMAS`] standard deviations and
//! [`MIN_FLAGGED`] pixels. The ceiling is the median level of the flagged pixels of such
//! groups; every flat pixel within [`MARGIN_SIGMAS`] per-frame noise SDs below it (plus the
//! flagged levels' own spread) or above it leaves the flat set. A sensor whose burst never
//! saturates keeps every pixel: the rule cannot fire, and its pack is unchanged.

use crate::math::fit::poly_eval;
use crate::math::special::ln_gamma;
use crate::model::layout::{POSITIONS, position};

/// Share of pure-noise pixels (Gaussian, continuous) the per-pixel test flags. One in a hundred
/// keeps the test's power on short bursts (3 frames, 8.7 DN² of read noise behind a well where
/// the law gives 3 000 DN²: 97 % of saturated pixels flagged, against 29 % at one in a
/// thousand); only crowds of flagged pixels count, so the false ones cost nothing.
pub const FALSE_POSITIVE: f64 = 1e-2;
/// A level group's flagged count must exceed pure noise's expectation by this many of its
/// standard deviations (Poisson) …
pub const EXCESS_SIGMAS: f64 = 6.0;
/// … and by this many pixels.
pub const MIN_FLAGGED: f64 = 10.0;
/// Levels this many per-frame noise SDs (the law's, at the ceiling) below the ceiling leave the
/// flat set too: a pixel `k` SD below a ceiling has its mean pulled down by `E[(Z − k)⁺]` SD,
/// 0.4 at the ceiling, 0.0085 at 2.
pub const MARGIN_SIGMAS: f64 = 2.0;
/// Only levels above this fraction of the range (black to white) are tested.
pub const UPPER_RANGE: f64 = 0.5;
/// Level groups over the tested range, per position.
const GROUPS: usize = 32;

/// Levels this many per-frame noise SDs below the flagged crowd (`ceiling − 2·spread`) and
/// lower are the ones the rule's noise law is fitted on: a level 3 SD below a ceiling reaches
/// it in 0.13 % of its frames, and its variance is cut by under 0.1 %.
pub const REFIT_SIGMAS: f64 = 3.0;
/// Refits of the law at most (each moves the fitted range down by the SD it reads; two settle
/// it on the random family).
const MAX_REFITS: usize = 4;

/// A burst's per-frame noise variance per position: `[c0, c1, c2]`, a polynomial in the level
/// above black.
pub type Law = [[f64; 3]; POSITIONS];

/// What the rule needs of one reference burst.
pub struct BurstView<'a, V: Fn(usize) -> f64, L: Fn(f64) -> Law> {
    /// Row-major clean levels, `not_flat` where a pixel is not flat.
    pub clean: &'a mut [u16],
    pub width: usize,
    pub not_flat: u16,
    pub frames: u32,
    pub black: [f32; POSITIONS],
    pub white: u16,
    /// A pixel's variance over the burst (unbiased, `m − 1` degrees of freedom).
    pub burst_variance: V,
    /// The burst's per-frame noise law over every level (the robust line of its frame-to-frame
    /// differences): the per-pixel test reads it.
    pub law: Law,
    /// The burst's per-frame noise law fitted over the levels below the argument (DN above
    /// black) from each level's median pixel variance, which the chart's motion does not move:
    /// the margin below the ceiling reads it.
    pub law_below: L,
}

/// What the rule did, per position.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Saturation {
    /// The lowest clean level left out (DN), `None` where no ceiling was found.
    pub cut: [Option<u16>; POSITIONS],
    /// Flat pixels left out.
    pub left_out: [u64; POSITIONS],
}

/// Where flagged pixels crowd: the ceiling (DN above black) and the robust SD of the flagged
/// levels there.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Ceiling {
    level: f64,
    spread: f64,
}

fn variance(law: &Law, pos: usize, x: f64) -> f64 {
    poly_eval(&law[pos], x).max(0.0)
}

/// Finds the ceiling (one level above black for all positions: the well and the ADC are
/// shared by the CFA's colours) and takes the flat pixels at or near it out of `view.clean`.
///
/// The ceiling is found with the law of every level (`view.law`). The margin below it is read
/// from a law fitted without the levels the ceiling cut: fitted over every level, the saturated
/// ones (whose burst variance is the read noise behind the well, or nothing) pull it down at the
/// ceiling (a tenth of the unsaturated law's variance on the random family: 0.5 SD of margin
/// where 2 are stated). So the margin's law is refitted below `ceiling − 2·spread −
/// REFIT_SIGMAS·σ(ceiling)` (σ from the refitted law, until that bound stops falling), from the
/// levels' median pixel variances (`view.law_below`): where the chart moved between frames the
/// robust line of the frame differences reads the edges (three times the noise SD at the
/// ceiling on seed 2 of the random family), and a ceiling found again with a law refitted on it
/// was a crowd of pure-noise pixels 470 DN lower and 700 DN wide, which cut the whole upper
/// half of the range.
pub fn leave_out<V: Fn(usize) -> f64, L: Fn(f64) -> Law>(view: BurstView<'_, V, L>) -> Saturation {
    let mut out = Saturation::default();
    if view.frames < 2 {
        return out;
    }
    let Some(ceiling) = find_ceiling(&view, &view.law) else {
        return out;
    };
    let sd_at = |law: &Law, x: f64| (0..POSITIONS).map(|p| variance(law, p, x)).fold(0.0, f64::max).sqrt();
    let (mut law, mut below) = (view.law, f64::INFINITY);
    for _ in 0..MAX_REFITS {
        let b = ceiling.level - 2.0 * ceiling.spread - REFIT_SIGMAS * sd_at(&law, ceiling.level);
        if b >= below {
            break;
        }
        let refit = (view.law_below)(b);
        if (0..POSITIONS).any(|p| variance(&refit, p, ceiling.level) <= 0.0) {
            break;
        }
        (law, below) = (refit, b);
    }
    let span = (0..POSITIONS).map(|p| view.white as f64 - view.black[p] as f64).fold(f64::INFINITY, f64::min).max(1.0);
    let lowest = UPPER_RANGE * span;
    for pos in 0..POSITIONS {
        let sd = variance(&law, pos, ceiling.level).sqrt();
        let cut = (view.black[pos] as f64 + ceiling.level - 2.0 * ceiling.spread - MARGIN_SIGMAS * sd)
            .floor()
            .max(view.black[pos] as f64 + lowest);
        out.cut[pos] = Some(cut.clamp(0.0, view.white as f64) as u16);
    }
    let w = view.width.max(1);
    for (y, row) in view.clean.chunks_mut(w).enumerate() {
        for (x, c) in row.iter_mut().enumerate() {
            let pos = position(y, x);
            if let Some(cut) = out.cut[pos]
                && *c != view.not_flat
                && *c >= cut
            {
                *c = view.not_flat;
                out.left_out[pos] += 1;
            }
        }
    }
    out
}

/// The ceiling where flagged pixels crowd under the noise law `law`, `None` where they
/// crowd nowhere.
fn find_ceiling<V: Fn(usize) -> f64, L: Fn(f64) -> Law>(view: &BurstView<'_, V, L>, law: &Law) -> Option<Ceiling> {
    let q = chi2_mean_quantile(view.frames - 1, FALSE_POSITIVE);
    let w = view.width.max(1);
    // Levels above black; the tested range is the upper part of the narrowest position's.
    let span = (0..POSITIONS).map(|p| view.white as f64 - view.black[p] as f64).fold(f64::INFINITY, f64::min).max(1.0);
    let lowest = UPPER_RANGE * span;
    let group = |x: f64| {
        let g = ((x - lowest) / ((1.0 - UPPER_RANGE) * span) * GROUPS as f64).floor();
        (g.max(0.0) as usize).min(GROUPS - 1)
    };
    // Per group: flagged pixels, and flagged expected under pure noise.
    let mut flagged = [0u64; GROUPS];
    let mut expected = [0f64; GROUPS];
    let mut levels: Vec<(usize, f64)> = Vec::new();
    // The law's variance and its false-positive rate at a clean level depend on the position and
    // the level alone: each is computed once, on first use (a `powf` per pixel of the upper range
    // before), the same values in the same order of additions.
    let mut at_level: [Vec<Option<(f64, f64)>>; POSITIONS] =
        std::array::from_fn(|_| vec![None; view.white as usize + 1]);
    for (y, row) in view.clean.chunks(w).enumerate() {
        for (x_col, &c) in row.iter().enumerate() {
            let pos = position(y, x_col);
            let x = c as f64 - view.black[pos] as f64;
            if c == view.not_flat || x < lowest {
                continue;
            }
            let of_level = || {
                let var = poly_eval(&law[pos], x);
                (var, false_positive_rate(view.frames, var))
            };
            let (var, rate) = match at_level[pos].get_mut(c as usize) {
                Some(Some(v)) => *v,
                Some(slot) => *slot.insert(of_level()),
                None => of_level(),
            };
            if var.is_nan() || var <= 0.0 {
                continue;
            }
            let g = group(x);
            expected[g] += rate;
            if (view.burst_variance)(y * w + x_col) < q * var {
                flagged[g] += 1;
                levels.push((g, x));
            }
        }
    }
    let crowded: Vec<bool> = (0..GROUPS)
        .map(|g| flagged[g] as f64 > expected[g] + EXCESS_SIGMAS * expected[g].sqrt() + MIN_FLAGGED)
        .collect();
    let mut at: Vec<f64> = levels.iter().filter(|(g, _)| crowded[*g]).map(|&(_, x)| x).collect();
    if at.is_empty() {
        return None;
    }
    at.sort_by(f64::total_cmp);
    let level = at[at.len() / 2];
    let mut dev: Vec<f64> = at.iter().map(|x| (x - level).abs()).collect();
    dev.sort_by(f64::total_cmp);
    Some(Ceiling { level, spread: 1.4826 * dev[dev.len() / 2] })
}

/// About the chance that a pixel of pure noise (per-frame variance `var`, `m` frames, integer
/// codes) is flagged, and not below it (an upper bound where only pixels whose codes all agree
/// can fall below the threshold): the continuous rate [`FALSE_POSITIVE`] plus the chance that
/// every frame gave the same code (`s² = 0`), `≈ (2π·var)^{−(m−1)/2} / √m` for a rounded Gaussian
/// (at most 1).
pub fn false_positive_rate(m: u32, var: f64) -> f64 {
    let m = m as f64;
    let same = (2.0 * std::f64::consts::PI * var.max(1e-9)).powf(-(m - 1.0) / 2.0) / m.sqrt();
    (FALSE_POSITIVE + same).min(1.0)
}

/// The `p` quantile of `χ²ₖ / k` (bisection on the regularized lower incomplete gamma function).
pub fn chi2_mean_quantile(k: u32, p: f64) -> f64 {
    let a = k.max(1) as f64 / 2.0;
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    while lower_gamma_regularized(a, hi * a) < p {
        hi *= 2.0;
    }
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if lower_gamma_regularized(a, mid * a) < p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// `P(a, x) = γ(a, x) / Γ(a)` by its power series (converges for every `x`; used here in the
/// lower tail, where it takes a few terms).
fn lower_gamma_regularized(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let (mut term, mut sum, mut n) = (1.0 / a, 1.0 / a, a);
    for _ in 0..10_000 {
        n += 1.0;
        term *= x / n;
        sum += term;
        if term < sum * 1e-15 {
            break;
        }
    }
    (sum.ln() - x + a * x.ln() - ln_gamma(a)).exp().min(1.0)
}

#[cfg(test)]
#[path = "tests_saturated.rs"]
mod tests;
