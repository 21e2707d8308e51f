//! The dark end follows the data and the law: on 14-bit dual-gain sensors whose variance at
//! black is small against the variance at the darkest level a chart session measures, the
//! synthetic noise variance must stay within 1.10 of the real one at every level from black
//! up, including the levels below the darkest calibrated one, at calibrated ISOs and at an ISO
//! interpolated between two, with the clean image at the reference ISO's brightness and at the
//! target's; and the pack must not lose to the plain 4 DN histogram of the same frames where that
//! histogram stands on data (method.md, *Synthesis*, "Within a bin near black" and "Against the
//! plain histogram at the dark end").
//!
//! The synthetic distribution at a clean level is computed exactly from the sampler's tables (the
//! pixel-independent model, whose PMFs hold the whole noise), clamp, lattice and the target
//! brightness's dither included; the real one from the simulator's own noise process at that
//! level (`Simulator::sample_noise_at_level`, 40 000 samples: a variance ratio's standard error
//! of about 0.7 % for Gaussian noise, more for heavy tails, whose three standard errors widen the
//! bound). At the reference brightness the real level is the reference level's distance above
//! black times the gain ratio; at the target brightness the level itself. Levels: every integer
//! code from black up over two bins, then every quarter bin up to 16 bins (the machinery:
//! `noisecal_e2e::dark_levels`).
//!
//! Before the fix (one PMF per 64 DN bin, held down to black; the test computes it too, as the
//! bin's own table at each level, and requires it to fail) the named sensor read 47.1 at worst at
//! ISO 800 and 37.0 at ISO 3200 (at black 152 DN² against the truth's 4.8), 51.6 at the
//! interpolated ISO 1600, the two random sensors 17.7–42.5; now 1.097, 1.045, 1.063 and at most
//! 1.075.

use noisecal_e2e::dark_levels::{
    calibrate, compare, darkest_levels, grey_chart, held_loses, judge, print_fitted_black,
};
use noisecal_sim::{SensorModel, SessionPlan, Simulator, random_dark_sensor, random_session};

/// The named sensor, from a small chart session: 192×128, a 16-frame reference at ISO 100 and
/// targets at ISO 800 and 3200, whole stops from −2 to +2 EV, and a dark step of 16 frames per
/// ISO (the variance at black is measured; without it the bins stay whole: printed, not judged).
/// Judged at both calibrated ISOs and at ISO 1600, interpolated between them.
#[test]
fn the_named_sensor_follows_the_law_down_to_black() {
    let sim = Simulator::new(SensorModel::dark_14bit(), grey_chart(192, 128), 2107).expect("simulator");
    let plan = SessionPlan::for_simulator(&sim, vec![800, 3200], 16).expect("plan").with_ev_steps(-2..=2);
    let darkest = darkest_levels(&sim, &plan, -2);
    eprintln!("dark_14bit: the darkest clean level per position is {darkest:.1?} DN above black");
    assert!(darkest.iter().all(|d| (15.0..45.0).contains(d)), "{darkest:?}");
    let isos = [800, 1600, 3200];
    // Without a dark step the variance at black is not identifiable from a chart whose darkest
    // patch is 25 DN up, and the bins stay whole: printed, not judged.
    let without = calibrate(&sim, &plan, false);
    judge("dark_14bit without dark frames", &compare(&sim, &without, &isos, 1), false, &[]);
    print_fitted_black(&sim, &without.pack, &[800, 3200]);
    let packs = calibrate(&sim, &plan, true);
    assert_eq!(packs.pack.bin_width, 64, "the default bins of a 14-bit sensor");
    assert!(packs.pack.iso(1600).is_none(), "ISO 1600 is interpolated");
    let results = compare(&sim, &packs, &isos, 1);
    let failures = judge("dark_14bit", &results, true, &[]);
    let held = results[2].1.iter().map(|l| l.at.held.m.var / l.at.real.var).fold(0.0, f64::max);
    assert!(held > 10.0, "one PMF per bin must fail here: {held}");
    assert!(held_loses(&results), "one PMF per bin must lose to the 4 DN plain histogram somewhere");
    assert!(failures.is_empty(), "{} failures:\n{}", failures.len(), failures.join("\n"));
    // The case is the issue's: at ISO 3200 the truth at black is a twentieth of the variance
    // 30 DN above it.
    let iso3200 = &results[2].1;
    let real_at =
        |k: i32| iso3200.iter().find(|l| l.pos == 0 && l.above_black == k).map(|l| l.at.real.var).expect("level");
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
    let mut power = Vec::new();
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
        let packs = calibrate(&sim, &plan, true);
        eprintln!("random sensor {}: {} | {}", sensor.seed, sensor.description, spec.description);
        let results = compare(&sim, &packs, &spec.target_isos, 2 + n as u64);
        // Random sensor 22 at 16 × base counts 35 DN per electron: near black its noise is a
        // comb of electron spikes whose place moves with the level, which a 64 DN bin's shape
        // cannot follow (its variance and tails can) and a 4 DN histogram can.
        let known: &[u32] = if sensor.seed == 22 { &[16 * base] } else { &[] };
        failures.extend(judge(&format!("random sensor {}", sensor.seed), &results, true, known));
        power.push(held_loses(&results));
    }
    assert!(power.iter().any(|&p| p), "one PMF per bin must lose to the 4 DN plain histogram somewhere");
    assert!(failures.is_empty(), "{} failures:\n{}", failures.len(), failures.join("\n"));
}
