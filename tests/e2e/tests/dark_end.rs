//! The dark end follows the data and the law: on 14-bit dual-gain sensors whose variance at
//! black is small against the variance at the darkest level a chart session measures, the
//! synthetic noise variance must stay within 1.10 of the real one at every level from black
//! up, including the levels below the darkest calibrated one (method.md, *Synthesis*, "Within a
//! bin near black").
//!
//! The synthetic variance at a clean level is computed exactly from the sampler's tables (the
//! pixel-independent model, whose PMFs hold the whole noise), clamp and lattice included; the
//! real one from the simulator's own noise process at that level, at the target ISO's brightness
//! (the reference level's distance above black times the gain ratio;
//! `Simulator::sample_noise_at_level`, 40 000 samples: a variance ratio's standard error of about
//! 0.7 %). Levels: every integer code from black up over two bins, then every quarter bin
//! up to 16 bins.
//!
//! Before the fix (one PMF per 64 DN bin, held down to black; the test computes it too, as the
//! bin's own table at each level, and requires it to fail) the named sensor read 47.1 at worst at
//! ISO 800 and 37.0 at ISO 3200 (at black 152 DN² against the truth's 4.8), the two random
//! sensors 17.7–42.5; now 1.097, 1.052 and at most 1.074.

use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::{BinTable, IsoSampler};
use noisecal_core::{CalibrationSession, FrameView, ModelPack, SessionConfig};
use noisecal_sim::{Chart, SensorModel, SessionPlan, Simulator, random_dark_sensor, random_session};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// The bound of the issue: synthetic / real variance within 1.10 either way.
const BOUND: f64 = 1.10;

/// Dark frames per ISO of a session's dark step.
const DARK_FRAMES: u64 = 16;

/// Samples of the real noise per level.
const REAL_SAMPLES: usize = 40_000;

/// Exact variance of `finish(level + n) − level` with `n` drawn from `t`.
fn synthetic_variance(s: &IsoSampler, t: &BinTable, pos: usize, level: u16) -> f64 {
    let (mut m1, mut m2) = (0.0, 0.0);
    for i in 0..t.len() {
        let n = t.first() + i as i32;
        let p = t.prob(n);
        if p == 0.0 {
            continue;
        }
        let d = s.finish(pos, level as i32 + n, false) as f64 - level as f64;
        m1 += p * d;
        m2 += p * d * d;
    }
    m2 - m1 * m1
}

/// One level's comparison.
struct Level {
    pos: usize,
    above_black: i32,
    synthetic: f64,
    /// What one PMF per bin gives there (the bin's own table, as before the levels near black
    /// were split): the test's power.
    held: f64,
    real: f64,
}

impl Level {
    fn ratio(&self) -> f64 {
        self.synthetic / self.real
    }
}

/// Synthetic against real variance at every level of the dark end, at every calibrated target
/// ISO of `pack`.
fn compare(sim: &Simulator, pack: &ModelPack, isos: &[u32], seed: u64) -> Vec<(u32, Vec<Level>)> {
    let bw = pack.bin_width as i32;
    let mut offsets: Vec<i32> = (0..=2 * bw).collect();
    offsets.extend((8..=64).map(|q| q * bw / 4).filter(|&k| k > 2 * bw));
    isos.iter()
        .map(|&iso| {
            let model = pack.iso(iso).expect("calibrated ISO");
            let s = IsoSampler::with_components(pack, model, Components::PIXEL);
            let jobs: Vec<(usize, i32)> = (0..4).flat_map(|p| offsets.iter().map(move |&k| (p, k))).collect();
            let levels = jobs
                .par_iter()
                .map(|&(pos, k)| {
                    let code = pack.layout.black[pos].ceil() as i32 + k;
                    let mut rng =
                        ChaCha8Rng::seed_from_u64(seed ^ ((iso as u64) << 32) ^ ((pos as u64) << 24) ^ k as u64);
                    // The pack's clean levels are at the reference ISO's brightness; the target's
                    // level is `g` times as far above black (the gain ratio: a gain not ∝ ISO;
                    // method.md, *Synthesis*).
                    let black = pack.layout.black[pos] as f64;
                    let level = (black + model.gain_ratio[pos] * (code as f64 - black)) as f32;
                    let real = sim.sample_noise_at_level(iso, level, pos, REAL_SAMPLES, &mut rng).expect("truth");
                    let n = real.len() as f64;
                    let m = real.iter().map(|&v| v as f64).sum::<f64>() / n;
                    let var = real.iter().map(|&v| (v as f64 - m).powi(2)).sum::<f64>() / (n - 1.0);
                    let bin = &model.positions[pos].bins[pack.binning().bin(pos, code as f32)];
                    Level {
                        pos,
                        above_black: k,
                        synthetic: synthetic_variance(&s, s.table(pos, code as u16), pos, code as u16),
                        held: synthetic_variance(&s, &BinTable::new(bin), pos, code as u16),
                        real: var,
                    }
                })
                .collect();
            (iso, levels)
        })
        .collect()
}

