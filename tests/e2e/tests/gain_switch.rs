//! Conversion-gain switches called from the data, judged against the random family's truth
//! (method.md, *ISO interpolation*, "Conversion-gain switches").
//!
//! - **Calls** (`family_switch_calls`): the family's 24 sensors, each calibrated from its own
//!   random session plus a dark step (`noisecal_e2e::dark_levels::DARK_FRAMES` frames per ISO). Every gap between two
//!   neighbouring calibrated ISOs is called switch / no switch / undetermined, with the dark
//!   step's variance at black and, from the same pack, from the chart's intercepts alone; the
//!   truth is whether the simulator's conversion gain differs across the gap. A wrong call
//!   (a switch where there is none, or "no switch" across a real one) is a failure.
//! - **Interpolation** (`dual_gain_interpolation_follows_the_truth`): three dual-gain family
//!   sensors (random 22 among them) calibrated at 4, 16 and 32 × base with a dark step and
//!   interpolated between: beside the switch (both neighbours on one conversion gain) the
//!   synthetic variance must be within 1.10 of the truth at every level from black up
//!   (`noisecal_e2e::dark_levels`); inside a switch's gap the plan must say so.

use noisecal_core::ModelPack;
use noisecal_core::derive::gain_switch::{CalibratedLaw, GapCall, calibrated_laws, gaps};
use noisecal_core::derive::interp;
use noisecal_core::resolve::{ModelKind, origin_text, resolve_model};
use noisecal_e2e::dark_levels::{BOUND, Level, Packs, calibrate_with, compare, grey_chart};
use noisecal_sim::{SensorModel, Simulator, random_dark_sensor, random_sensor, random_session};
use rayon::prelude::*;

/// Sensors of the family judged (those of `random_sensors.rs`).
const SENSORS: u64 = 24;

/// Whether the sensor's conversion gain differs between two ISOs.
fn truth_switch(model: &SensorModel, below: u32, above: u32) -> bool {
    let hcg = |iso: u32| model.at_iso(iso).expect("ISO").high_conversion_gain;
    hcg(below) != hcg(above)
}

/// Tallies of one way of reading the laws over the family.
#[derive(Debug, Default, Clone, Copy)]
struct Tally {
    gaps: usize,
    switches: usize,
    /// Right calls: switch across a switch, no switch across none.
    right: usize,
    /// A switch called where the conversion gain does not change.
    false_switch: usize,
    /// "No switch" called across a real switch.
    missed: usize,
    undetermined: usize,
    /// Real switches called.
    found: usize,
}

impl Tally {
    fn add(&mut self, truth: bool, call: &GapCall) {
        self.gaps += 1;
        self.switches += truth as usize;
        match (truth, call) {
            (true, GapCall::Switch(_)) => {
                self.right += 1;
                self.found += 1;
            }
            (false, GapCall::NoSwitch) => self.right += 1,
            (false, GapCall::Switch(_)) => self.false_switch += 1,
            (true, GapCall::NoSwitch) => self.missed += 1,
            (_, GapCall::Undetermined) => self.undetermined += 1,
        }
    }
}

fn call_text(c: &GapCall) -> String {
    match c {
        GapCall::NoSwitch => "none".into(),
        GapCall::Switch(s) => format!("SWITCH {:.2}", s.ratio),
        GapCall::Undetermined => "undetermined".into(),
    }
}

/// The laws with the dark step's variance at black left out: what a chart-only session gives.
fn chart_only(laws: &[CalibratedLaw]) -> Vec<CalibratedLaw> {
    laws.iter().map(|l| CalibratedLaw { at_black: [None; 4], ..*l }).collect()
}

/// The laws as the detector before pinning read them: every positive chart intercept trusted
/// (a position whose intercept is not positive left out, as it left it out). Its calls are
/// [`gaps`]' on these, an undetermined gap read as "no switch".
fn trusting_every_intercept(laws: &[CalibratedLaw]) -> Vec<CalibratedLaw> {
    laws.iter()
        .map(|l| {
            let law = l.law.map(|p| p.filter(|p| p.a > 0.0 && p.b > 0.0));
            CalibratedLaw { law, at_black: law.map(|p| p.map(|p| p.b)), ..*l }
        })
        .collect()
}

/// Calibrates `plan` as the CLI would, then a dark step of 16 frames per ISO at the shortest
/// exposure the ISO uses; a dark frame the session refuses (a sensor whose dark signal at a
/// long exposure passes the dark level) is left out, as a user's would be.
fn calibrate_lenient_dark(sim: &Simulator, plan: &noisecal_sim::SessionPlan) -> ModelPack {
    let mut config = noisecal_core::SessionConfig::new(plan.reference_iso);
    config.make = "sim".into();
    let mut session = noisecal_core::CalibrationSession::new(sim.layout(), config).expect("session");
    plan.feed(sim, &mut session, |_, _| ()).expect("capture");
    session.begin_dark().expect("dark step");
    for (iso, exposure) in plan.dark_settings() {
        for k in 0..16 {
            let (px, meta) = sim.capture_dark(iso, exposure, k).expect("dark capture");
            let _refused = session.push_frame(&noisecal_core::FrameView::from_array(&px).expect("view"), &meta);
        }
    }
    session.finish().expect("a pack")
}

