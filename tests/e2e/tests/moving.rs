//! Motion between frames is not noise (method.md, "Motion"): sensors of the random family
//! calibrated from sessions whose chart moves between frames (a random walk of 0.05–0.6 px with
//! jumps, rotation, focus breathing, edge blur of 0.5–2 px, flicker: `random_moving_scene`), and
//! from the same sessions held still, then judged by the variance and the 0.1 % / 99.9 % tails
//! of synthetic noise against real noise on held-out captures that do not move.

use noisecal_core::model::structure::Components;
use noisecal_e2e::calibrate_lenient;
use noisecal_e2e::moments::{Moments, heldout_moments};
use noisecal_sim::{random_moving_scene, random_sensor, random_session};
use rayon::prelude::*;

/// Sensors in the study.
const SENSORS: u64 = 8;

struct Outcome {
    seed: u64,
    description: String,
    still: Vec<Moments>,
    moving: Vec<Moments>,
    /// The same on a held-out set of [`LINE_FRAMES`] frames per burst, for the row- and
    /// column-mean variances only.
    still_lines: Vec<Moments>,
    moving_lines: Vec<Moments>,
    events: Vec<String>,
    /// The self-check's robust-spread findings of the still and the moving pack.
    still_spread: Vec<String>,
    moving_spread: Vec<String>,
}

/// The pack's robust-spread findings (method.md, "Self-check").
fn spread_findings(pack: &noisecal_core::ModelPack) -> Vec<String> {
    pack.warnings.iter().filter(|w| w.contains("robust spread")).cloned().collect()
}

fn calibrate(
    sim: &noisecal_sim::Simulator,
    plan: &noisecal_sim::SessionPlan,
) -> (noisecal_core::ModelPack, Vec<String>) {
    let (session, pack) = calibrate_lenient(sim, plan);
    (pack, session.events().to_vec())
}

fn run(seed: u64) -> Outcome {
    let sensor = random_sensor(seed);
    let mut spec = random_session(seed, &sensor.model);
    let scene = random_moving_scene(seed);
    // The still session has the moving one's blur: only the motion differs.
    spec.edge_blur_px = Some(scene.edge_blur_px);
    let still_sim = spec.simulator(&sensor.model, seed ^ 0xA5A5).expect("simulator");
    let plan = spec.plan(&still_sim).expect("plan");
    let (still_pack, _) = calibrate(&still_sim, &plan);
    let still_spread = spread_findings(&still_pack);
    let mut moving_model = sensor.model.clone();
    let mut moving_spec = spec.clone();
    scene.apply(&mut moving_model, &mut moving_spec);
    let moving_sim = moving_spec.simulator(&moving_model, seed ^ 0xA5A5).expect("simulator");
    let (moving_pack, events) = calibrate(&moving_sim, &plan);
    let moving_spread = spread_findings(&moving_pack);
    let hsim = spec.heldout_simulator(&sensor.model, seed ^ 0xA5A5).expect("held-out simulator");
    let hplan = spec.heldout_plan(&plan).expect("held-out plan");
    let off = spec.heldout.index_offset;
    let mut lplan = hplan.clone();
    lplan.frames_per_burst = line_frames();
    // The line study's held-out captures do not shake ([`still_heldout_for_lines`]).
    let mut still_sensor = sensor.model.clone();
    still_heldout_for_lines(&mut still_sensor);
    let lsim = spec.heldout_simulator(&still_sensor, seed ^ 0xA5A5).expect("held-out simulator");
    Outcome {
        seed,
        description: format!("{} | {}", sensor.description, moving_spec.description),
        still: heldout_moments(&hsim, &hplan, off, &still_pack, Components::ON_OWN_CAPTURES),
        moving: heldout_moments(&hsim, &hplan, off, &moving_pack, Components::ON_OWN_CAPTURES),
        still_lines: heldout_moments(&lsim, &lplan, off, &still_pack, Components::ON_OWN_CAPTURES),
        moving_lines: heldout_moments(&lsim, &lplan, off, &moving_pack, Components::ON_OWN_CAPTURES),
        events,
        still_spread,
        moving_spread,
    }
}

