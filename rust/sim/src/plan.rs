//! The capture order of a calibration session: per EV step, the reference burst, then one burst
//! per target ISO with the same ISO × exposure product.
//!
//! EV steps are integers counted in units of `1 / ev_steps_per_stop` EV: with the default
//! `ev_steps_per_stop = 1` they are whole stops (−4..=4), with 10 they are tenths of a stop
//! (−10..=10 is ±1 EV in 21 settings), with 18 consecutive settings are 2^(1/18) ≈ 3.9 % apart
//! (a photon-transfer-style sweep). See [`SessionPlan::with_ev_steps_per_stop`].

use crate::error::SimError;
use crate::sim::Simulator;

/// One frame of a [`SessionPlan`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PlannedFrame {
    /// EV step (0 = base exposure at the reference ISO), in units of
    /// `1 / SessionPlan::ev_steps_per_stop` EV.
    pub step: i32,
    /// ISO of the frame.
    pub iso: u32,
    /// Exposure time (ns).
    pub exposure_ns: u64,
    /// Running index in capture order (0, 1, 2, …), unique in the session: pass it to
    /// [`Simulator::capture`] as the frame index.
    pub index: u64,
    /// Index of the frame within its burst (0..frames_per_burst).
    pub in_burst: u32,
    /// Whether the frame belongs to the reference burst of its step.
    pub is_reference: bool,
}

/// A calibration capture plan. All fields are public.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionPlan {
    /// ISO of the reference bursts (the lowest ISO of the session).
    pub reference_iso: u32,
    /// ISOs to calibrate; each gets a burst per EV step after the reference burst. An ISO equal
    /// to the reference gets its own burst (fresh noise) too.
    pub target_isos: Vec<u32>,
    /// EV steps in capture order (default −4..=4), in units of `1 / ev_steps_per_stop` EV.
    pub ev_steps: Vec<i32>,
    /// Steps per stop (EV): 1 (default) for whole-stop steps, e.g. 10 for tenth-stop steps.
    pub ev_steps_per_stop: u32,
    /// Frames per burst (M).
    pub frames_per_burst: u32,
    /// Reference exposure at EV 0 (ns).
    pub base_exposure_ns: u64,
}

impl SessionPlan {
    /// A plan with the default EV steps −4..=4.
    pub fn new(reference_iso: u32, target_isos: Vec<u32>, frames_per_burst: u32, base_exposure_ns: u64) -> Self {
        Self {
            reference_iso,
            target_isos,
            ev_steps: (-4..=4).collect(),
            ev_steps_per_stop: 1,
            frames_per_burst,
            base_exposure_ns,
        }
    }

    /// A plan for a simulator: reference at the model's base ISO, EV 0 exposure from
    /// [`Simulator::mid_range_exposure_ns`] (chart mid-range at EV 0, bright patches clipped at
    /// EV +4, dark chart at EV −4), default EV steps.
    pub fn for_simulator(sim: &Simulator, target_isos: Vec<u32>, frames_per_burst: u32) -> Result<Self, SimError> {
        let reference_iso = sim.model().base_iso;
        let plan = Self::new(reference_iso, target_isos, frames_per_burst, sim.mid_range_exposure_ns(reference_iso)?);
        plan.validate()?;
        Ok(plan)
    }

    /// The same plan with other EV steps.
    pub fn with_ev_steps(mut self, ev_steps: impl IntoIterator<Item = i32>) -> Self {
        self.ev_steps = ev_steps.into_iter().collect();
        self
    }

    /// The same plan with EV steps counted in `1 / steps_per_stop` EV (the steps themselves are
    /// kept: set them with [`SessionPlan::with_ev_steps`]). E.g. `.with_ev_steps_per_stop(10)
    /// .with_ev_steps(-10..=10)` is ±1 EV in tenth-stop steps.
    pub fn with_ev_steps_per_stop(mut self, steps_per_stop: u32) -> Self {
        self.ev_steps_per_stop = steps_per_stop;
        self
    }

    /// The same plan with a dense sweep: `count` consecutive settings, `steps_per_stop` per
    /// stop, the first at step `first_step` (e.g. `with_dense_ev_steps(-9, 18, 18)` is 18
    /// settings from −0.5 EV up, each 2^(1/18) ≈ 3.9 % brighter than the last).
    pub fn with_dense_ev_steps(self, first_step: i32, count: u32, steps_per_stop: u32) -> Self {
        self.with_ev_steps_per_stop(steps_per_stop).with_ev_steps((0..count as i32).map(|k| first_step + k))
    }

    /// EV of a step: `step / ev_steps_per_stop`.
    pub fn ev(&self, step: i32) -> f64 {
        step as f64 / self.ev_steps_per_stop.max(1) as f64
    }