#[test]
fn family_switch_calls() {
    type Calls = Vec<(u32, u32, bool, GapCall, GapCall, GapCall)>;
    let rows: Vec<(u64, String, Calls)> = (0..SENSORS)
        .into_par_iter()
        .map(|seed| {
            let sensor = random_sensor(seed);
            let spec = random_session(seed, &sensor.model);
            let sim = spec.simulator(&sensor.model, seed ^ 0xA5A5).expect("simulator");
            let plan = spec.plan(&sim).expect("plan");
            let pack = calibrate_lenient_dark(&sim, &plan);
            let laws = calibrated_laws(&pack);
            let with_dark = gaps(&laws);
            let chart = gaps(&chart_only(&laws));
            let before = gaps(&trusting_every_intercept(&chart_only(&laws)));
            let calls = with_dark
                .into_iter()
                .zip(chart)
                .zip(before)
                .map(|((d, c), b)| {
                    let b = match b.call {
                        GapCall::Switch(s) => GapCall::Switch(s),
                        _ => GapCall::NoSwitch,
                    };
                    (d.below_iso, d.above_iso, truth_switch(&sensor.model, d.below_iso, d.above_iso), d.call, c.call, b)
                })
                .collect();
            let dg = sensor
                .model
                .dual_gain
                .as_ref()
                .map_or("single gain".to_string(), |g| format!("dual gain from ISO {}", g.min_iso));
            (seed, format!("{} bits, {dg}, ISOs {:?}", sensor.bits, pack.iso_list()), calls)
        })
        .collect();
    let (mut dark, mut chart, mut before) = (Tally::default(), Tally::default(), Tally::default());
    for (seed, what, calls) in &rows {
        eprintln!("random sensor {seed}: {what}");
        for (lo, hi, truth, d, c, b) in calls {
            dark.add(*truth, d);
            chart.add(*truth, c);
            before.add(*truth, b);
            eprintln!(
                "  {lo:>6} → {hi:<6} truth {:<7} with dark frames {:<16} chart only {:<16} trusting every intercept {}",
                if *truth { "SWITCH" } else { "none" },
                call_text(d),
                call_text(c),
                call_text(b)
            );
        }
    }
    eprintln!(
        "with dark frames: {dark:?}\nchart only:       {chart:?}\ntrusting every intercept (the detector before): {before:?}"
    );
    // From the chart alone: no wrong call. Measured: 0 false, 0 missed, 12 of 40 gaps
    // undetermined, 3 of 6 switches found.
    assert_eq!(chart.false_switch, 0, "chart only: switches called where the gain does not change: {chart:?}");
    assert_eq!(chart.missed, 0, "chart only: real switches called 'no switch': {chart:?}");
    // With dark frames: every call right. Measured: 40 of 40 (0 false, 0 missed, 6 of 6 found).
    // Sensor 19 (10 bits, black 13.5 DN, single gain) was a false switch at ISO 500 → 1600 while
    // the read term was the dark frames' spread as measured: the clamp at 0 DN took 36 % and 58 %
    // of it (0.66 across the gap); `read_at_black` undoes the clamp.
    assert_eq!(dark.missed, 0, "with dark frames: real switches called 'no switch': {dark:?}");
    assert_eq!(dark.false_switch, 0, "with dark frames: switches called where the gain does not change: {dark:?}");
    // The family's sessions cross switches, and with dark frames the detector finds them.
    assert!(dark.switches >= 3, "{dark:?}");
    assert_eq!(dark.found, dark.switches, "with dark frames every real switch is called: {dark:?}");
    assert!(dark.undetermined < dark.gaps / 4, "dark frames pin most gaps: {dark:?}");
}

/// One dual-gain sensor's session: the reference at base, targets at 4, 16 and 32 × base, whole
/// stops from −2 to +2 EV on the grey chart, a dark step.
fn dual_gain_session(sensor: &noisecal_sim::RandomSensor) -> (Simulator, ModelPack) {
    let mut spec = random_session(sensor.seed, &sensor.model);
    let base = sensor.model.base_iso;
    spec.target_isos = vec![4 * base, 16 * base, 32 * base];
    spec.dense = false;
    spec.ev_steps_per_stop = 1;
    spec.ev_steps = (-2..=2).collect();
    spec.frames_per_burst = spec.frames_per_burst.max(8);
    (spec.width, spec.height) = (192, 128);
    let sim = Simulator::new(sensor.model.clone(), grey_chart(spec.width, spec.height), sensor.seed ^ 0x65A1)
        .expect("simulator");
    let plan = spec.plan(&sim).expect("plan");
    let pack = calibrate_with(&sim, &plan, true, false, None);
    (sim, pack)
}