/// The held-out captures of the line study are taken without the sensor's sub-pixel shake
/// (`jitter_px`, 0–0.12 px in the family): "real noise" there is capture − clean, and a shake
/// moves every horizontal (vertical) patch edge of a row (column) at once, so the flat pixels'
/// share of the blurred edges adds to the real row-mean variance what no noise model should
/// make. Measured on sensor 6 (jitter 0.093 px), ISO 200 EV +2: real row-mean variance 1.013
/// with the shake against 0.726 without (its pixels' part 0.751 / 0.709), rows 0.72 → 0.98;
/// ISO 320 EV +2 0.84 → 0.98, EV +4 0.82 → 0.91. Per pixel the same shake is a far smaller
/// share (one pixel's edge term against its own noise, not a line's sum), so the variance
/// study's held-out set keeps it.
fn still_heldout_for_lines(model: &mut noisecal_sim::SensorModel) {
    model.jitter_px = 0.0;
}

/// Held-out frames per burst for the row- and column-mean variances. The fidelity held-out set
/// (2–8 frames of 72–128 rows) gives the ratio of two such variances a sampling SD of about 0.17
/// in log, so ×1.2 (0.18) cannot be judged there. With 24 frames the SD was about 0.05 at most
/// pairs, but 0.13 (rows) and 0.19 (columns) on seed 4 at EV +4, where the saturation rule
/// leaves few rows and columns with 16 flat pixels of a parity on its 64 × 48 held-out image:
/// there rows 1.358 at ISO 250 and columns 0.689 at ISO 3200 were sampling (2.3 and 2.0 SD),
/// not the model or the score. With 192 frames the same pairs read 0.933 and 0.991 (SD 0.051
/// and 0.065) and the SD elsewhere is about 0.02.
const LINE_FRAMES: u32 = 192;

/// [`LINE_FRAMES`], or `NOISECAL_LINE_FRAMES` where set (to see a line ratio converge: a
/// ratio beyond ×1.2 that is sampling shrinks toward 1 as the frames grow).
fn line_frames() -> u32 {
    std::env::var("NOISECAL_LINE_FRAMES").ok().and_then(|s| s.trim().parse().ok()).unwrap_or(LINE_FRAMES).max(2)
}

/// Sampling slack on the line ratios, in standard deviations of their logarithm (each pair's
/// own, from its degrees of freedom: `Moments::line_log_sd`).
const LINE_SLACK_SD: f64 = 3.0;

/// Pairs with fewer real samples are printed, not judged (their variance ratios' sampling SD
/// exceeds 1 %).
const MIN_SAMPLES: usize = 20_000;
/// Tails (0.1 % / 99.9 % quantiles) are judged with at least this many samples (50 beyond each).
const MIN_TAIL_SAMPLES: usize = 50_000;

/// The moving session against the still one and against the truth, at one (ISO, EV step)
/// where the still session is within 1.10 of the real variance:
/// - synthetic variance within ×1.08 of the still session's (plus 3 SE: two independent
///   synthetic sets, heavy tails counted at twice a Gaussian's sampling variance);
/// - within 1.10 of the real variance (plus 3 SE), and tails within 1.25 where there are
///   enough samples.
///
/// What the still session itself gets wrong (clipping near white, the dark end: 8 of 85 pairs
/// of the default seeds, up to 1.56) is not motion and is judged elsewhere. On the code before motion was registered, seeds 4 and 5 gave moving
/// ratios of 1.49–1.57 and 1.27–1.34 where the still ones were 0.97–1.05.
fn judge(seed: u64, s: &Moments, m: &Moments) -> Vec<String> {
    let mut out = Vec::new();
    if s.samples < MIN_SAMPLES {
        return out;
    }
    let se = (8.0 / s.samples as f64).sqrt();
    let (sv, mv) = (s.var_ratio(), m.var_ratio());
    let at = format!("seed {seed} ISO {} EV step {}", s.iso, s.step);
    if sv.ln().abs() > 1.10f64.ln() {
        return out;
    }
    if (mv / sv).ln().abs() > 1.08f64.ln() + 3.0 * se {
        out.push(format!("{at}: moving variance ratio {mv:.3} against still {sv:.3}"));
    }
    if mv.ln().abs() > 1.10f64.ln() + 3.0 * se {
        out.push(format!("{at}: moving variance ratio {mv:.3} (still {sv:.3}) beyond 1.10"));
    }
    if s.samples >= MIN_TAIL_SAMPLES {
        let (sl, sh) = s.tail_ratios();
        let (ml, mh) = m.tail_ratios();
        for (name, st, mt) in [("0.1 %", sl, ml), ("99.9 %", sh, mh)] {
            if st.ln().abs() <= 1.25f64.ln() && mt.ln().abs() > 1.25f64.ln() + 0.05 {
                out.push(format!("{at}: moving {name} tail ratio {mt:.2} (still {st:.2}) beyond 1.25"));
            }
        }
    }
    out
}

