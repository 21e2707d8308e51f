//! A small version of `tests/bench/sim_tiles.py`'s set, calibrated through the folder driver
//! with its two kinds of reference burst (issues 21 and 23): the sensor's own frames at the
//! reference ISO (what a real reference burst is, and what sim_tiles.py writes since tiles11),
//! and the ordered dither it wrote before (frame `j` of a step `floor(clean + (j + ½)/8)`: one
//! sub-DN phase for every pixel of a frame).
//!
//! The sensor (sim_tiles.py's): 8 bits, black 2.87 DN, `clip(round(clean + N(0, A·(clean −
//! black) + B)), 0, 255)` with `A` 0.019 and `B` 0.01 DN² (set 002's law: sub-DN noise, a clamp
//! at 0), clean images with a fixed pattern (DSNU 0.1 DN, PRNU 0.5 %). Steps 3.5 DN apart, each
//! 8 reference frames at ISO 100 (twice the exposure; their own noise at half the gain, `A/2`)
//! and one target frame at ISO 200; a dark burst of 16 frames a ISO.
//!
//! The truth at a step is the exact variance of `noisy − round(clean)` over the step's pixels
//! (both roundings and the clamp, per pixel, pooled), the pack's convention: a clean code stands
//! for the levels that round to it. The steps' codes are the codes whose bins hold their own
//! samples, so there the pack must follow it.

use std::path::Path;

use ndarray::Array2;
use noisecal_core::FrameMeta;
use noisecal_core::math::special::erfc;
use noisecal_core::model::layout::{CfaPattern, SensorLayout};
use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::synthesize;
use noisecal_input::calibrate::{CalibrateOptions, CalibrateReport, calibrate_path};
use noisecal_input::dng::write_dng_from_layout;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const W: usize = 128;
const H: usize = 128;
const BLACK: f64 = 2.87;
const WHITE: u16 = 255;
const A: f64 = 0.019;
const B: f64 = 0.01;
const DSNU: f64 = 0.1;
const PRNU: f64 = 0.005;
const STEP: f64 = 3.5;
const STEPS: usize = 20;
const REF_FRAMES: usize = 8;
const DARK_FRAMES: usize = 16;
/// The steps checked against the truth: 3.5 … 21 DN above black (sim_tiles.py's band near black).
const CHECKED: usize = 6;

#[derive(Clone, Copy, Debug, PartialEq)]
enum References {
    /// The sensor's own frames at ISO 100: `A/2` (half the gain), the same `B`.
    Noise,
    /// sim_tiles.py before tiles11: `floor(clean + (j + ½)/8)`.
    Ordered,
}

fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    // Box–Muller.
    let (u, v): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

fn variance(clean: f64, a: f64) -> f64 {
    a * (clean - BLACK).max(0.0) + B
}

fn noisy(clean: &Array2<f64>, a: f64, rng: &mut ChaCha8Rng) -> Array2<u16> {
    clean.mapv(|c| (c + variance(c, a).sqrt() * gaussian(rng)).round().clamp(0.0, WHITE as f64) as u16)
}

/// The exact variance of `noisy − round(clean)` pooled over the pixels of `clean`.
fn truth(clean: &Array2<f64>) -> f64 {
    truth_moments(clean).1
}

/// The exact mean and variance of `noisy − round(clean)` pooled over the pixels of `clean`.
fn truth_moments(clean: &Array2<f64>) -> (f64, f64) {
    let (mut n, mut m, mut m2) = (0.0, 0.0, 0.0);
    for &c in clean {
        let sd = variance(c, A).sqrt();
        let cdf = |t: f64| 0.5 * erfc(-(t - c) / (sd * std::f64::consts::SQRT_2));
        let r = c.round();
        for k in -8i32..=8 {
            let v = r + k as f64;
            let upper = if v >= WHITE as f64 { 1.0 } else { cdf(v + 0.5) };
            let lower = if v <= 0.0 { 0.0 } else { cdf(v - 0.5) };
            let p = if v < 0.0 || v > WHITE as f64 { 0.0 } else { upper - lower };
            n += p;
            m += p * k as f64;
            m2 += p * (k * k) as f64;
        }
    }
    let mean = m / n;
    (mean, m2 / n - mean * mean)
}

fn layout() -> SensorLayout {
    SensorLayout { width: W as u32, height: H as u32, cfa: CfaPattern::Rggb, black: [BLACK as f32; 4], white: WHITE }
}

fn write(dir: &Path, name: &str, px: &Array2<u16>, iso: u32, exposure_ns: u64) {
    let meta = FrameMeta { iso, exposure_ns, black: Some([BLACK as f32; 4]) };
    write_dng_from_layout(&dir.join(name), &layout(), &meta, "simulated", "sim_tiles references", px)
        .expect("write a DNG");
}

/// The clean image `level` DN above black, with the fixed pattern `(dsnu, prnu)`.
fn flat(level: f64, pattern: &(Array2<f64>, Array2<f64>)) -> Array2<f64> {
    Array2::from_shape_fn((H, W), |i| BLACK + pattern.0[i] + level * (1.0 + pattern.1[i]))
}

