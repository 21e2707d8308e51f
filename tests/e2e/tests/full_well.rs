//! Reference pixels at the sensor's ceiling (method.md, "Calibration" 2, *Saturated reference
//! pixels*), with known truth: random-family sensors whose full well fills below white (seeds 0
//! and 4) or whose ADC clips at white first (seed 6), calibrated and held-out sessions, the
//! chart still and moving. Every pixel whose true level is at the ceiling leaves the flat set;
//! no pixel far below it does; and at a step where nothing reaches the ceiling the rule does not
//! fire (the flat set, and so the pack, is what it was without the rule).
//!
//! What it buys (`tests/e2e/tests/moving.rs`, seed 0, ISO 640 / 1000, EV +3): synthetic/real
//! variance 1.19 / 1.16 → 1.02 / 0.99, because the pack's bin at the ceiling no longer mixes
//! pixels of every brightness above it.

use noisecal_core::calibrate::flat::NOT_FLAT;
use noisecal_core::{CalibrationSession, FrameView, POSITIONS, SessionConfig, position};
use noisecal_sim::{SessionPlan, Simulator, random_moving_scene, random_sensor, random_session};

/// What one reference burst's flat test did against the truth.
#[derive(Debug, Default)]
struct Tally {
    /// Pixels whose true level is at the ceiling (mean electrons at the full well, or a mean at
    /// white), and of them those left flat.
    at_ceiling: usize,
    kept_at_ceiling: usize,
    /// Pixels left out as saturated, and the pixels whose true level could reach the cut (within
    /// `(3 + 4/√M)` noise SDs of the ceiling).
    left_out: u64,
    near_ceiling: usize,
    /// Per position where the ceiling is reached: the ceiling (the largest true level), the
    /// rule's cut, and the true per-frame noise SD at the ceiling (DN).
    cuts: Vec<(f32, u16, f32)>,
}

/// Per EV step of `plan` on `sim`, the flat test's saturated pixels against the truth of
/// `truth` (the still simulator: its clean images are the moving one's without the motion).
fn tally(sim: &Simulator, truth: &Simulator, plan: &SessionPlan, off: u64) -> Vec<(i32, Tally)> {
    let layout = sim.layout();
    let w = layout.width as usize;
    let m = plan.frames_per_burst as f64;
    let mut out = Vec::new();
    let mut session: Option<CalibrationSession> = None;
    let mut step = None;
    for f in plan.frames() {
        if step != Some(f.step) {
            let mut s =
                CalibrationSession::new(layout.clone(), SessionConfig::new(plan.reference_iso)).expect("session");
            s.begin_step(plan.exposure_ns(f.step, plan.reference_iso)).expect("step");
            session = Some(s);
            step = Some(f.step);
        }
        let Some(s) = session.as_mut() else { continue };
        if f.is_reference {
            let (px, meta) = sim.capture(f.iso, f.exposure_ns, f.index + off).expect("capture");
            s.push_frame(&FrameView::from_array(&px).expect("view"), &meta).expect("push");
            continue;
        }
        s.close_reference_burst().expect("close");
        let report = s.flat_report().expect("report").clone();
        let clean = s.clean_image().expect("clean").to_vec();
        session = None;
        let exposure = plan.exposure_ns(f.step, plan.reference_iso);
        let expected = truth.clean_expected(plan.reference_iso, exposure).expect("truth");
        let levels: Vec<f32> = expected.iter().copied().collect();
        let well = truth.model().full_well_e;
        let white = layout.white as f32;
        let electrons: Vec<f32> = truth.mean_electrons(exposure).iter().copied().collect();
        let saturated = |i: usize| electrons[i] >= well || levels[i] >= white - 0.5;
        let mut t = Tally { left_out: report.saturated.iter().sum(), ..Tally::default() };
        for pos in 0..POSITIONS {
            let of_pos = || levels.iter().enumerate().filter(|(i, _)| position(i / w, i % w) == pos);
            let top = of_pos().map(|(_, &v)| v).fold(f32::MIN, f32::max);
            let at: Vec<usize> = of_pos().filter(|(i, _)| saturated(*i)).map(|(i, _)| i).collect();
            if !at.is_empty() {
                let sd = truth.predicted_variance(plan.reference_iso, top, pos).expect("variance").sqrt() as f32;
                t.at_ceiling += at.len();
                t.kept_at_ceiling += at.iter().filter(|&&i| clean[i] != NOT_FLAT).count();
                t.near_ceiling +=
                    of_pos().filter(|(_, v)| **v >= top - (3.0 + 4.0 / m.sqrt() as f32) * sd - 3.0).count();
                if let Some(cut) = report.saturation_cut[pos] {
                    t.cuts.push((top, cut, sd));
                }
            }
        }
        out.push((f.step, t));
    }
    out
}