#[test]
fn motion_between_frames_is_not_measured_as_noise() {
    // `NOISECAL_SEEDS=3,13` runs only those sensors.
    let seeds: Vec<u64> = match std::env::var("NOISECAL_SEEDS") {
        Ok(s) => s.split(',').filter_map(|x| x.trim().parse().ok()).collect(),
        Err(_) => (0..SENSORS).collect(),
    };
    let outcomes: Vec<Outcome> = seeds.into_par_iter().map(run).collect();
    let mut failures: Vec<String> = Vec::new();
    println!(
        "seed ISO    step samples | still: var ratio, tails lo/hi, rows/cols | moving: var ratio, tails lo/hi, rows/cols"
    );
    for o in &outcomes {
        println!("{:>4} {}", o.seed, o.description);
        for e in o.events.iter().filter(|e| e.contains("moved") || e.contains("shift")) {
            println!("     event: {e}");
        }
        for w in &o.moving_spread {
            println!("     moving pack: {w}");
        }
        // Heavy tails, clipping, row noise and blur alone must not read as a robust-spread
        // finding: a still session's pack has none.
        for w in &o.still_spread {
            failures.push(format!("seed {} still pack: {w}", o.seed));
        }
        for (s, m) in o.still.iter().zip(&o.moving) {
            let (sl, sh) = s.tail_ratios();
            let (ml, mh) = m.tail_ratios();
            let (sr, sc) = s.line_ratios();
            let (mr, mc) = m.line_ratios();
            println!(
                "     {:>5} {:>4} {:>7} | {:.3} {:.2}/{:.2} {:.2}/{:.2} | {:.3} {:.2}/{:.2} {:.2}/{:.2}  (real var {:.2}, tails {:.1}/{:.1})",
                s.iso,
                s.step,
                s.samples,
                s.var_ratio(),
                sl,
                sh,
                sr,
                sc,
                m.var_ratio(),
                ml,
                mh,
                mr,
                mc,
                s.var.0,
                s.low_tail.0,
                s.high_tail.0
            );
        }
    }
    let judged: usize = outcomes.iter().flat_map(|o| o.still.iter()).filter(|s| s.samples >= MIN_SAMPLES).count();
    for o in &outcomes {
        for (s, m) in o.still.iter().zip(&o.moving) {
            failures.extend(judge(o.seed, s, m));
        }
    }
    // Row- and column-mean variance, synthetic over real, on the large held-out set.
    let mut line_stats = [[0usize; 2]; 2];
    let mut line_logs: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    for o in &outcomes {
        println!("{:>4} rows/cols on {} frames per burst: still | moving", o.seed, line_frames());
        for (s, m) in o.still_lines.iter().zip(&o.moving_lines) {
            let (sr, sc) = s.line_ratios();
            let (mr, mc) = m.line_ratios();
            let (rsr, rsc) = s.raw_line_ratios();
            let (rmr, rmc) = m.raw_line_ratios();
            let (srs, scs) = s.line_log_sd();
            let (mrs, mcs) = m.line_log_sd();
            println!(
                "     {:>5} {:>4} | {sr:.3} {sc:.3} | {mr:.3} {mc:.3}  (log SD {srs:.3} {scs:.3}; as measured {rsr:.3} {rsc:.3} | {rmr:.3} {rmc:.3}; real row var {:.4} of which pixels {:.4}, col var {:.4} of which pixels {:.4})",
                s.iso, s.step, s.row_var.0, s.row_pixel.0, s.col_var.0, s.col_pixel.0
            );
            // Both sessions, at every pair: ×1.2, plus each ratio's own sampling slack.
            for (session, what, r, sd) in [
                ("still", "row", sr, srs),
                ("still", "column", sc, scs),
                ("moving", "row", mr, mrs),
                ("moving", "column", mc, mcs),
            ] {
                if r.is_finite() && r.ln().abs() > 1.2f64.ln() + LINE_SLACK_SD * sd {
                    failures.push(format!(
                        "seed {} ISO {} EV step {}: {session} {what}-mean variance ratio {r:.3} beyond 1.2 (slack {:.3} in log)",
                        o.seed,
                        s.iso,
                        s.step,
                        LINE_SLACK_SD * sd
                    ));
                }
            }
            for (k, r) in [sr, sc, mr, mc].into_iter().enumerate() {
                if r.is_finite() {
                    let session = k / 2;
                    line_stats[session][0] += 1;
                    line_logs[session].push(r.ln().abs());
                    if r.ln().abs() > 1.2f64.ln() {
                        line_stats[session][1] += 1;
                    }
                }
            }
        }
    }
    for (session, name) in ["still", "moving"].iter().enumerate() {
        let v = &mut line_logs[session];
        v.sort_by(f64::total_cmp);
        println!(
            "{name}: {} of {} row/column ratios beyond 1.2, median |ln| {:.3}, largest {:.3}",
            line_stats[session][1],
            line_stats[session][0],
            v.get(v.len() / 2).copied().unwrap_or(f64::NAN),
            v.last().copied().unwrap_or(f64::NAN)
        );
    }
    print_audit(&outcomes);
    println!("{judged} (ISO, EV step) pairs judged, {} failures", failures.len());
    if std::env::var("NOISECAL_SEEDS").is_err() {
        assert!(judged >= 60, "too few pairs judged: {judged}");
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// One pair's figure in the audit summary: |ln| of the ratio, the ratio, where.
type Scored = (f64, f64, String);

/// How many of `scored` lie beyond `bound` (as a ratio, either side), and beyond it plus
/// `slack_sd` of each pair's own sampling SD in log; the three farthest pairs.
fn audit_line(name: &str, bound: f64, slack_sd: f64, scored: &mut [(Scored, f64)]) {
    let beyond = scored.iter().filter(|((l, _, _), _)| *l > bound.ln()).count();
    let beyond_slack = scored.iter().filter(|((l, _, _), sd)| *l > bound.ln() + slack_sd * sd).count();
    scored.sort_by(|a, b| b.0.0.total_cmp(&a.0.0));
    let worst: Vec<String> = scored.iter().take(3).map(|((_, r, at), _)| format!("{r:.3} {at}")).collect();
    println!(
        "  {name:<22} beyond {bound:.2}: {beyond:>3} of {:>3}; beyond it + {slack_sd} SD: {beyond_slack:>3}; worst: {}",
        scored.len(),
        worst.join(", ")
    );
}

/// The audit of the "Done when" bounds over every judged pair, still and moving: variance ratio
/// (≤ 1.03 still, ≤ 1.10 moving; pairs with at least [`MIN_SAMPLES`]), 0.1 % / 99.9 % tail
/// ratios (≤ 1.25; at least [`MIN_TAIL_SAMPLES`]), row- and column-mean variance ratios on the
/// line study's held-out set (≤ 1.2). Counts with and without each pair's sampling slack
/// (variance: `Moments::var_ratio_se` doubled for heavy tails; lines: `Moments::line_log_sd`);
/// printed only, the asserts are the study's own.
fn print_audit(outcomes: &[Outcome]) {
    println!("audit of the bounds (count beyond / pairs; slack in SD of each pair's own log ratio):");
    for (k, name) in ["still", "moving"].into_iter().enumerate() {
        let (mut var, mut tails, mut rows, mut cols) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for o in outcomes {
            let (fid, lines) = if k == 0 { (&o.still, &o.still_lines) } else { (&o.moving, &o.moving_lines) };
            for m in fid.iter().filter(|m| m.samples >= MIN_SAMPLES) {
                let at = format!("(seed {} ISO {} EV {})", o.seed, m.iso, m.step);
                let r = m.var_ratio();
                var.push(((r.ln().abs(), r, at.clone()), 2.0 * m.var_ratio_se()));
                if m.samples >= MIN_TAIL_SAMPLES {
                    let (lo, hi) = m.tail_ratios();
                    // The 0.1 % quantile of a Gaussian: SD sqrt(p/n)/φ(z) against a width of
                    // z = 3.09 SD, so 3.04/sqrt(n) relative; two independent sides.
                    let sd = 4.3 / (m.samples as f64).sqrt();
                    tails.push(((lo.ln().abs(), lo, format!("{at} 0.1 %")), sd));
                    tails.push(((hi.ln().abs(), hi, format!("{at} 99.9 %")), sd));
                }
            }
            for m in lines {
                let at = format!("(seed {} ISO {} EV {})", o.seed, m.iso, m.step);
                let (r, c) = m.line_ratios();
                let (rs, cs) = m.line_log_sd();
                if r.is_finite() {
                    rows.push(((r.ln().abs(), r, at.clone()), rs));
                }
                if c.is_finite() {
                    cols.push(((c.ln().abs(), c, at), cs));
                }
            }
        }
        println!(" {name}:");
        audit_line("variance ratio", if k == 0 { 1.03 } else { 1.10 }, 3.0, &mut var);
        if k == 0 {
            audit_line("variance ratio", 1.10, 3.0, &mut var);
        }
        audit_line("tail ratios", 1.25, 3.0, &mut tails);
        audit_line("row-mean var ratio", 1.2, LINE_SLACK_SD, &mut rows);
        audit_line("col-mean var ratio", 1.2, LINE_SLACK_SD, &mut cols);
    }
}

/// A target frame that moved further than [`noisecal_core::calibrate::motion::MAX_MOTION_PX`]
/// against its reference burst is refused by name, with what to do; frames that moved less are
/// taken, with their motion reported.
#[test]
fn a_frame_that_moved_too_far_is_refused_by_name() {
    use noisecal_core::error::SessionError;
    use noisecal_sim::{Motion, SensorModel};
    let mut model = SensorModel::phone_10bit();
    model.jitter_px = 0.0;
    // Each frame jumps to a pose within ±2.8 px per axis.
    model.motion =
        Some(Motion { max_shift_px: 2.8, step_px: 0.0, jump_probability: 1.0, max_rotation_rad: 0.0, breathing: 0.0 });
    let mut chart = noisecal_sim::Chart::color_checker(192, 144).expect("chart");
    chart.edge_blur_px = 1.5;
    let sim = noisecal_sim::Simulator::new(model, chart, 5).expect("simulator");
    let plan = noisecal_sim::SessionPlan::for_simulator(&sim, vec![200], 8).expect("plan").with_ev_steps([0]);
    let mut session =
        noisecal_core::CalibrationSession::new(sim.layout(), noisecal_core::SessionConfig::new(plan.reference_iso))
            .expect("session");
    session.begin_step(plan.exposure_ns(0, plan.reference_iso)).expect("step");
    let (mut refused, mut taken) = (0, 0);
    for f in plan.frames() {
        let (px, meta) = sim.capture(f.iso, f.exposure_ns, f.index).expect("capture");
        let r = session.push_frame(&noisecal_core::FrameView::from_array(&px).expect("view"), &meta);
        if f.is_reference {
            continue;
        }
        match r {
            Err(SessionError::Moved { shift_px, .. }) => {
                let e = r.expect_err("refused").to_string();
                assert!(e.contains("moved") && e.contains("mount") && e.contains("ISO 200"), "{e}");
                assert!(shift_px > 2.0, "refused at {shift_px:.2} px");
                refused += 1;
            }
            Err(e) => panic!("unexpected refusal: {e}"),
            Ok(rep) => {
                let m = rep.motion.expect("a target frame is registered");
                assert!(m.max_shift() <= 2.0);
                taken += 1;
            }
        }
    }
    assert!(refused >= 1 && taken >= 1, "refused {refused}, taken {taken}");
}
