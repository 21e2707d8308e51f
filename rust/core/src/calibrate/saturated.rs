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
    for (i, c) in view.clean.iter_mut().enumerate() {
        let pos = position(i / w, i % w);
        if let Some(cut) = out.cut[pos]
            && *c != view.not_flat
            && *c >= cut
        {
            *c = view.not_flat;
            out.left_out[pos] += 1;
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
    for (i, &c) in view.clean.iter().enumerate() {
        let pos = position(i / w, i % w);
        let x = c as f64 - view.black[pos] as f64;
        if c == view.not_flat || x < lowest {
            continue;
        }
        let var = poly_eval(&law[pos], x);
        if var.is_nan() || var <= 0.0 {
            continue;
        }
        let g = group(x);
        expected[g] += false_positive_rate(view.frames, var);
        if (view.burst_variance)(i) < q * var {
            flagged[g] += 1;
            levels.push((g, x));
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
mod tests {
    use super::*;
    use crate::calibrate::flat::{GROUPS as FLAT_GROUPS, Groups, median_variance_fits_below};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn chi2_quantiles_match_the_tables() {
        // χ²ₖ's 0.1 % points (tables): k = 1: 1.571e-6, 2: 0.002001, 5: 0.2102, 15: 3.483.
        for (k, table) in [(1u32, 1.571e-6), (2, 0.002_001), (5, 0.2102), (15, 3.483)] {
            let q = chi2_mean_quantile(k, 1e-3) * k as f64;
            assert!((q / table - 1.0).abs() < 2e-3, "χ²_{k}: {q:e} against {table:e}");
        }
    }

    /// One burst of `m` frames per pixel over a `w × h` image: `truth(y, x)` gives the pixel's
    /// true level above black (and `None` for a pixel at a ceiling `Some(ceiling, read var)`),
    /// the noise variance is `law(level)`, codes are rounded and clipped at `white`.
    struct Burst {
        clean: Vec<u16>,
        var: Vec<f64>,
    }

    fn burst(
        w: usize,
        h: usize,
        m: u32,
        level: impl Fn(usize, usize) -> f64,
        law: impl Fn(f64) -> f64,
        well: Option<(f64, f64)>,
        white: u16,
        seed: u64,
    ) -> Burst {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let unit = Normal::new(0.0, 1.0).expect("normal");
        let (mut clean, mut var) = (Vec::with_capacity(w * h), Vec::with_capacity(w * h));
        for y in 0..h {
            for x in 0..w {
                let l = level(y, x);
                let v: Vec<f64> = (0..m)
                    .map(|_| {
                        let shot = l + law(l).sqrt() * unit.sample(&mut rng);
                        let out = match well {
                            Some((top, read)) if shot >= top => top + read.sqrt() * unit.sample(&mut rng),
                            _ => shot,
                        };
                        (BLACK + out).round().clamp(0.0, white as f64)
                    })
                    .collect();
                let mean = v.iter().sum::<f64>() / m as f64;
                clean.push(mean.round() as u16);
                var.push(v.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / (m - 1) as f64);
            }
        }
        Burst { clean, var }
    }

    const BLACK: f64 = 64.0;

    /// The burst's per-frame noise law over every level, as a line through the pixels' mean
    /// burst variance per level group (64 over the range, those with 64 pixels or more, weighted
    /// by their count): what the per-pixel flags read (flat.rs reads the frame differences'
    /// robust line, which the saturated levels pull down alike).
    fn fitted_law(b: &Burst, white: u16) -> Law {
        const G: usize = 64;
        let span = white as f64 - BLACK;
        let mut acc = [[0f64; 2]; G];
        for (c, v) in b.clean.iter().zip(&b.var) {
            let g = (((*c as f64 - BLACK) / span * G as f64).floor().max(0.0) as usize).min(G - 1);
            acc[g][0] += 1.0;
            acc[g][1] += v;
        }
        let (mut x, mut y, mut wt) = (Vec::new(), Vec::new(), Vec::new());
        for (g, [n, s]) in acc.iter().enumerate() {
            if *n >= 64.0 {
                x.push((g as f64 + 0.5) / G as f64 * span);
                y.push(s / n);
                wt.push(*n);
            }
        }
        let mut c = if x.is_empty() { vec![0.0] } else { crate::math::fit::nn_poly_fit(&x, &y, &wt, 1) };
        c.resize(3, 0.0);
        [[c[0], c[1], c[2]]; POSITIONS]
    }

    /// The margin's law as `flat.rs` fits it ([`median_variance_fits_below`]): per position and
    /// level group the median burst variance over the median of `χ²ₖ/k` (Wilson–Hilferty), from
    /// groups of 32 pixels or more.
    fn median_law(b: &Burst, w: usize, m: u32, white: u16, below: f64) -> Law {
        let groups = Groups { black: [BLACK as f32; POSITIONS], white };
        let mut vars = vec![Vec::new(); POSITIONS * FLAT_GROUPS];
        for (i, (c, v)) in b.clean.iter().zip(&b.var).enumerate() {
            let pos = position(i / w, i % w);
            vars[pos * FLAT_GROUPS + groups.group(pos, *c as f32)].push(*v);
        }
        let k = (m - 1) as f64;
        let factor = (1.0 - 2.0 / (9.0 * k)).powi(3);
        let pixels: Vec<usize> = vars.iter().map(Vec::len).collect();
        let medians: Vec<f64> = vars
            .iter_mut()
            .map(|v| {
                if v.len() < 32 {
                    return f64::NAN;
                }
                let mid = v.len() / 2;
                let (_, med, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
                *med / factor
            })
            .collect();
        median_variance_fits_below(&medians, &pixels, &groups, below)
    }

    /// The rule on burst `b` with the law fitted from its own pixels (`fitted_law`), as the flat
    /// test runs it.
    fn run(b: &mut Burst, w: usize, m: u32, white: u16) -> Saturation {
        let var = b.var.clone();
        let fit = Burst { clean: b.clean.clone(), var: b.var.clone() };
        leave_out(BurstView {
            clean: &mut b.clean,
            width: w,
            not_flat: u16::MAX,
            frames: m,
            black: [BLACK as f32; POSITIONS],
            white,
            burst_variance: move |i| var[i],
            law: fitted_law(&fit, white),
            law_below: move |below| median_law(&fit, w, m, white, below),
        })
    }

    #[test]
    fn pure_noise_is_flagged_at_the_stated_rate_and_finds_no_ceiling() {
        // Levels spread over the upper half of a 12-bit range; a bright sensor (1 e⁻/DN) and a
        // dim one whose integer codes often repeat (0.05 DN² per DN, 2 frames: a third of the
        // pixels have two equal codes at the bottom of the range).
        let (w, h) = (512, 256);
        for (m, slope) in [(2u32, 1.0), (2, 0.01), (3, 1.0), (3, 0.01), (8, 0.01)] {
            let law = move |l: f64| 4.0 + slope * l;
            // Up to 3 700 DN above black: 5 SD below white, where no frame clips.
            let level = |y: usize, x: usize| 2100.0 + ((y * w + x) % 1600) as f64;
            let mut b = burst(w, h, m, level, law, None, 4095, m as u64);
            let q = chi2_mean_quantile(m - 1, FALSE_POSITIVE);
            let (mut flagged, mut expected) = (0.0, 0.0);
            for (c, v) in b.clean.iter().zip(&b.var) {
                let l = *c as f64 - BLACK;
                flagged += f64::from(u8::from(*v < q * law(l)));
                expected += false_positive_rate(m, law(l));
            }
            // Never above the stated rate (6 SD and 25 % over it); where `q·σ²` is a few DN²
            // (codes fine against the threshold) at it within 25 %. Where `q·σ²` is under a DN²
            // only pixels whose codes all agree can be flagged, so the stated rate (which adds
            // the continuous 1 % to them) is an upper bound.
            assert!(
                flagged < expected + 6.0 * expected.sqrt() + 0.25 * expected,
                "m = {m}, slope {slope}: {flagged} flagged, {expected:.0} expected"
            );
            if q * law(2100.0) >= 3.0 {
                assert!(
                    flagged > expected - 6.0 * expected.sqrt() - 0.25 * expected,
                    "m = {m}, slope {slope}: {flagged} flagged, {expected:.0} expected"
                );
            }
            let before = b.clean.clone();
            let s = run(&mut b, w, m, 4095);
            assert_eq!(s.cut, [None; POSITIONS], "m = {m}, slope {slope}: a ceiling in pure noise");
            assert_eq!(b.clean, before);
        }
    }

    #[test]
    fn a_full_well_below_white_is_found_from_a_short_burst() {
        // 12-bit, the well fills 3 810 DN above black (4 058 DN, below white at 4 095), shot
        // noise 1 DN² per DN, 8.7 DN² of read noise behind the well; levels from 2 000 DN up to
        // twice the well. 3- and 6-frame bursts.
        let (w, h) = (256, 128);
        let well = 3810.0;
        let law = |l: f64| 8.7 + l;
        for m in [2u32, 3, 6] {
            let level = |y: usize, x: usize| 2000.0 + ((y * w + x) * 7 % 5600) as f64;
            let mut b = burst(w, h, m, level, law, Some((well, 8.7)), 4095, 10 + m as u64);
            let truth: Vec<f64> = (0..h).flat_map(|y| (0..w).map(move |x| level(y, x))).collect();
            let s = run(&mut b, w, m, 4095);
            let sd = law(well).sqrt();
            for cut in s.cut {
                let cut = cut.expect("a ceiling") as f64 - BLACK;
                // 2 SD of shot noise below the well, within 3 DN.
                assert!((cut - (well - 2.0 * sd)).abs() < 3.0 + 0.2 * sd, "m = {m}: cut {cut:.0}");
            }
            // Every pixel whose true level is at or above the well has left; of those whose clean
            // level cannot reach the cut (4 SD of the mean of `m` frames below it), none.
            let (mut kept_above, mut left_below, mut below) = (0, 0, 0);
            for (c, &t) in b.clean.iter().zip(&truth) {
                if t >= well && *c != u16::MAX {
                    kept_above += 1;
                }
                if t < well - (2.0 + 4.0 / (m as f64).sqrt()) * sd - 3.0 {
                    below += 1;
                    left_below += usize::from(*c == u16::MAX);
                }
            }
            assert_eq!(kept_above, 0, "m = {m}: saturated pixels kept");
            assert_eq!(left_below, 0, "m = {m}: {left_below} of {below} unsaturated pixels left out");
        }
    }

    #[test]
    fn pixels_at_white_leave_too() {
        // 10-bit, the ADC clips at white (1 023) before the well: codes there do not move.
        let (w, h) = (128, 96);
        let law = |l: f64| 0.5 + 0.3 * l;
        let level = |y: usize, x: usize| 500.0 + ((y * w + x) * 3 % 900) as f64;
        let mut b = burst(w, h, 4, level, law, None, 1023, 5);
        let s = run(&mut b, w, 4, 1023);
        for cut in s.cut {
            let cut = cut.expect("a ceiling");
            assert!((980..1023).contains(&cut), "cut {cut}");
        }
        assert!(b.clean.iter().all(|&c| c == u16::MAX || c < 1023));
    }
}