/// Calibrates `plan` on `sim` as the CLI would, then (when `dark`) a dark step of
/// [`DARK_FRAMES`] per ISO at the shortest exposure the ISO uses.
fn calibrate(sim: &Simulator, plan: &SessionPlan, dark: bool) -> ModelPack {
    let mut config = SessionConfig::new(plan.reference_iso);
    config.make = "sim".into();
    let mut session = CalibrationSession::new(sim.layout(), config).expect("session");
    plan.feed(sim, &mut session, |_, _| ()).expect("capture");
    if dark {
        session.begin_dark().expect("dark step");
        for (iso, exposure) in plan.dark_settings() {
            for k in 0..DARK_FRAMES {
                let (px, meta) = sim.capture_dark(iso, exposure, k).expect("dark capture");
                session.push_frame(&FrameView::from_array(&px).expect("view"), &meta).expect("dark frame accepted");
            }
        }
    }
    session.finish().expect("a pack")
}

/// Prints the comparison and returns the levels beyond the bound.
fn judge(name: &str, results: &[(u32, Vec<Level>)]) -> Vec<String> {
    let mut failures = Vec::new();
    for (iso, levels) in results {
        let worst = levels.iter().map(|l| l.ratio().ln().abs()).fold(0.0, f64::max).exp();
        let at_black: Vec<String> =
            levels.iter().filter(|l| l.above_black == 0).map(|l| format!("{:.1}/{:.1}", l.synthetic, l.real)).collect();
        let held = levels.iter().map(|l| (l.held / l.real).ln().abs()).fold(0.0, f64::max).exp();
        eprintln!(
            "{name} ISO {iso}: worst ratio {worst:.3} (one PMF per bin: {held:.3}); at black (synthetic/real DN², \
             per position) {}",
            at_black.join(", ")
        );
        for l in levels.iter().filter(|l| l.pos == 0 && (l.above_black % 8 == 0 || l.above_black < 8)) {
            eprintln!(
                "  +{:>4} DN: {:8.2} / {:8.2} = {:.3} (one PMF per bin {:.3})",
                l.above_black,
                l.synthetic,
                l.real,
                l.ratio(),
                l.held / l.real
            );
        }
        for l in levels.iter().filter(|l| !(1.0 / BOUND..=BOUND).contains(&l.ratio())) {
            failures.push(format!(
                "{name} ISO {iso} position {} +{} DN: synthetic {:.2} / real {:.2} DN² = {:.3}",
                l.pos,
                l.above_black,
                l.synthetic,
                l.real,
                l.ratio()
            ));
        }
    }
    failures
}

/// A chart of 24 neutral patches from reflectance 0.9 down to 0.03 (log-spaced, the
/// ColorChecker's white to its black) on the ColorChecker's layout and lamp: every CFA position
/// sees its darkest patch at about a thirtieth of its brightest, so at −2 EV the darkest
/// calibrated level is 20–40 DN above black at every position (a colour chart's saturated
/// patches reach within a few DN of black in one channel).
fn grey_chart(width: u32, height: u32) -> Chart {
    let mut chart = Chart::color_checker(width, height).expect("chart");
    chart.patches = (0..24).map(|i| [0.9f32 * (0.03f32 / 0.9).powf(i as f32 / 23.0); 3]).collect();
    chart
}

/// The darkest clean level (DN above black) of a session's darkest step, per CFA position.
fn darkest_levels(sim: &Simulator, plan: &SessionPlan, step: i32) -> [f32; 4] {
    let clean = sim.clean_expected(plan.reference_iso, plan.exposure_ns(step, plan.reference_iso)).expect("clean");
    let black = sim.layout().black;
    std::array::from_fn(|p| {
        clean
            .indexed_iter()
            .filter(|((y, x), _)| (y % 2) * 2 + x % 2 == p)
            .map(|(_, &v)| v - black[p])
            .fold(f32::INFINITY, f32::min)
    })
}