struct Run {
    refused: usize,
    normalised: usize,
    /// Per checked step: level, truth, pixel-only synthetic variance.
    steps: Vec<(f64, f64, f64)>,
    /// Per code of the checked band.
    codes: Vec<CodeRow>,
}

/// One clean code of the checked band: how the calibration's steps reached it, and what the
/// pack draws there against the truth.
#[derive(Debug)]
struct CodeRow {
    code: u16,
    /// The steps' pixels whose clean level rounds to the code.
    true_pixels: usize,
    /// The steps' pixels whose reference burst's mean rounds to it (every burst, flat or not).
    assigned: usize,
    /// The mean and variance of `noisy − round(clean)` over a clean image at the code (its
    /// fixed pattern, within the code), and of pixel-only draws on its rounded image.
    truth: (f64, f64),
    drawn: (f64, f64),
}

/// Pixel-only draws onto `round(clean)` (4 seeds): the mean and variance of `drawn − code`.
fn drawn_moments(pixel: &IsoSampler, clean: &Array2<f64>) -> (f64, f64) {
    let code = clean.mapv(|c| c.round() as u16);
    let d: Vec<f64> = (0..4)
        .flat_map(|s| {
            let out = synthesize(pixel, code.view(), 31 + s);
            out.iter().zip(&code).map(|(&o, &c)| o as f64 - c as f64).collect::<Vec<_>>()
        })
        .collect();
    let m = d.iter().sum::<f64>() / d.len() as f64;
    (m, d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / d.len() as f64)
}

fn run(kind: References) -> Run {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut rng = ChaCha8Rng::seed_from_u64(2002);
    let pattern = (
        Array2::from_shape_fn((H, W), |_| DSNU * gaussian(&mut rng)),
        Array2::from_shape_fn((H, W), |_| PRNU * gaussian(&mut rng)),
    );
    let mut ref_rng = ChaCha8Rng::seed_from_u64(2003);
    let mut true_pixels = vec![0usize; WHITE as usize + 1];
    let mut assigned = vec![0usize; WHITE as usize + 1];
    for i in 0..2 * DARK_FRAMES {
        let iso = if i < DARK_FRAMES { 100 } else { 200 };
        write(dir.path(), &format!("dark_{i:03}.dng"), &noisy(&flat(0.0, &pattern), A, &mut rng), iso, 1000);
    }
    for k in 1..=STEPS {
        let clean = flat(STEP * k as f64, &pattern);
        let ns = 40_000 * k as u64;
        let mut sum = Array2::<f64>::zeros((H, W));
        for j in 0..REF_FRAMES {
            let px = match kind {
                References::Noise => noisy(&clean, A / 2.0, &mut ref_rng),
                References::Ordered => {
                    clean.mapv(|c| (c + (j as f64 + 0.5) / REF_FRAMES as f64).floor().clamp(0.0, WHITE as f64) as u16)
                }
            };
            sum.zip_mut_with(&px, |s, &p| *s += p as f64);
            write(dir.path(), &format!("ref_{k:03}_{j}.dng"), &px, 100, 2 * ns);
        }
        for (&c, &s) in clean.iter().zip(&sum) {
            true_pixels[c.round() as usize] += 1;
            assigned[(s / REF_FRAMES as f64).round() as usize] += 1;
        }
        write(dir.path(), &format!("target_{k:03}.dng"), &noisy(&clean, A, &mut rng), 200, ns);
    }
    let (pack, report) = calibrate_path(dir.path(), &CalibrateOptions::default(), &mut |_, _| {}).expect("calibrate");
    let (refused, normalised) = brightness_verdicts(&report);
    let model = pack.iso(200).expect("ISO 200 calibrated");
    let pixel = IsoSampler::with_components(&pack, model, Components::PIXEL);
    let steps = (1..=CHECKED)
        .map(|k| {
            let level = STEP * k as f64;
            let clean = flat(level, &pattern);
            (level, truth(&clean), drawn_moments(&pixel, &clean).1)
        })
        .collect();
    let first = (BLACK + STEP).round() as u16;
    let last = (BLACK + STEP * CHECKED as f64).round() as u16;
    let codes = (first..=last)
        .map(|code| {
            let clean = flat(code as f64 - BLACK, &pattern);
            CodeRow {
                code,
                true_pixels: true_pixels[code as usize],
                assigned: assigned[code as usize],
                truth: truth_moments(&clean),
                drawn: drawn_moments(&pixel, &clean),
            }
        })
        .collect();
    Run { refused, normalised, steps, codes }
}

/// Frames refused as off their burst's brightness, and frames normalised to it.
fn brightness_verdicts(report: &CalibrateReport) -> (usize, usize) {
    for w in report.rejected.iter().chain(&report.warnings).filter(|w| w.contains("brightness")) {
        eprintln!("  {w}");
    }
    let refused = report.rejected.iter().filter(|r| r.contains("off the brightness of its burst")).count();
    let normalised = report.warnings.iter().filter(|w| w.contains("brightness off its burst")).count();
    (refused, normalised)
}

