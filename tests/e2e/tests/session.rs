//! Real captures are messy: the session on simulated data that has each flaw, plus the paths a
//! user takes (DNG folder vs recording, checkpoint and resume, determinism) and bad input.

use noisecal_cli::simulate::SimSession;
use noisecal_core::error::SessionError;
use noisecal_core::{CalibrationSession, FrameMeta, FrameView, ModelPack, SessionConfig};
use noisecal_e2e::{calibrate, setup};
use noisecal_input::calibrate::{CalibrateOptions, calibrate_path};
use noisecal_sim::{Chart, Flicker, SensorModel, Simulator};

#[test]
fn dng_folder_and_recording_give_the_same_pack() {
    let dir = tempfile::tempdir().unwrap();
    for (model, name) in [(SensorModel::phone_12bit(), "12"), (SensorModel::phone_14bit(), "14")] {
        let s = SimSession::new(model, name, 96, 64, 3, vec![400, 1600], 4, vec![-2, 0, 2]).unwrap();
        let dngs = dir.path().join(format!("dngs{name}"));
        let rec = dir.path().join(format!("s{name}.rec"));
        s.write(Some(&dngs), Some(&rec), 40, || {}).unwrap();
        let opts = CalibrateOptions { pooling: Some(200), ..Default::default() };
        let (a, _) = calibrate_path(&dngs, &opts, &mut |_, _| {}).unwrap();
        let (b, _) = calibrate_path(&rec, &opts, &mut |_, _| {}).unwrap();
        assert_eq!(a.to_bytes().unwrap(), b.to_bytes().unwrap(), "{name}-bit: DNG folder and recording differ");
        assert_eq!(a.iso_list(), vec![400, 1600]);
    }
}

#[test]
fn same_frames_same_bytes_on_any_thread_count() {
    let s = setup(SensorModel::phone_10bit(), 96, 64, 5, vec![400], 4, vec![-1, 1]);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let (_, a) = one.install(|| calibrate(&s, |c| c.pooling = Some(100)));
    let (_, b) = calibrate(&s, |c| c.pooling = Some(100));
    assert_eq!(a.to_bytes().unwrap(), b.to_bytes().unwrap());
    let sampler = noisecal_core::synth::sampler::IsoSampler::new(&a, &a.isos[0]);
    let clean = s.sim.clean_expected(50, s.plan.base_exposure_ns).unwrap().mapv(|v| v.round() as u16);
    let x = one.install(|| noisecal_core::synth::synthesize(&sampler, clean.view(), 9));
    let y = noisecal_core::synth::synthesize(&sampler, clean.view(), 9);
    let z = noisecal_core::synth::synthesize(&sampler, clean.view(), 10);
    assert_eq!(x, y);
    assert_ne!(y, z);
}

#[test]
fn checkpoint_and_resume_give_the_same_pack() {
    let s = setup(SensorModel::phone_10bit(), 96, 64, 7, vec![200, 800], 4, vec![-2, 0]);
    let (_, whole) = calibrate(&s, |c| c.pooling = Some(100));
    let mut config = SessionConfig::new(s.plan.reference_iso);
    config.pooling = Some(100);
    let mut session = CalibrationSession::new(s.sim.layout(), config).unwrap();
    let frames: Vec<_> = s.plan.frames().collect();
    let mut step = None;
    for (i, f) in frames.iter().enumerate() {
        if i == frames.len() / 2 + 1 {
            // Interrupted mid-burst: resume from bytes.
            let bytes = session.checkpoint().unwrap();
            session = CalibrationSession::restore(&bytes).unwrap();
        }
        if step != Some(f.step) {
            session.begin_step(s.plan.exposure_ns(f.step, s.plan.reference_iso)).unwrap();
            step = Some(f.step);
        }
        let (px, meta) = s.sim.capture(f.iso, f.exposure_ns, f.index).unwrap();
        session.push_frame(&FrameView::from_array(&px).unwrap(), &meta).unwrap();
    }
    assert_eq!(session.finish().unwrap().to_bytes().unwrap(), whole.to_bytes().unwrap());
    // A damaged checkpoint is refused, not trusted.
    let mut bytes = session.checkpoint().unwrap();
    let n = bytes.len();
    bytes[n / 2] ^= 0xFF;
    assert!(CalibrationSession::restore(&bytes).is_err());
    assert!(CalibrationSession::restore(&bytes[..n / 3]).is_err());
}

