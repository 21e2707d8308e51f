//! A sampler for clean images at the target brightness (`--clean-at target`) reads the fine levels
//! near black from the bins its tables were built from, deconvolved once: it is the sampler the
//! earlier route built, which deconvolved every bin a second time for those levels, table for
//! table and level for level, at every calibrated ISO of a pack with structured components and a
//! dark step. The fine levels are built from the deconvolved bins, not the pack's own: a version
//! that handed them the pack's bins differs at some ISO (checked here, so the comparison is not
//! one that cannot fail).

use std::borrow::Cow;

use noisecal_core::derive::fine_levels::target_fine_levels;
use noisecal_core::model::structure::Components;
use noisecal_core::resolve::{ModelKind, sampler_for};
use noisecal_core::synth::CleanAt;
use noisecal_core::synth::sampler::{IsoSampler, carried_gain_ratio};
use noisecal_core::{CalibrationSession, ModelPack, POSITIONS, SessionConfig};
use noisecal_sim::{Chart, SensorModel, SessionPlan, Simulator};

/// A small simulated session with structured components (a fixed pattern among them) and dark
/// frames at every ISO.
fn structured_pack() -> ModelPack {
    let model = SensorModel::phone_10bit().with_structured_noise();
    let sim = Simulator::new(model, Chart::color_checker(96, 64).expect("chart"), 11).expect("simulator");
    let plan = SessionPlan::for_simulator(&sim, vec![100, 400, 1600], 6).expect("plan").with_ev_steps(-3..=3);
    let mut session = CalibrationSession::new(sim.layout(), SessionConfig::new(plan.reference_iso)).expect("session");
    // A frame the session refuses (a drift check on a frame offset) is left out, as a capture app does.
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

/// The earlier route: the fine levels from the pack's bins deconvolved anew (`own = false`) or,
/// as a wrong version would, from the pack's own bins (`own = true`).
fn rebuilt(pack: &ModelPack, iso: u32, own: bool) -> IsoSampler {
    let model = pack.iso(iso).expect("calibrated");
    let base = IsoSampler::with_components(pack, model, Components::ALL);
    let st = base.structure().cloned();
    let gains = model.gain_ratio;
    let target = base
        .clean_at(CleanAt::Target, pack.layout.black, gains, Some(carried_gain_ratio(pack, model)))
        .expect("target");
    let fine = std::array::from_fn(|p| {
        let bins = &model.positions[p].bins;
        let bins = || match (&st, own) {
            (Some(st), false) => Cow::Owned(st.deconvolved(p, bins)),
            _ => Cow::Borrowed(&bins[..]),
        };
        target_fine_levels(pack, model, p, bins, gains[p])
    });
    target.with_target_fine_levels(fine)
}

fn same(a: &IsoSampler, b: &IsoSampler) -> bool {
    (0..POSITIONS).all(|p| a.tables(p) == b.tables(p) && a.target_tables(p) == b.target_tables(p))
}

#[test]
fn target_sampler_deconvolves_once_and_is_the_earlier_one() {
    let pack = structured_pack();
    let mut wrong_differs = false;
    for iso in [100, 400, 1600] {
        let model = pack.iso(iso).expect("calibrated");
        let st = pack.structure_of(iso).expect("structured components");
        assert!(st.fpn.is_some(), "ISO {iso}: a fixed pattern (the fine levels need the dark step's)");
        let now = sampler_for(&pack, model, ModelKind::Noisecal, Components::ALL, CleanAt::Target, false)
            .expect("target sampler");
        assert!(now.structure().is_some(), "ISO {iso}: structured components added");
        assert!(same(&now, &rebuilt(&pack, iso, false)), "ISO {iso}: not the earlier route's sampler");
        wrong_differs |= !same(&now, &rebuilt(&pack, iso, true));
    }
    assert!(wrong_differs, "fine levels from the pack's own bins give the same sampler: the check cannot fail");
}