    /// Checks the plan; the error names the first bad field.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |what: &'static str, value: String, fix: &'static str| Err(SimError::Parameter { what, value, fix });
        if self.reference_iso == 0 {
            return bad("SessionPlan::reference_iso", "0".into(), "use the sensor's base ISO");
        }
        if self.target_isos.is_empty() {
            return bad("SessionPlan::target_isos", "empty".into(), "list at least one ISO to calibrate");
        }
        if let Some(&iso) = self.target_isos.iter().find(|&&i| i < self.reference_iso) {
            return bad(
                "SessionPlan::target_isos",
                format!("{iso} (below reference {})", self.reference_iso),
                "every target ISO must be ≥ the reference ISO (the reference is the lowest)",
            );
        }
        if !(1..=1000).contains(&self.ev_steps_per_stop) {
            return bad(
                "SessionPlan::ev_steps_per_stop",
                self.ev_steps_per_stop.to_string(),
                "use 1 (whole stops) up to 1000 steps per stop",
            );
        }
        let max_step = 16 * self.ev_steps_per_stop as i32;
        if self.ev_steps.is_empty() || self.ev_steps.iter().any(|s| !(-max_step..=max_step).contains(s)) {
            return bad(
                "SessionPlan::ev_steps",
                format!("{:?}", self.ev_steps),
                "give one or more steps within ±16 EV (±16 × ev_steps_per_stop)",
            );
        }
        let mut sorted = self.ev_steps.clone();
        sorted.sort_unstable();
        sorted.dedup();
        if sorted.len() != self.ev_steps.len() {
            return bad("SessionPlan::ev_steps", format!("{:?}", self.ev_steps), "list each EV step once");
        }
        if self.frames_per_burst == 0 {
            return bad(
                "SessionPlan::frames_per_burst",
                "0".into(),
                "use at least 1 frame per burst (2+ to measure spread)",
            );
        }
        if self.base_exposure_ns == 0 {
            return bad("SessionPlan::base_exposure_ns", "0".into(), "use a positive exposure");
        }
        Ok(())
    }

    /// Exposure (ns) of `iso` at EV `step`: `base · 2^(step / ev_steps_per_stop) ·
    /// reference_iso / iso`, rounded, ≥ 1.
    pub fn exposure_ns(&self, step: i32, iso: u32) -> u64 {
        let factor = match self.ev_steps_per_stop {
            // Whole stops: the exact powers of two of the original plans.
            0 | 1 => 2f64.powi(step),
            k => 2f64.powf(step as f64 / k as f64),
        };
        let e = self.base_exposure_ns as f64 * factor * self.reference_iso as f64 / iso.max(1) as f64;
        (e.round() as u64).max(1)
    }

    /// Number of frames in the plan.
    /// The dark step's settings: each ISO of the plan with the shortest exposure it uses there
    /// (dark shading needs no long exposure), by ISO.
    pub fn dark_settings(&self) -> Vec<(u32, u64)> {
        let mut by_iso = std::collections::BTreeMap::new();
        for f in self.frames() {
            let e = by_iso.entry(f.iso).or_insert(f.exposure_ns);
            *e = (*e).min(f.exposure_ns);
        }
        by_iso.into_iter().collect()
    }

    pub fn len(&self) -> usize {
        self.ev_steps.len() * (1 + self.target_isos.len()) * self.frames_per_burst as usize
    }

    /// Whether the plan has no frames.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Captures the plan's frames on `sim` and pushes them into `session` in capture order, a new
    /// EV step (`begin_step`) where the step changes; each frame's outcome goes to `outcome`
    /// (a session may refuse a frame: the caller decides whether that is a failure).
    pub fn feed(
        &self,
        sim: &Simulator,
        session: &mut noisecal_core::CalibrationSession,
        mut outcome: impl FnMut(
            &PlannedFrame,
            Result<noisecal_core::calibrate::FrameReport, noisecal_core::error::SessionError>,
        ),
    ) -> Result<(), SimError> {
        let mut step = None;
        for f in self.frames() {
            if step != Some(f.step) {
                session
                    .begin_step(self.exposure_ns(f.step, self.reference_iso))
                    .expect("a planned exposure is positive");
                step = Some(f.step);
            }
            let (px, meta) = sim.capture(f.iso, f.exposure_ns, f.index)?;
            let view = noisecal_core::FrameView::from_array(&px).expect("a captured frame is contiguous");
            outcome(&f, session.push_frame(&view, &meta));
        }
        Ok(())
    }

    /// The frames in capture order: per EV step, the reference burst, then each target ISO's
    /// burst in `target_isos` order.
    pub fn frames(&self) -> impl Iterator<Item = PlannedFrame> + '_ {
        let m = self.frames_per_burst;
        let bursts = std::iter::once((self.reference_iso, true)).chain(self.target_isos.iter().map(|&i| (i, false)));
        let per_step: Vec<(u32, bool)> = bursts.collect();
        let per_step_frames = per_step.len() as u64 * m as u64;
        self.ev_steps.iter().enumerate().flat_map(move |(si, &step)| {
            let per_step = per_step.clone();
            per_step.into_iter().enumerate().flat_map(move |(bi, (iso, is_reference))| {
                let exposure_ns = self.exposure_ns(step, iso);
                (0..m).map(move |k| PlannedFrame {
                    step,
                    iso,
                    exposure_ns,
                    index: si as u64 * per_step_frames + bi as u64 * m as u64 + k as u64,
                    in_burst: k,
                    is_reference,
                })
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn capture_order_and_constant_brightness() {
        let plan = SessionPlan::new(50, vec![100, 400], 3, 8_000_000).with_ev_steps([-1, 0, 2]);
        plan.validate().expect("valid");
        let frames: Vec<PlannedFrame> = plan.frames().collect();
        assert_eq!(frames.len(), plan.len());
        assert_eq!(frames.len(), 3 * 3 * 3);
        for (i, f) in frames.iter().enumerate() {
            assert_eq!(f.index, i as u64);
        }
        assert_eq!((frames[0].step, frames[0].iso, frames[0].exposure_ns), (-1, 50, 4_000_000));
        assert!(frames[..3].iter().all(|f| f.is_reference));
        assert_eq!((frames[3].iso, frames[3].exposure_ns, frames[3].in_burst), (100, 2_000_000, 0));
        assert_eq!((frames[6].iso, frames[6].exposure_ns), (400, 500_000));
        assert_eq!((frames[9].step, frames[9].iso, frames[9].exposure_ns), (0, 50, 8_000_000));
        assert_eq!(frames[26].exposure_ns, 32_000_000 / 8);
        for f in &frames {
            let bright = f.iso as f64 * f.exposure_ns as f64;
            let want = 50.0 * 8e6 * 2f64.powi(f.step);
            assert!((bright / want - 1.0).abs() < 1e-6);
        }
    }

    #[test]
    fn fractional_steps_are_exact_fractions_of_a_stop() {
        let whole = SessionPlan::new(50, vec![100, 400], 2, 8_000_000).with_ev_steps([-1, 0, 1]);
        let tenth = whole.clone().with_ev_steps_per_stop(10).with_ev_steps(-10..=10);
        tenth.validate().expect("valid");
        assert_eq!(tenth.len(), 21 * 3 * 2);
        // Whole-stop settings coincide with the integer plan.
        for (s10, s1) in [(-10, -1), (0, 0), (10, 1)] {
            for iso in [50, 100, 400] {
                assert_eq!(tenth.exposure_ns(s10, iso), whole.exposure_ns(s1, iso));
            }
        }
        assert!((tenth.ev(-3) + 0.3).abs() < 1e-12);
        for s in -10..10 {
            let r = tenth.exposure_ns(s + 1, 50) as f64 / tenth.exposure_ns(s, 50) as f64;
            assert!((r - 2f64.powf(0.1)).abs() < 1e-5, "{s}: {r}");
        }
        // A photon-transfer sweep: 18 per stop, settings 3.9 % apart.
        let ptc = whole.clone().with_dense_ev_steps(-9, 30, 18);
        assert_eq!((ptc.ev_steps[0], ptc.ev_steps[29], ptc.ev_steps_per_stop), (-9, 20, 18));
        ptc.validate().expect("valid");
        let f: Vec<PlannedFrame> = ptc.frames().filter(|f| f.is_reference && f.in_burst == 0).collect();
        assert_eq!(f.len(), 30);
        for w in f.windows(2) {
            let r = w[1].exposure_ns as f64 / w[0].exposure_ns as f64;
            assert!((r - 1.0393).abs() < 1e-3, "{r}");
        }
        // Bounds scale with the unit.
        assert!(whole.clone().with_ev_steps_per_stop(10).with_ev_steps([160]).validate().is_ok());
        let e = whole.clone().with_ev_steps_per_stop(10).with_ev_steps([161]).validate().expect_err("out of range");
        assert!(e.to_string().contains("ev_steps"), "{e}");
        let e = whole.with_ev_steps_per_stop(0).validate().expect_err("zero unit");
        assert!(e.to_string().contains("ev_steps_per_stop"), "{e}");
    }

    #[test]
    fn bad_plans_are_named() {
        let p = SessionPlan::new(100, vec![50], 2, 1000);
        assert!(p.validate().expect_err("must be refused").to_string().contains("target_isos"));
        let p = SessionPlan::new(100, vec![200], 0, 1000);
        assert!(p.validate().expect_err("must be refused").to_string().contains("frames_per_burst"));
        let p = SessionPlan::new(100, vec![200], 2, 1000).with_ev_steps([0, 0]);
        assert!(p.validate().expect_err("must be refused").to_string().contains("ev_steps"));
    }
}
