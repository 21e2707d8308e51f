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

/// A sampler built for clean levels up to `top` (`noisecal synth` of one image,
/// [`noisecal_core::synth::sampler_up_to::SamplerUpTo`]) is the full sampler at every level up to `top`, table
/// for table, and synthesizes an image within `top` to the same bytes, on one thread and three;
/// past `top` it skipped the deconvolution (its tables there differ, so the build did less). At
/// low `top` the fine levels near black read bins past it: the full fine levels then differ from
/// those read with the rest left as the model's bins (checked, so the route that deconvolves the
/// rest first is exercised and a version without it would differ), and wherever the fine levels
/// are the same with the rest read and not read, they are those of every bin deconvolved.
#[test]
fn a_sampler_up_to_a_level_is_the_full_one_there() {
    use noisecal_core::derive::fine_levels::position_fine_levels;
    use noisecal_core::resolve::resolve_model;
    let pack = structured_pack();
    let white = pack.layout.white;
    let (mut skipped, mut fine_reads_past) = (0usize, 0usize);
    for iso in [100, 400, 1600] {
        let resolved = resolve_model(&pack, iso, ModelKind::Noisecal, false).expect("model");
        let full = resolved.sampler(&pack, Components::ALL, CleanAt::Reference, false).expect("full sampler");
        let model = pack.iso(iso).expect("calibrated");
        let st = full.structure().expect("structured components").clone();
        for top in [66u16, 70, 90, 200, 400, white] {
            let up_to =
                resolved.sampler_up_to(&pack, Components::ALL, CleanAt::Reference, false, top).expect("sampler");
            for p in 0..POSITIONS {
                for level in 0..=top {
                    assert!(
                        up_to.table(p, level) == Some(full.table(p, level)),
                        "ISO {iso}, top {top}, position {p}, level {level}"
                    );
                }
                let (lut, tables) = full.position_tables(p);
                skipped += (top as usize + 1..=white as usize)
                    .filter(|&l| up_to.tables(p)[lut[l] as usize] != tables[lut[l] as usize])
                    .count();
                // Do the fine levels read a bin past `top`? (The deconvolution without the floor
                // suffices to tell.)
                let bins = &model.positions[p].bins;
                let all = st.deconvolved(p, bins);
                let used =
                    pack.binning().lut(p)[..=top as usize].iter().map(|&b| b as usize + 1).max().expect("levels");
                let mut mixed = all.clone();
                mixed[used.min(bins.len())..].clone_from_slice(&bins[used.min(bins.len())..]);
                let mut unread = mixed.clone();
                unread[used.min(bins.len())..].iter_mut().for_each(|b| b.clipped = true);
                let fine = |b: &[noisecal_core::model::pack::BinModel]| position_fine_levels(&pack, model, p, b);
                let (read, not_read, truth) = (fine(&mixed), fine(&unread), fine(&all));
                // Where the check passes, the fine levels are those of every bin deconvolved.
                assert!(
                    read != not_read || read == truth,
                    "ISO {iso}, top {top}, position {p}: the check missed a read"
                );
                fine_reads_past += (read != truth) as usize;
            }
            let clean = ndarray::Array2::from_shape_fn((37, 53), |(y, x)| {
                (60 + ((y * 53 + x) * 7919) % (top as usize - 59)) as u16
            });
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
                let (a, b) = pool.install(|| {
                    (
                        noisecal_core::synth::synthesize(&full, clean.view(), 5),
                        up_to.synthesize_at(clean.view(), 5, (0, 0)).expect("levels within top"),
                    )
                });
                assert!(a == b, "ISO {iso}, top {top}, {threads} threads: other bytes");
            }
        }
    }
    assert!(skipped > 1000, "{skipped} levels past top with other tables: the build skipped nothing");
    assert!(fine_reads_past > 0, "the fine levels never read a bin past top: their check cannot fail here");
    eprintln!(
        "levels past top with skipped tables: {skipped}; positions where the fine levels read past top: {fine_reads_past}"
    );
}

