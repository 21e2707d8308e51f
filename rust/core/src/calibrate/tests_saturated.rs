//! Tests of `saturated.rs` (a child module by `#[path]`, so they keep its private items). They
//! fit the margin through `flat.rs`'s median-variance line, and `flat.rs` uses `saturated.rs`:
//! kept in a file of their own so that no circle runs between the two files.

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
