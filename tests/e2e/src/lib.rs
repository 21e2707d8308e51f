//! Shared helpers of the end-to-end tests: small simulated sessions pushed through a session.

pub mod dark_levels;
pub mod moments;
pub mod sub_dn;

use ndarray::Array2;
use noisecal_core::calibrate::flat::NOT_FLAT;
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
    push_plan(s, &mut session);
    let pack = session.finish().expect("finish");
    (session, pack)
}

/// Pushes the plan's frames into a session in capture order, one EV step after another; every
/// frame must be taken.
pub fn push_plan(s: &Setup, session: &mut CalibrationSession) {
    s.plan
        .feed(&s.sim, session, |_, r| {
            r.expect("push");
        })
        .expect("capture");
}

/// Calibrates `plan` on `sim` as the CLI would: the frames the session refuses (a burst whose
/// brightness is off, a frame that moved too far) are left out. Returns the session (make
/// "sim") and its pack.
pub fn calibrate_lenient(sim: &Simulator, plan: &SessionPlan) -> (CalibrationSession, ModelPack) {
    let mut config = SessionConfig::new(plan.reference_iso);
    config.make = "sim".into();
    let mut session = CalibrationSession::new(sim.layout(), config).expect("session");
    plan.feed(sim, &mut session, |_, _| ()).expect("capture");
    let pack = session.finish().expect("a pack");
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

/// Scores of every model at one held-out ISO.
#[derive(Debug, Clone)]
pub struct IsoScores {
    pub iso: u32,
    /// Real flat-pixel samples scored.
    pub samples: u64,
    /// `(model name, marginal JSD, conditional JSD)`, in the order the models were given.
    pub models: Vec<(String, f64, f64)>,
    /// Real half against real half (alternate frames), marginal and conditional.
    pub floor: (f64, f64),
}

impl IsoScores {
    /// Marginal and conditional JSD of a model.
    pub fn of(&self, name: &str) -> (f64, f64) {
        self.models.iter().find(|m| m.0 == name).map(|m| (m.1, m.2)).expect("a scored model")
    }
}

/// A held-out target frame with its step's clean image: `(frame, clean levels (0 where not
/// flat), flat mask, captured frame)`.
pub type HeldOutFrame<'a> = (&'a noisecal_sim::PlannedFrame, &'a Array2<u16>, &'a Array2<bool>, &'a Array2<u16>);

/// Simulates a held-out set (`plan` on `sim`, frame indices shifted by `index_offset`) and hands
/// every target frame to `visit` with its EV step's clean image and flat mask (method.md,
/// "Measuring fidelity"): the step's reference burst, closed at its first target frame, gives
/// them (levels binned by `bin_width`); a refused reference frame is left out, and a step whose
/// burst gives no clean image is skipped.
pub fn for_each_heldout_frame(
    sim: &Simulator,
    plan: &SessionPlan,
    index_offset: u64,
    bin_width: u16,
    mut visit: impl FnMut(HeldOutFrame<'_>),
) {
    let layout = sim.layout();
    let (w, h) = (layout.width as usize, layout.height as usize);
    let mut session: Option<CalibrationSession> = None;
    let mut clean: Option<(Array2<u16>, Array2<bool>)> = None;
    let mut step = None;
    for f in plan.frames() {
        if step != Some(f.step) {
            let mut c = SessionConfig::new(plan.reference_iso);
            c.bin_width = Some(bin_width);
            let mut s = CalibrationSession::new(layout.clone(), c).expect("session");
            s.begin_step(plan.exposure_ns(f.step, plan.reference_iso)).expect("step");
            session = Some(s);
            clean = None;
            step = Some(f.step);
        }
        let (px, meta) = sim.capture(f.iso, f.exposure_ns, f.index + index_offset).expect("capture");
        if f.is_reference {
            if let Some(s) = session.as_mut() {
                let _ = s.push_frame(&FrameView::from_array(&px).expect("view"), &meta);
            }
            continue;
        }
        if clean.is_none() {
            let Some(s) = session.as_mut() else { continue };
            if s.close_reference_burst().is_err() {
                continue;
            }
            let raw = s.clean_image().expect("clean image of a closed burst");
            let c16 = Array2::from_shape_vec((h, w), raw.iter().map(|&c| if c == NOT_FLAT { 0 } else { c }).collect())
                .expect("shape");
            let mask = Array2::from_shape_vec((h, w), raw.iter().map(|&c| c != NOT_FLAT).collect()).expect("shape");
            clean = Some((c16, mask));
        }
        let Some((c16, mask)) = clean.as_ref() else { continue };
        visit((&f, c16, mask, &px));
    }
}

/// Synthetic sets each model draws per held-out target frame in [`score_heldout`]; a model
/// scores the mean of its sets' JSDs (as [`noisecal_core::metrics::score_seeds`] does).
pub const SYNTH_SETS: u64 = 4;

/// The synthesis seed of set `set` of held-out frame `index`: the same for every model scored
/// (common random numbers: each model's sampler turns the same uniform draw at a pixel into its
/// own noise value, so the models' synthetic sets differ only where the models do, and the
/// sampling noise of a JSD difference between two models shrinks to what their differences
/// leave). With a seed of its own per model, that noise alone moved pack / plain by ±8 % per ISO
/// on sensor 3 of the random family.
pub fn heldout_synth_seed(index: u64, set: u64) -> u64 {
    0x5EED_0000 + index * 7 + set * 0x1_0000_0000
}

/// Simulates a held-out set (`plan` on `sim`, frame indices shifted by `index_offset`) and
/// scores each model on it (method.md, "Measuring fidelity"): per EV step the reference burst
/// gives the clean image and flat mask, every target frame gives real noise on the flat pixels,
/// and each model synthesizes [`SYNTH_SETS`] sets of the same number of frames on the same
/// clean image, with the same seeds for every model ([`heldout_synth_seed`]); a model's score
/// is the mean over its sets. `models` maps a name to one model per target ISO of the plan
/// (`binning` groups levels for the conditional JSD, 8 bins per group).
pub fn score_heldout(
    sim: &Simulator,
    plan: &SessionPlan,
    index_offset: u64,
    binning: &noisecal_core::Binning,
    models: &[(&str, Vec<noisecal_core::model::pack::IsoModel>, &ModelPack)],
) -> Vec<IsoScores> {
    use noisecal_core::metrics::{DEFAULT_GROUP_BINS, NoiseSamples, compare, score_seeds};
    use noisecal_core::synth::sampler::IsoSampler;
    use noisecal_core::synth::synthesize;
    use std::collections::BTreeMap;

    let samplers: Vec<BTreeMap<u32, IsoSampler>> =
        models.iter().map(|(_, ms, pack)| ms.iter().map(|m| (m.iso, IsoSampler::new(pack, m))).collect()).collect();
    let new_samples = || NoiseSamples::new(binning, DEFAULT_GROUP_BINS);
    // Per ISO: real, real halves, and per model one synthetic accumulator per set.
    type Acc = (NoiseSamples, [NoiseSamples; 2], Vec<Vec<NoiseSamples>>);
    let mut acc: BTreeMap<u32, Acc> = BTreeMap::new();
    let mut count: BTreeMap<u32, u64> = BTreeMap::new();
    for_each_heldout_frame(sim, plan, index_offset, binning.bin_width, |(f, c16, mask, px)| {
        let cf = c16.mapv(|v| v as f32);
        let e = acc.entry(f.iso).or_insert_with(|| {
            let sets = || (0..SYNTH_SETS).map(|_| new_samples()).collect();
            (new_samples(), [new_samples(), new_samples()], models.iter().map(|_| sets()).collect())
        });
        let k = count.entry(f.iso).or_default();
        e.0.add_frame(cf.view(), px.view(), Some(mask.view())).expect("sizes");
        e.1[(*k % 2) as usize].add_frame(cf.view(), px.view(), Some(mask.view())).expect("sizes");
        for (mi, s) in samplers.iter().enumerate() {
            if let Some(sampler) = s.get(&f.iso) {
                for (set, out_acc) in e.2[mi].iter_mut().enumerate() {
                    let out = synthesize(sampler, c16.view(), heldout_synth_seed(f.index, set as u64));
                    out_acc.add_frame(cf.view(), out.view(), Some(mask.view())).expect("sizes");
                }
            }
        }
        *k += 1;
    });
    acc.into_iter()
        .map(|(iso, (real, halves, syn))| {
            let floor = compare(&halves[0], &halves[1]);
            IsoScores {
                iso,
                samples: (0..noisecal_core::POSITIONS).map(|p| real.total(p)).sum(),
                models: models
                    .iter()
                    .zip(&syn)
                    .map(|((name, _, _), sets)| {
                        let sc = score_seeds(&real, sets);
                        (name.to_string(), sc.marginal_overall, sc.conditional_overall)
                    })
                    .collect(),
                floor: (floor.marginal_overall, floor.conditional_overall),
            }
        })
        .collect()
}

/// The plain empirical estimator's model of every target ISO of a session: each bin its own
/// histogram, the nearest bin with samples for empty bins.
pub fn plain_models(session: &CalibrationSession, pack: &ModelPack) -> Vec<noisecal_core::model::pack::IsoModel> {
    use noisecal_core::calibrate::estimate::plain_empirical;
    use noisecal_core::model::pack::PositionModel;
    pack.isos
        .iter()
        .map(|m| {
            let mut p = m.clone();
            p.lattice = [None; noisecal_core::POSITIONS];
            p.positions = (0..noisecal_core::POSITIONS)
                .map(|pos| PositionModel::new(plain_empirical(&session.histograms(m.iso, pos).expect("histograms"))))
                .collect();
            p
        })
        .collect()
}
