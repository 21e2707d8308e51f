//! The cost of black's phase tables (`StructureSampler::black_phase_set`,
//! `synth::phase_tables::phase_set_less_held`) on a sensor where they are largest: bins of 1 DN,
//! so black's bin holds black's code alone and takes the fixed pattern out of its `Y`, with a
//! pattern of several DN (many held points) over noise of about a DN (many codes).
//!
//! `cargo test -p noisecal-core --test phase_black_cost -- --ignored --nocapture` prints, per ISO
//! and CFA position, the time of `black_phase_set` (median of 5) and the bytes of the tables it
//! makes.

use noisecal_core::model::layout::POSITIONS;
use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::{CalibrationSession, ModelPack, SessionConfig};
use noisecal_sim::{Chart, SensorModel, SessionPlan, Simulator};

/// The 10-bit phone with structured components and a fixed pattern (DSNU) of `pattern_dn` DN,
/// calibrated on bins of 1 DN with dark frames at every ISO.
fn one_dn_pack(pattern_dn: f32) -> ModelPack {
    let mut model = SensorModel::phone_10bit().with_structured_noise();
    model.dsnu_post_dn = pattern_dn;
    let sim = Simulator::new(model, Chart::color_checker(96, 64).expect("chart"), 11).expect("simulator");
    let plan = SessionPlan::for_simulator(&sim, vec![100, 800], 6).expect("plan").with_ev_steps(-3..=3);
    let mut config = SessionConfig::new(plan.reference_iso);
    config.bin_width = Some(1);
    let mut session = CalibrationSession::new(sim.layout(), config).expect("session");
    plan.feed(&sim, &mut session, |_, _| ()).expect("capture");
    session.begin_dark().expect("dark step");
    for (iso, exposure_ns) in plan.dark_settings() {
        for i in 0..3u64 {
            let (px, meta) = sim.capture_dark(iso, exposure_ns, 1_000 + i).expect("dark frame");
            let view = noisecal_core::FrameView::from_array(&px).expect("contiguous");
            session.push_frame(&view, &meta).expect("dark frame accepted");
        }
    }
    session.finish().expect("a pack")
}

#[test]
#[ignore = "measurement: calibrates a simulated session"]
fn black_phase_set_cost() {
    let pattern: f32 = std::env::var("NOISECAL_PATTERN_DN").ok().and_then(|s| s.parse().ok()).unwrap_or(3.0);
    let pack = one_dn_pack(pattern);
    assert_eq!(pack.binning().bin_width, 1);
    for m in &pack.isos {
        let s = IsoSampler::with_components(&pack, m, Components::ALL);
        let Some(st) = s.structure() else {
            println!("ISO {}: no structured components", m.iso);
            continue;
        };
        for p in 0..POSITIONS {
            let bin = &m.positions[p].bins[0];
            let black = f64::from(pack.layout.black[p]);
            let mut times = vec![];
            let mut set = None;
            for _ in 0..5 {
                let t0 = std::time::Instant::now();
                set = st.black_phase_set(p, bin, black);
                times.push(t0.elapsed().as_secs_f64() * 1e3);
            }
            times.sort_by(f64::total_cmp);
            println!(
                "ISO {} position {p}: black's bin {} codes; black_phase_set {:.2} ms (median of 5, {:.2}–{:.2}), tables {} bytes",
                m.iso,
                bin.counts.len(),
                times[2],
                times[0],
                times[4],
                set.as_ref().map_or(0, |s| s.heap_bytes())
            );
        }
    }
}
