//! Shared helpers of the end-to-end tests: small simulated sessions pushed through a session.

use ndarray::Array2;
use noisecal_core::flat::NOT_FLAT;
use noisecal_core::{CalibrationSession, FrameView, ModelPack, SessionConfig};
use noisecal_sim::{Chart, SensorModel, SessionPlan, Simulator};

/// A simulator and its plan.
#[derive(Debug)]
pub struct Setup {
    pub sim: Simulator,
    pub plan: SessionPlan,
}

pub fn setup(model: SensorModel, w: u32, h: u32, seed: u64, isos: Vec<u32>, frames: u32, ev: Vec<i32>) -> Setup {
    let chart = Chart::color_checker(w, h).expect("chart");
    let sim = Simulator::new(model, chart, seed).expect("simulator");
    let plan = SessionPlan::for_simulator(&sim, isos, frames).expect("plan").with_ev_steps(ev);
    Setup { sim, plan }
}

/// Runs the plan through a session in capture order; `tweak` adjusts the config.
pub fn calibrate(s: &Setup, tweak: impl FnOnce(&mut SessionConfig)) -> (CalibrationSession, ModelPack) {
    let mut config = SessionConfig::new(s.plan.reference_iso);
    tweak(&mut config);
    let mut session = CalibrationSession::new(s.sim.layout(), config).expect("session");
    let mut step = None;
    for f in s.plan.frames() {
        if step != Some(f.step) {
            session.begin_step(s.plan.exposure_ns(f.step, s.plan.reference_iso)).expect("step");
            step = Some(f.step);
        }
        let (px, meta) = s.sim.capture(f.iso, f.exposure_ns, f.index).expect("capture");
        session.push_frame(&FrameView::from_array(&px).expect("view"), &meta).expect("push");
    }
    let pack = session.finish().expect("finish");
    (session, pack)
}

/// Held-out clean image at an exposure (reference burst of `m` frames from frame index `base`):
/// levels, and which pixels are flat.
pub fn heldout_clean(s: &Setup, exposure_ns: u64, m: u64, base: u64, bin_width: u16) -> (Array2<u16>, Vec<bool>) {
    let layout = s.sim.layout();
    let mut c = SessionConfig::new(s.plan.reference_iso);
    c.bin_width = Some(bin_width);
    let mut session = CalibrationSession::new(layout.clone(), c).expect("session");
    session.begin_step(exposure_ns).expect("step");
    for k in 0..m {
        let (px, meta) = s.sim.capture(s.plan.reference_iso, exposure_ns, base + k).expect("capture");
        session.push_frame(&FrameView::from_array(&px).expect("view"), &meta).expect("push");
    }
    session.close_reference_burst().expect("close");
    let raw = session.clean_image().expect("clean");
    let flat = raw.iter().map(|&c| c != NOT_FLAT).collect();
    let clean = Array2::from_shape_vec(
        (layout.height as usize, layout.width as usize),
        raw.iter().map(|&c| if c == NOT_FLAT { 0 } else { c }).collect(),
    )
    .expect("shape");
    (clean, flat)
}