#[test]
fn noisy_short_reference_still_finds_the_flat_chart() {
    // Two reference frames, high read noise: the flat test must not mask out the patches.
    let mut m = SensorModel::phone_10bit();
    m.read_noise_post_dn = 4.0;
    let s = setup(m, 128, 96, 9, vec![400], 2, vec![0]);
    let (session, _) = calibrate(&s, |c| c.pooling = Some(50));
    let report = session.flat_report().expect("step closed");
    let frac = report.total_flat() as f64 / report.considered.iter().sum::<u64>() as f64;
    // The colour checker's patch interiors cover most of the frame; its edges must be excluded.
    let rects = s.sim.chart().patch_rects();
    let interior: usize = rects.iter().filter_map(|r| r.interior(4.0)).map(|(a, b)| a.len() * b.len()).sum();
    let interior_frac = interior as f64 / (128.0 * 96.0);
    assert!(frac > 0.8 * interior_frac, "flat {frac:.3} vs patch interiors {interior_frac:.3}");
    assert!(frac < 0.97, "edges must be masked out (flat {frac:.3})");
}

#[test]
fn flicker_is_detected_and_normalised() {
    let mut m = SensorModel::phone_10bit();
    m.flicker = Some(Flicker { probability: 0.3, amplitude: 0.04 });
    let s = setup(m.clone(), 128, 96, 13, vec![200], 8, vec![0, 1]);
    let (session, with) = calibrate(&s, |c| c.pooling = Some(100));
    let progress = session.progress();
    assert!(progress.drift_frames >= 2, "flicker frames should be reported ({})", progress.drift_frames);
    let (_, without) = calibrate(&s, |c| {
        c.pooling = Some(100);
        c.normalise_drift = false;
    });
    // Steady-light truth: the same sensor without flicker.
    m.flicker = None;
    let steady = setup(m, 128, 96, 13, vec![200], 8, vec![0, 1]);
    let (_, truth) = calibrate(&steady, |c| c.pooling = Some(100));
    let spread = |p: &ModelPack| -> f64 {
        // Mean variance over well-measured bins of position 0.
        let bins: Vec<_> = p.isos[0].positions[0].bins.iter().filter(|b| !b.filled() && b.samples > 2000).collect();
        bins.iter().map(|b| b.moments().1).sum::<f64>() / bins.len().max(1) as f64
    };
    let (v_with, v_without, v_truth) = (spread(&with), spread(&without), spread(&truth));
    assert!(
        (v_with - v_truth).abs() < 0.5 * (v_without - v_truth).abs(),
        "normalised {v_with:.2}, raw {v_without:.2}, steady truth {v_truth:.2}"
    );
}