/// A sampler built up to a level refuses an image with a level above it, naming the level, its
/// row and the top, and draws no band holding it; an image within the top is drawn. What the
/// refusal prevents: the tables past the top hold the model's own bins with the structured
/// offsets still in them, so their variance exceeds the full sampler's by about the offsets'
/// variance (an unguarded draw there adds those offsets a second time); checked here, so the
/// guard is not one that guards nothing.
#[test]
fn a_sampler_up_to_a_level_refuses_levels_above_it() {
    use noisecal_core::resolve::resolve_model;
    use noisecal_core::synth::sampler_up_to::LevelAboveTop;
    let pack = structured_pack();
    let (iso, top) = (1600, 200u16);
    let resolved = resolve_model(&pack, iso, ModelKind::Noisecal, false).expect("model");
    let full = resolved.sampler(&pack, Components::ALL, CleanAt::Reference, false).expect("full sampler");
    let up_to = resolved.sampler_up_to(&pack, Components::ALL, CleanAt::Reference, false, top).expect("sampler");
    let (h, w) = (70, 53);
    let within = ndarray::Array2::from_shape_fn((h, w), |(y, x)| (60 + (y * w + x) * 7919 % 141) as u16);
    assert!(within.iter().all(|&l| l <= top));
    for (row, level) in [(0usize, top + 1), (h - 1, 900), (33, pack.layout.white)] {
        let mut clean = within.clone();
        clean[[row, 5]] = level;
        let want = LevelAboveTop { level, row, top };
        assert_eq!(up_to.synthesize_at(clean.view(), 5, (0, 0)), Err(want.clone()));
        let sunk = std::sync::Mutex::new(Vec::new());
        let got = up_to.synthesize_bands(clean.view(), 5, (0, 0), |y0, _| sunk.lock().expect("sink").push(y0));
        assert_eq!(got, Err(want));
        let band = row / noisecal_core::synth::BAND_ROWS * noisecal_core::synth::BAND_ROWS;
        assert!(!sunk.lock().expect("sink").contains(&band), "the band of row {row} was drawn");
        assert!(up_to.table(0, level).is_none(), "a table above the top");
    }
    let drawn = up_to.synthesize_at(within.view(), 5, (0, 0)).expect("levels within top");
    assert!(drawn == noisecal_core::synth::synthesize(&full, within.view(), 5), "other bytes within top");
    let err = up_to.synthesize_at(ndarray::Array2::from_elem((2, 2), 900).view(), 5, (0, 0)).expect_err("refused");
    assert!(err.to_string().contains("clean level 900 (row 0) is above 200"), "{err}");
    // What an unguarded draw above the top would give: the variance of the tables past the top
    // against the full sampler's, by exact moments of the tables.
    let var = |t: &noisecal_core::synth::sampler::BinTable| {
        let moment =
            |k: i32| (0..t.len() as i32).map(|i| t.prob(t.first() + i) * f64::from(t.first() + i).powi(k)).sum::<f64>();
        moment(2) - moment(1).powi(2)
    };
    // Every bin that holds a level above the top only, at each position: the variance each
    // unguarded table adds over the full one's.
    let mut excess = Vec::new();
    for p in 0..POSITIONS {
        let (lut, tables) = full.position_tables(p);
        let first = lut[top as usize] as usize + 1;
        let last = lut[pack.layout.white as usize - 1] as usize;
        excess.extend((first..last).map(|b| var(&up_to.tables(p)[b]) - var(&tables[b])));
    }
    excess.sort_by(f64::total_cmp);
    let (lowest, median) = (excess[excess.len() / 20], excess[excess.len() / 2]);
    eprintln!(
        "{} bins above the top: unguarded variance − full, 5 % {lowest:.3}, median {median:.3} DN²",
        excess.len()
    );
    assert!(lowest > 4.0 && median > 4.0, "tables past the top as the full ones: nothing to guard");
}