/// The margin below the ceiling method.md states, in per-frame noise SDs at the ceiling
/// (`calibrate/saturated.rs`, `MARGIN_SIGMAS`).
const MARGIN_SIGMAS: f32 = 2.0;

/// Pixels at the ceiling from which every one must leave the flat set.
const SMALLEST_CROWD: usize = 30;

#[test]
fn pixels_at_the_ceiling_leave_the_flat_set_and_no_others() {
    for seed in [0u64, 4, 6] {
        let sensor = random_sensor(seed);
        let mut spec = random_session(seed, &sensor.model);
        let scene = random_moving_scene(seed);
        spec.edge_blur_px = Some(scene.edge_blur_px);
        let still = spec.simulator(&sensor.model, seed ^ 0xA5A5).expect("simulator");
        let plan = spec.plan(&still).expect("plan");
        let mut moving_model = sensor.model.clone();
        let mut moving_spec = spec.clone();
        scene.apply(&mut moving_model, &mut moving_spec);
        let moving = moving_spec.simulator(&moving_model, seed ^ 0xA5A5).expect("simulator");
        let heldout = spec.heldout_simulator(&sensor.model, seed ^ 0xA5A5).expect("held-out simulator");
        let hplan = spec.heldout_plan(&plan).expect("held-out plan");
        let runs = [
            ("still", tally(&still, &still, &plan, 0)),
            ("moving", tally(&moving, &still, &plan, 0)),
            ("held-out", tally(&heldout, &heldout, &hplan, spec.heldout.index_offset)),
        ];
        let mut saturated_steps = 0;
        for (what, steps) in &runs {
            for (step, t) in steps {
                println!("seed {seed} {what} EV step {step}: {t:?}");
                let at = format!("seed {seed}, {what}, EV step {step}");
                if t.at_ceiling == 0 {
                    // Nothing reaches the ceiling: the rule must not fire.
                    assert_eq!(t.left_out, 0, "{at}: pixels left out with no ceiling reached");
                    continue;
                }
                assert!(
                    t.left_out as usize <= t.near_ceiling,
                    "{at}: {} pixels left out, only {} could reach the cut",
                    t.left_out,
                    t.near_ceiling
                );
                // A crowd of flagged pixels needs more than `MIN_FLAGGED` (10) of them beyond
                // chance: a handful of saturated pixels is below what the rule can see.
                if t.at_ceiling < SMALLEST_CROWD {
                    continue;
                }
                saturated_steps += 1;
                assert!(
                    t.kept_at_ceiling as f64 <= 0.01 * t.at_ceiling as f64 + 1.0,
                    "{at}: {} of {} pixels at the ceiling kept flat",
                    t.kept_at_ceiling,
                    t.at_ceiling
                );
                // The margin below the ceiling is the stated `MARGIN_SIGMAS` (2) SDs of the true
                // noise there, plus the flagged levels' spread: at least 1.8 SD. With the law
                // fitted over every level, the saturated ones included, it read 0.5–0.8 SD.
                for &(top, cut, sd) in &t.cuts {
                    let margin = (top - cut as f32) / sd;
                    assert!(
                        margin >= 0.9 * MARGIN_SIGMAS,
                        "{at}: cut {cut} is {margin:.2} SD below the ceiling {top:.0}"
                    );
                }
            }
        }
        assert!(saturated_steps >= 3, "seed {seed}: the sessions never reached the ceiling");
    }
}
