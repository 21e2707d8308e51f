//! A photon-transfer-style capture, as a DSLR user makes one: 41 exposure settings about 4 %
//! apart, each a 5-frame reference burst plus a single target frame, written as a DNG folder
//! in shuffled order. Grouping must keep every setting its own EV step (nothing merged, nothing
//! "normalised" as drift), and the pack must score within 1.5× of an HG fit on the same frames
//! on an independent held-out set (in fact well below it).

use std::path::Path;

use noisecal_cli::eval::{EvalOptions, evaluate, render_text};
use noisecal_input::calibrate::{CalibrateOptions, calibrate_path};
use noisecal_input::dng;
use noisecal_input::grouping::scan_dng_set;
use noisecal_sim::{Chart, SensorModel, SessionPlan, Simulator};

const STEPS: i32 = 41;
/// 17 steps per stop: 2^(1/17) = 4.2 % apart.
const PER_STOP: u32 = 17;

fn dslr() -> SensorModel {
    let mut m = SensorModel::phone_14bit();
    m.dual_gain = None;
    m
}

/// Writes the sweep: per setting `refs` reference frames at the base ISO and `targets` frames at
/// ISO 400 with the same ISO × exposure; `offset` shifts frame indices (fresh noise).
fn write_sweep(dir: &Path, steps: &[i32], refs: u32, targets: u32, offset: u64) -> SessionPlan {
    let sim = Simulator::new(dslr(), Chart::color_checker(128, 96).expect("chart"), 5).expect("sim");
    let base = sim.mid_range_exposure_ns(100).expect("exposure") / 4;
    let plan = SessionPlan::new(100, vec![400], refs.max(targets), base)
        .with_ev_steps_per_stop(PER_STOP)
        .with_ev_steps(steps.iter().copied());
    plan.validate().expect("plan");
    std::fs::create_dir_all(dir).expect("dir");
    let layout = sim.layout();
    for f in plan.frames() {
        if (f.is_reference && f.in_burst >= refs) || (!f.is_reference && f.in_burst >= targets) {
            continue;
        }
        let (px, meta) = sim.capture(f.iso, f.exposure_ns, f.index + offset).expect("capture");
        // Names that say nothing about the order: grouping must come from the metadata.
        let name = format!("IMG_{:04}.dng", (f.index * 7919 + offset) % 10_000);
        dng::write_dng_from_layout(&dir.join(name), &layout, &meta, "Sim", "DSLR", &px).expect("write DNG");
    }
    plan
}

#[test]
fn a_dense_photon_transfer_sweep_calibrates() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cal = dir.path().join("cal");
    let held = dir.path().join("held");
    let all: Vec<i32> = (0..STEPS).collect();
    write_sweep(&cal, &all, 5, 1, 0);
    // Held-out: every fourth setting, 4 reference frames and 2 targets, fresh noise.
    let some: Vec<i32> = (0..STEPS).step_by(4).collect();
    write_sweep(&held, &some, 4, 2, 1_000_000);

    let set = scan_dng_set(&cal, None).expect("grouping");
    assert_eq!(set.steps.len(), STEPS as usize, "every setting is its own step: {:?}", set.warnings);
    assert!(set.steps.iter().all(|s| s.reference.len() == 5 && s.targets.len() == 1));

    let (pack, report) = calibrate_path(&cal, &CalibrateOptions::default(), &mut |_, _| {}).expect("calibrate");
    assert!(report.rejected.is_empty(), "no frame refused: {:?}", report.rejected);
    let m = pack.iso(400).expect("ISO 400 calibrated");
    assert_eq!(m.drift_frames, 0, "nothing normalised as drift");
    for g in m.gain_ratio {
        assert!((g - 1.0).abs() < 0.05, "gain ratio {g}");
    }
    let pack_path = dir.path().join("p.pack");
    std::fs::write(&pack_path, pack.to_bytes().expect("bytes")).expect("write pack");
    let opts = EvalOptions { seeds: 2, ..Default::default() };
    let r = evaluate(&pack, &pack_path, &held, &opts, true).expect("eval");
    println!("{}", render_text(&r));
    let iso = r.isos.iter().find(|i| i.iso == 400).expect("ISO 400 scored");
    let nc = iso.model("noisecal").expect("noisecal");
    let hg = iso.model("hg").expect("hg");
    assert!(
        nc.conditional_overall <= 1.5 * hg.conditional_overall && nc.marginal_overall <= 1.5 * hg.marginal_overall,
        "noisecal {:.5}/{:.5} vs HG {:.5}/{:.5}",
        nc.marginal_overall,
        nc.conditional_overall,
        hg.marginal_overall,
        hg.conditional_overall
    );
}