/// The worst synthetic/real variance ratio over `levels` (as `|ln|`, returned as a ratio) and
/// the levels beyond [`BOUND`] (widened by the real side's sampling error, three SEs).
fn judge_levels(name: &str, levels: &[Level]) -> (f64, Vec<String>) {
    let mut worst = 0.0f64;
    let mut out = Vec::new();
    for l in levels {
        for (what, r, real) in
            [("clean at reference", l.ratio(), &l.at.real), ("clean at target", l.target_ratio(), &l.at.real_target)]
        {
            worst = worst.max(r.ln().abs());
            let b = BOUND * (1.0 + Level::slack(real));
            if !(1.0 / b..=b).contains(&r) {
                out.push(format!(
                    "{name} position {} +{} DN, {what}: {r:.3} (real {:.2} DN², bound ×{b:.3})",
                    l.pos, l.above_black, real.var
                ));
            }
        }
    }
    (worst.exp(), out)
}

#[test]
fn dual_gain_interpolation_follows_the_truth() {
    // Random 22 and 62 (14 bits, the dark end's sensors) and the first 12-bit dual-gain member
    // whose switch lies between 4 and 16 × base.
    let mut sensors = vec![random_dark_sensor(0, 16), random_dark_sensor(1, 16)];
    sensors.push(
        (0..)
            .map(random_sensor)
            .find(|s| {
                s.bits == 12
                    && !s.clips_black
                    && s.model.dual_gain.as_ref().is_some_and(|g| (5..=16).contains(&(g.min_iso / s.model.base_iso)))
                    && s.model.max_analog_iso >= 32 * s.model.base_iso
            })
            .expect("a 12-bit dual-gain member"),
    );
    let mut failures = Vec::new();
    let mut judged = 0;
    let mut in_gap = 0;
    // In a switch's gap, modelled from the side whose conversion gain the camera uses there.
    let mut in_gap_on_its_gain = 0;
    for sensor in &mut sensors {
        // Its black level reported as the true dark level (as in `dark_end.rs`).
        sensor.model.bias_dn = [0.0; 4];
        let (sim, pack) = dual_gain_session(sensor);
        let base = sensor.model.base_iso;
        eprintln!("random sensor {}: {}", sensor.seed, sensor.description);
        let laws = calibrated_laws(&pack);
        for g in gaps(&laws) {
            let truth = truth_switch(&sensor.model, g.below_iso, g.above_iso);
            eprintln!("  gap {} → {}: truth {truth}, called {}", g.below_iso, g.above_iso, call_text(&g.call));
        }
        let packs = Packs { pack: pack.clone(), plain: pack.clone(), plain4: pack.clone() };
        for factor in [8u32, 22] {
            let iso = factor * base;
            let p = interp::plan(&pack, iso, false).expect("inside");
            let model = resolve_model(&pack, iso, ModelKind::Noisecal, false).expect("model").model;
            // The calibrated ISOs around it.
            let cal = pack.iso_list();
            let lo = cal.iter().copied().filter(|&k| k < iso).max().expect("below");
            let hi = cal.iter().copied().filter(|&k| k > iso).min().expect("above");
            let bracketed_on_one_gain = p.neighbours.iter().all(|&k| !truth_switch(&sensor.model, k, iso));
            eprintln!(
                "  ISO {iso} ({factor} × base): {}, {}",
                origin_text(&model.origin),
                if bracketed_on_one_gain { "every neighbour on its conversion gain" } else { "ACROSS the switch" }
            );
            if truth_switch(&sensor.model, lo, hi) {
                // Inside the switch's gap: which gain the camera uses is unknown; the plan must
                // say so.
                in_gap += 1;
                in_gap_on_its_gain += bracketed_on_one_gain as usize;
                assert!(p.in_switch_gap.is_some(), "ISO {iso} lies in a real switch's gap: {p:?}");
                assert!(p.gap_warning().is_some_and(|w| w.contains("Calibrate ISO")), "{p:?}");
                continue;
            }
            let results = compare(&sim, &packs, &[iso], 7 + factor as u64);
            let (worst, beyond) = judge_levels(&format!("random {} ISO {iso}", sensor.seed), &results[0].1);
            let at_black: Vec<String> = results[0]
                .1
                .iter()
                .filter(|l| l.above_black == 0)
                .map(|l| format!("{:.1}/{:.1}", l.at.pack.m.var, l.at.real.var))
                .collect();
            eprintln!(
                "    worst variance ratio from black up {worst:.3}; at black (synthetic/real DN²) {}",
                at_black.join(", ")
            );
            assert!(bracketed_on_one_gain, "ISO {iso}: the plan stands across the switch: {p:?}");
            judged += 1;
            failures.extend(beyond);
        }
    }
    eprintln!(
        "{judged} ISOs judged, {in_gap} inside a switch's gap, {in_gap_on_its_gain} of them modelled on their own gain"
    );
    assert!(judged >= 3 && in_gap >= 1, "the study must judge both cases: {judged} / {in_gap}");
    // 8 × base is halfway in log ISO between 4 and 16 × base: a tie, taken to the low-gain side
    // (method.md). All three sensors use the low gain there; the upper side on a tie, the
    // convention before, modelled all three from the high-gain side (0 of 3).
    assert_eq!(in_gap_on_its_gain, in_gap, "ties in a switch's gap modelled across it");
    assert!(failures.is_empty(), "{} levels beyond the bound:\n{}", failures.len(), failures.join("\n"));
}