#[test]
fn sparse_bins_are_pooled_not_trusted() {
    let s = setup(SensorModel::phone_10bit(), 96, 64, 17, vec![800], 3, vec![-1, 1]);
    let (session, pack) = calibrate(&s, |c| c.pooling = None);
    let m = &pack.isos[0];
    let est = m.positions[0].estimate.as_ref().expect("a calibrated position has an estimate report");
    assert!(
        matches!(est.choice, noisecal_core::model::estimate_report::Choice::CrossValidated { .. }),
        "{:?}",
        est.choice
    );
    // The chosen pooling is at least as likely on held-out frames as the plain histogram.
    let (plain, chosen) = est.gain_over_plain().expect("scores");
    assert!(chosen <= plain, "chosen {chosen} vs plain {plain}");
    let bins = &m.positions[0].bins;
    let raw = session.histograms(800, 0).expect("ISO 800 was captured");
    use noisecal_core::model::pack::BinSource;
    for (i, (b, h)) in bins.iter().zip(&raw).enumerate() {
        // Bins without samples are filled, bins with samples say so and keep their own moments.
        assert_eq!(b.samples, h.total(), "bin {i}");
        // Clipped bins: filled in law mode, measured where they keep their own histogram (only
        // with law mode chosen can a clipped bin with samples be filled).
        if b.clipped && h.total() > 0 {
            assert!(
                b.source == BinSource::Measured
                    || (b.source == BinSource::Filled
                        && est.clip_mode == noisecal_core::model::estimate_report::ClipMode::Law),
                "bin {i}: {:?}",
                b.source
            );
        } else {
            assert_eq!(b.source == BinSource::Filled, h.total() == 0, "bin {i}");
        }
        if h.total() > 0 {
            // The bin's own moments, with the 3-frame clean image's selection undone in
            // unclipped bins: the mean moves by a fraction of the spread and the spread grows back what
            // the error hid (method.md, "Selection by the clean image").
            let (mm, mv) = h.moments();
            let [pm, pv] = b.measured.expect("measured moments");
            if b.clipped {
                assert!((mm - pm).abs() < 1e-9 && (mv - pv).abs() < 1e-9, "bin {i}");
            } else {
                assert!((mm - pm).abs() <= mv.sqrt() + 1e-9, "bin {i}: mean {mm} → {pm}");
                assert!(pv >= 0.9 * mv && pv <= 1.5 * mv + 1e-9, "bin {i}: variance {mv} → {pv}");
            }
        }
    }
    let filled = bins.iter().filter(|b| b.filled()).count();
    assert!(filled > 0 && filled < bins.len());
    // Above the last measured unclipped bin the fill follows the variance law: never falling
    // towards white.
    let last = bins.iter().rposition(|b| b.measured.is_some() && !b.clipped).expect("a measured bin");
    let tail: Vec<f64> = bins[last + 1..].iter().filter(|b| b.filled()).map(|b| b.moments().1).collect();
    for w in tail.windows(2) {
        assert!(w[1] >= w[0] * 0.98, "fill variance falls towards white: {tail:?}");
    }
}

#[test]
fn bad_frames_are_refused_and_change_nothing() {
    let chart = Chart::color_checker(64, 48).unwrap();
    let sim = Simulator::new(SensorModel::phone_10bit(), chart, 1).unwrap();
    let mut session = CalibrationSession::new(sim.layout(), SessionConfig::new(50)).unwrap();
    let (px, meta) = sim.capture(50, 1_000_000, 0).unwrap();
    let view = FrameView::from_array(&px).unwrap();
    assert_eq!(session.push_frame(&view, &meta).unwrap_err(), SessionError::NoStep);
    session.begin_step(1_000_000).unwrap();
    // A target before any reference frame of the step.
    let e = session.push_frame(&view, &FrameMeta::new(200, 250_000)).unwrap_err();
    assert!(matches!(e, SessionError::NoReference { .. }), "{e}");
    session.push_frame(&view, &meta).unwrap();
    let before = session.clone();
    // Wrong size.
    let small = ndarray::Array2::<u16>::zeros((46, 64));
    let e = session.push_frame(&FrameView::from_array(&small).unwrap(), &meta).unwrap_err();
    assert!(e.to_string().contains("64×48"), "{e}");
    // Below the reference ISO.
    assert!(matches!(
        session.push_frame(&view, &FrameMeta::new(25, 2_000_000)),
        Err(SessionError::BelowReference { .. })
    ));
    // A target of another EV step (exposure did not apply).
    let e = session.push_frame(&view, &FrameMeta::new(200, 1_000_000)).unwrap_err();
    assert!(matches!(e, SessionError::WrongStep { .. }), "{e}");
    // Black level at white.
    let bad = FrameMeta { black: Some([1023.0; 4]), ..meta };
    assert!(session.push_frame(&view, &bad).is_err());
    assert_eq!(session.progress().frames_rejected, 6);
    assert!(matches!(session.finish(), Err(SessionError::NothingCalibrated)));
    // Nothing but the rejected count changed: the same good frames give the same pack.
    assert_eq!(session.clean_image(), before.clean_image());
    let mut after = session;
    let mut reference = before;
    for k in 1..4 {
        let (px, meta) = sim.capture(200, 250_000, k).unwrap();
        let v = FrameView::from_array(&px).unwrap();
        after.push_frame(&v, &meta).unwrap();
        reference.push_frame(&v, &meta).unwrap();
    }
    assert_eq!(after.progress().isos, reference.progress().isos);
    assert_eq!(after.finish().unwrap().to_bytes().unwrap(), reference.finish().unwrap().to_bytes().unwrap());
}