/// The lowest ratio of pixel-only variance to the truth a checked step may draw: a rule that
/// left out every pixel near a half code (branch halfcode12: 2 `σ_e` around each) kept the
/// lower-variance phases of the 3.5 and 10.5 DN steps, 0.903× and 0.922×; main and the rule of
/// `calibrate/half_code.rs` 0.975–1.027×.
const STEP_LOW: f64 = 0.95;

/// What a calibration from a set must show: no frame refused or normalised for its brightness
/// (the sensor's noise moves a frame's mean by `σ/√N`, not by a lamp's flicker), and pixel-only
/// synthesis at each checked step within [`STEP_LOW`] … 1.15× of the truth (4 × 16 384 draws:
/// the ratio's SD is about 1 %; the step's own 4 096 samples a position about 3 %). Returns
/// what failed.
fn failures(r: &Run) -> Vec<String> {
    let mut out = Vec::new();
    if (r.refused, r.normalised) != (0, 0) {
        out.push(format!(
            "{} reference frames refused and {} normalised for their brightness",
            r.refused, r.normalised
        ));
    }
    for (l, t, v) in &r.steps {
        if v / t >= 1.15 || v / t < STEP_LOW {
            out.push(format!("at the {l} DN step pixel-only draws {v:.4} DN² against the truth {t:.4}"));
        }
    }
    out
}

/// The codes of the checked band that no step reaches (fewer than 1 % of a step's pixels have a
/// clean level that rounds to them), whose pixel-only draws onto a clean image at the code are
/// off its truth: where some pixels' burst means rounded to the code, by more than 0.1 DN in
/// the mean or outside 0.85–1.15× in the variance; where none did (the bin is pooled from its
/// neighbours alone, which the half-code rule does not touch), by more than 0.25 DN or 1.25×
/// (4 × 16 384 draws: the mean's SE 0.003 DN, the ratio's SD about 1 %). Before the half-code
/// rule (`calibrate/half_code.rs`) such a code held mostly pixels whose burst mean had rounded
/// to it from the neighbouring step, one code off: codes 9, 16 and 23 drew means +0.37, +0.56,
/// +0.58 DN and code 9 1.79× the variance (fails). With the rule: +0.016, −0.029, −0.052 DN and
/// 0.994, 1.003, 1.000×; code 8, which no pixel reaches, 1.178×.
fn unreached_code_failures(r: &Run) -> Vec<String> {
    let step = W * H;
    r.codes
        .iter()
        .filter(|c| c.true_pixels * 100 < step)
        .filter(|c| {
            let (mean, ratio) = if c.assigned > 0 { (0.1, 0.85..=1.15) } else { (0.25, 0.8..=1.25) };
            (c.drawn.0 - c.truth.0).abs() > mean || !ratio.contains(&(c.drawn.1 / c.truth.1))
        })
        .map(|c| {
            format!(
                "code {} (no step reaches it; {} pixels' means rounded to it) draws mean {:+.3}, variance {:.4} against the truth {:+.3}, {:.4}",
                c.code, c.assigned, c.drawn.0, c.drawn.1, c.truth.0, c.truth.1
            )
        })
        .collect()
}

/// The sensor's own references pass, at the steps and at the codes no step reaches; the ordered dither sim_tiles.py wrote before tiles11 fails
/// both checks: it moves whole frames by up to 0.94 DN, so the 3.5 and 10.5 DN steps' brighter
/// frames are refused as off their burst's brightness (7 frames), and what is left of those
/// bursts is biased low, so their codes draw 0.85× the truth (measured: 0.855, 0.846, and 0.902
/// at 17.5 DN; the sensor's own references 0.975–1.027).
#[test]
fn reference_bursts_of_the_sensors_own_noise_are_kept_and_the_steps_follow_the_truth() {
    let mut got = Vec::new();
    let mut unreached = Vec::new();
    for kind in [References::Noise, References::Ordered] {
        let r = run(kind);
        if kind == References::Noise {
            unreached = unreached_code_failures(&r);
        }
        eprintln!("{kind:?}: {} refused, {} normalised", r.refused, r.normalised);
        for (l, t, v) in &r.steps {
            eprintln!("{kind:?}: {l:5.1} DN  truth {t:.4}  pixel-only {v:.4} ({:.3}×)", v / t);
        }
        for c in &r.codes {
            eprintln!(
                "{kind:?}: code {:3}  true {:6}  assigned {:6}  truth mean {:+.3} var {:.4}  drawn mean {:+.3} var {:.4} ({:.3}×)",
                c.code,
                c.true_pixels,
                c.assigned,
                c.truth.0,
                c.truth.1,
                c.drawn.0,
                c.drawn.1,
                c.drawn.1 / c.truth.1
            );
        }
        got.push(failures(&r));
    }
    assert!(got[0].is_empty(), "the sensor's own references: {:?}", got[0]);
    assert!(unreached.is_empty(), "codes no step reaches, the sensor's own references: {unreached:?}");
    let ordered = &got[1];
    assert!(
        ordered.iter().any(|f| f.contains("refused")) && ordered.iter().any(|f| f.contains("truth")),
        "the ordered dither's references must fail both checks: {ordered:?}"
    );
}