/// The named sensor, from a small chart session: 192×128, a 16-frame reference at ISO 100 and
/// targets at ISO 800 and 3200, whole stops from −2 to +2 EV, and a dark step of 16 frames per
/// ISO (the variance at black is measured; without it the bins stay whole: printed, not judged).
#[test]
fn the_named_sensor_follows_the_law_down_to_black() {
    let sim = Simulator::new(SensorModel::dark_14bit(), grey_chart(192, 128), 2107).expect("simulator");
    let plan = SessionPlan::for_simulator(&sim, vec![800, 3200], 16).expect("plan").with_ev_steps(-2..=2);
    let darkest = darkest_levels(&sim, &plan, -2);
    eprintln!("dark_14bit: the darkest clean level per position is {darkest:.1?} DN above black");
    assert!(darkest.iter().all(|d| (15.0..45.0).contains(d)), "{darkest:?}");
    // Without a dark step the variance at black is not identifiable from a chart whose darkest
    // patch is 25 DN up, and the bins stay whole: printed, not judged.
    let without = calibrate(&sim, &plan, false);
    judge("dark_14bit without dark frames", &compare(&sim, &without, &[800, 3200], 1));
    let pack = calibrate(&sim, &plan, true);
    assert_eq!(pack.bin_width, 64, "the default bins of a 14-bit sensor");
    let results = compare(&sim, &pack, &[800, 3200], 1);
    let failures = judge("dark_14bit", &results);
    let held = results[1].1.iter().map(|l| l.held / l.real).fold(0.0, f64::max);
    assert!(held > 10.0, "one PMF per bin must fail here: {held}");
    assert!(failures.is_empty(), "{} levels beyond ×{BOUND}:\n{}", failures.len(), failures.join("\n"));
    // The case is the issue's: at ISO 3200 the truth at black is a twentieth of the variance
    // 30 DN above it.
    let iso3200 = &results[1].1;
    let real_at = |k: i32| iso3200.iter().find(|l| l.pos == 0 && l.above_black == k).map(|l| l.real).expect("level");
    assert!(real_at(0) < 0.07 * real_at(30), "{} vs {}", real_at(0), real_at(30));
}

/// Two members of the random family with the same property (14 bits, high conversion gain at
/// 16 × base, the variance at black under a fifth of that 30 DN above it, the floor out of
/// reach), their black level reported exactly, each from the named sensor's session shape
/// (192×128 on the grey chart, targets at 4 and 16 × base, whole stops from −2 to +2 EV, a dark
/// step) with its own random session's bursts (at least 8 frames).
#[test]
fn random_dark_sensors_follow_the_law_down_to_black() {
    let mut failures = Vec::new();
    for n in 0..2 {
        let mut sensor = random_dark_sensor(n, 16);
        // Its black level reported as the true dark level (the family draws an offset of up to
        // ±2.5 DN at 14 bits): an offset moves the truth near black by the shot slope × the
        // offset, which nothing the calibration measures shows (method.md, *Known limits*).
        sensor.model.bias_dn = [0.0; 4];
        let mut spec = random_session(sensor.seed, &sensor.model);
        let base = sensor.model.base_iso;
        spec.target_isos = vec![4 * base, 16 * base];
        spec.dense = false;
        spec.ev_steps_per_stop = 1;
        spec.ev_steps = (-2..=2).collect();
        spec.frames_per_burst = spec.frames_per_burst.max(8);
        (spec.width, spec.height) = (192, 128);
        let chart = grey_chart(spec.width, spec.height);
        let sim = Simulator::new(sensor.model.clone(), chart, sensor.seed ^ 0xDA4C).expect("simulator");
        let plan = spec.plan(&sim).expect("plan");
        eprintln!("darkest clean level per position {:.1?} DN above black", darkest_levels(&sim, &plan, -2));
        let pack = calibrate(&sim, &plan, true);
        eprintln!("random sensor {}: {} | {}", sensor.seed, sensor.description, spec.description);
        let results = compare(&sim, &pack, &spec.target_isos, 2 + n as u64);
        failures.extend(judge(&format!("random sensor {}", sensor.seed), &results));
    }
    assert!(failures.is_empty(), "{} levels beyond ×{BOUND}:\n{}", failures.len(), failures.join("\n"));
}
