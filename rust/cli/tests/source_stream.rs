//! `source`: a DNG folder and a recording of one session are the same stream of records, and a
//! held-out set whose black level is not the pack's is scored above black, as synth and renoise
//! treat their inputs.

use std::path::Path;

use noisecal_cli::eval::{EvalOptions, evaluate};
use noisecal_cli::simulate::SimSession;
use noisecal_core::FrameMeta;
use noisecal_input::calibrate::{CalibrateOptions, calibrate_path};
use noisecal_input::dng;
use noisecal_input::source::{Record, Source};
use noisecal_sim::SensorModel;

fn session(seed: u64, frames: u32) -> SimSession {
    SimSession::new(SensorModel::phone_10bit(), "sim", 96, 64, seed, vec![200, 800], frames, vec![-2, 0, 2])
        .expect("simulated session")
}

/// (step index, reference exposure) for BeginStep, (ISO, exposure, pixels) for frames.
#[derive(Debug, PartialEq)]
enum Seen {
    Step(usize, u64),
    Frame(u32, u64, Vec<u16>),
}

fn stream(path: &Path) -> (Vec<Seen>, bool) {
    let mut source = Source::open(path, None).expect("open");
    let mut seen = Vec::new();
    while let Some(r) = source.next_record().expect("record") {
        match r {
            Record::BeginStep { index, reference_exposure_ns, .. } => {
                seen.push(Seen::Step(index, reference_exposure_ns))
            }
            Record::Frame(f) => {
                let (iso, exposure) = (f.meta.iso, f.meta.exposure_ns);
                seen.push(Seen::Frame(iso, exposure, f.into_array().expect("pixels").into_raw_vec_and_offset().0));
            }
            other => panic!("unexpected record {other:?}"),
        }
    }
    (seen, source.complete())
}

#[test]
fn a_dng_folder_and_a_recording_are_one_stream() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (dngs, rec) = (dir.path().join("dngs"), dir.path().join("s.rec"));
    let s = session(3, 3);
    s.write(Some(&dngs), Some(&rec), 24, || {}).expect("write");
    let (a, a_complete) = stream(&dngs);
    let (b, b_complete) = stream(&rec);
    assert!(a_complete && b_complete);
    assert_eq!(a.iter().filter(|r| matches!(r, Seen::Step(..))).count(), 3);
    assert_eq!(a.iter().filter(|r| matches!(r, Seen::Frame(..))).count(), s.plan.len());
    assert!(a == b, "the DNG folder and the recording of one session stream different records");

    // A cut recording: the whole records, then the cut, and no End.
    let bytes = std::fs::read(&rec).expect("read");
    let cut = dir.path().join("cut.rec");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).expect("write");
    let mut source = Source::open(&cut, None).expect("open");
    let mut frames = 0;
    let last = loop {
        match source.next_record().expect("record") {
            Some(Record::Frame(_)) => frames += 1,
            Some(Record::CutShort(e)) => break Some(e),
            Some(_) => {}
            None => break None,
        }
    };
    assert!(last.is_some_and(|e| e.to_string().contains("cut short")), "no cut-short record");
    assert!(source.next_record().expect("after the cut").is_none());
    assert!(!source.complete() && frames > 0 && frames < s.plan.len());
}

#[test]
fn skipping_a_step_leaves_out_its_frames() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (dngs, rec) = (dir.path().join("dngs"), dir.path().join("s.rec"));
    session(4, 2).write(Some(&dngs), Some(&rec), 0, || {}).expect("write");
    for path in [&dngs, &rec] {
        let mut source = Source::open(path, None).expect("open");
        let mut steps = Vec::new();
        while let Some(r) = source.next_record().expect("record") {
            match r {
                Record::BeginStep { index, .. } => {
                    steps.push((index, 0));
                    if index == 1 {
                        source.skip_step();
                    }
                }
                Record::Frame(_) => steps.last_mut().expect("a step").1 += 1,
                _ => {}
            }
        }
        // Two reference frames at ISO 50, two at 200 and two at 800 per step.
        assert_eq!(steps, vec![(0, 6), (1, 0), (2, 6)], "{}", path.display());
    }
}

/// Writes `from`'s DNGs into `to` with every level and the black level `shift` DN lower.
fn lower_black(from: &Path, to: &Path, shift: u16) {
    std::fs::create_dir_all(to).expect("dir");
    for p in dng::scan_folder(from).expect("scan") {
        let img = dng::read_dng(&p).expect("read");
        let mut layout = img.layout.clone();
        layout.black = layout.black.map(|b| b - shift as f32);
        let meta = FrameMeta { black: None, ..img.meta };
        let px = img.pixels.mapv(|v| v.saturating_sub(shift));
        dng::write_dng_from_layout(&to.join(p.file_name().expect("name")), &layout, &meta, &img.make, &img.model, &px)
            .expect("write");
    }
}

#[test]
fn a_held_out_set_with_another_black_level_is_scored_above_black() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (cal, held, low) = (dir.path().join("cal"), dir.path().join("held"), dir.path().join("low"));
    session(5, 4).write(Some(&cal), None, 0, || {}).expect("write");
    SimSession { index_offset: 10_000, ..session(5, 3) }.write(Some(&held), None, 0, || {}).expect("write");
    // 40 DN is ten bins of the pack: scored at the captures' own levels, every clean level would
    // be taken for a much darker one.
    lower_black(&held, &low, 40);
    let (pack, _) = calibrate_path(&cal, &CalibrateOptions::default(), &mut |_, _| {}).expect("calibrate");
    let pack_path = dir.path().join("p.pack");
    let opts = EvalOptions { seeds: 1, ..Default::default() };
    let same = evaluate(&pack, &pack_path, &held, &opts, true).expect("eval");
    let lower = evaluate(&pack, &pack_path, &low, &opts, true).expect("eval with another black level");
    assert!(lower.notes.iter().any(|n| n.contains("shifted onto the pack's black level")), "{:?}", lower.notes);
    assert!(!same.notes.iter().any(|n| n.contains("black level")), "{:?}", same.notes);
    for (a, b) in same.isos.iter().zip(&lower.isos) {
        assert_eq!(a.iso, b.iso);
        let (x, y) = (a.model("noisecal").expect("noisecal"), b.model("noisecal").expect("noisecal"));
        assert!(
            (x.conditional_overall - y.conditional_overall).abs() < 0.15 * x.conditional_overall + 0.002,
            "ISO {}: conditional JSD {} at the pack's black level, {} 40 DN lower",
            a.iso,
            x.conditional_overall,
            y.conditional_overall
        );
    }
}