#[test]
fn byte_identical_frames_are_refused_not_calibrated() {
    // Every frame of a step is a copy of its first reference frame (with each frame's own
    // settings): no noise at all, which a real capture never has.
    let s = setup(SensorModel::phone_10bit(), 96, 64, 3, vec![400], 3, vec![-1, 1]);
    let mut session = CalibrationSession::new(s.sim.layout(), SessionConfig::new(s.plan.reference_iso)).unwrap();
    let mut step = None;
    let mut copy = None;
    for f in s.plan.frames() {
        if step != Some(f.step) {
            session.begin_step(s.plan.exposure_ns(f.step, s.plan.reference_iso)).unwrap();
            step = Some(f.step);
            copy = Some(s.sim.capture(f.iso, f.exposure_ns, f.index).unwrap().0);
        }
        let (_, meta) = s.sim.capture(f.iso, f.exposure_ns, f.index).unwrap();
        let px = copy.as_ref().unwrap();
        if let Err(e) = session.push_frame(&FrameView::from_array(px).unwrap(), &meta) {
            panic!("a copied frame was refused early ({e}); the test expects the refusal at finish");
        }
    }
    match session.finish() {
        Err(SessionError::NoNoise { iso: 400 }) => {}
        other => panic!("copied frames gave {other:?}"),
    }
    // The same session with real frames calibrates.
    let (_, pack) = calibrate(&s, |_| {});
    assert_eq!(pack.iso_list(), vec![400]);
}

/// An absurd camera NoiseProfile (S = 1e-3, O = 1e10, from a damaged tag or
/// record) does not go into the pack, where `synth --model noiseprofile`, `eval` and `report`
/// would size their work by it; the pack says why.
#[test]
fn an_absurd_noise_profile_is_left_out_with_a_warning() {
    use noisecal_core::model::pack::NoiseProfile;
    let s = setup(SensorModel::phone_10bit(), 64, 48, 5, vec![200, 800], 3, vec![-1, 1]);
    let mut session = CalibrationSession::new(s.sim.layout(), SessionConfig::new(s.plan.reference_iso)).unwrap();
    session.set_noise_profile(200, NoiseProfile([[1e-3, 1e10]; 4]));
    session.set_noise_profile(800, NoiseProfile([[2e-4, 3e-6]; 4]));
    noisecal_e2e::push_plan(&s, &mut session);
    let pack = session.finish().expect("a pack without the absurd profile");
    assert_eq!(pack.iso(200).unwrap().noise_profile, None);
    assert!(pack.iso(800).unwrap().noise_profile.is_some(), "a plausible profile is kept");
    assert!(
        pack.warnings.iter().any(|w| w.contains("ISO 200") && w.contains("NoiseProfile is impossible")),
        "{:?}",
        pack.warnings
    );
    let back = ModelPack::from_bytes(&pack.to_bytes().unwrap()).expect("the pack decodes");
    assert_eq!(back.iso(200).unwrap().noise_profile, None);
}
